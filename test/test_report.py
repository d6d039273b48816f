"""The calibration report (core.products.report, core.monitor.change): what it says about a known
rig."""
import copy

import numpy as np
import pytest

from densecalib_ros.core.monitor.change import calibration_change, pose_agreement
from densecalib_ros.core.products.report import (camera_centres_in_rig, camera_table,
                                                 distortion_text, intrinsics_note, layout_table,
                                                 overall_lines, rig_report)
from densecalib_ros.core.products.scale import apply_known_baseline
from densecalib_ros.core.types import CameraQuality, RigQuality

from sfm_fixtures import gt_calibration, gt_rig


@pytest.fixture
def rig():
    names = ["cam0", "cam1", "cam2", "cam3"]
    cams, poses = gt_rig(4, seed=5)
    fisheye, _ = gt_rig(4, model="OPENCV_FISHEYE", seed=5)
    cams[3] = fisheye[3]
    out = gt_calibration(names, cams, poses)
    for cam in out.cameras.values():
        cam.quality = CameraQuality(0.5, 1000, 0.8, 400)
    out.quality.update(reprojection_rms_px=0.5, num_points=900, pipeline="incremental",
                       camera_lens={"cam3": "fisheye"})
    return out


def test_camera_table_names_each_models_parameters(rig):
    rig.cameras["cam0"].quality.focal_std_px = 3.14
    rig.cameras["cam3"].quality.focal_std_px = 0.52
    rig.cameras["cam3"].quality.principal_point_std_px = 0.71
    rig.cameras["cam3"].quality.projection_std_px = 0.333
    table = camera_table(rig)
    lines = {line.split()[0]: line for line in table.splitlines()[1:]}
    header = table.splitlines()[0].split()
    columns = {name: dict(zip(header, line.split())) for name, line in lines.items()}
    assert columns["cam0"]["f_std"] == "3.1" and columns["cam0"]["pp_std"] == "-"
    assert columns["cam3"]["f_std"] == "0.5" and columns["cam3"]["pp_std"] == "0.7"
    assert columns["cam3"]["proj_std"] == "0.33" and columns["cam0"]["proj_std"] == "-"
    assert columns["cam1"]["f_std"] == "-"
    assert set(lines) == set(rig.cameras)
    assert "k1=" in lines["cam0"] and "k2=" in lines["cam0"] and "k3=" not in lines["cam0"]
    assert all(f"k{i}=" in lines["cam3"] for i in range(1, 5)) and "OPENCV_FISHEYE" in lines["cam3"]
    # the sigmas of a held principal point say what they include (files written before: nothing)
    assert intrinsics_note(rig) == ""
    rig.quality.held_pp_std_fraction = 0.01
    note = intrinsics_note(rig)
    assert note.startswith("f_std and proj_std of cam0 include") and "1 % of the long side" in note
    assert note in rig_report(rig)
    k = rig.cameras["cam0"].intrinsics
    assert distortion_text(k) == f"k1={k.params[3]:.4g} k2={k.params[4]:.4g}"
    assert f"{k.params[0]:.1f}" in lines["cam0"]


def test_layout_gives_centres_and_axis_angles_in_the_rig_frame(rig):
    centres = camera_centres_in_rig(rig)
    np.testing.assert_allclose(centres["cam0"], 0.0, atol=1e-12)
    for name, cam in rig.cameras.items():
        np.testing.assert_allclose(cam.cam_from_rig[:3, :3] @ centres[name]
                                   + cam.cam_from_rig[:3, 3], 0.0, atol=1e-9)
    rows = {line.split()[0]: line.split()[1:] for line in layout_table(rig).splitlines()[1:]}
    R = rig.cameras["cam3"].cam_from_rig[:3, :3]
    axis_deg = np.degrees(np.arccos(R[2, 2]))  # angle between the z axes of cam3 and the rig
    assert float(rows["cam3"][4]) == pytest.approx(axis_deg, abs=0.01)
    assert float(rows["cam2"][3]) == pytest.approx(np.linalg.norm(centres["cam2"]), abs=1e-3)
    assert "x_units" in layout_table(rig)
    metric = apply_known_baseline(rig, "cam0", "cam1", 0.25)
    assert "x_m" in layout_table(metric)
    assert "0.25 m baseline cam0-cam1" in "\n".join(overall_lines(metric))


def test_change_points_at_the_moved_and_refocused_camera(rig):
    moved = copy.deepcopy(rig)
    c = np.cos(np.radians(1.5)), np.sin(np.radians(1.5))
    moved.cameras["cam2"].cam_from_rig = np.array(
        [[c[0], -c[1], 0, 0], [c[1], c[0], 0, 0], [0, 0, 1, 0], [0, 0, 0, 1]]
    ) @ moved.cameras["cam2"].cam_from_rig
    moved.cameras["cam3"].intrinsics.params[4] += 0.02  # fisheye k1: a refocused lens
    change = calibration_change(rig, moved)
    assert max(change, key=lambda n: change[n].rotation_change_deg) == "cam2"
    assert change["cam2"].rotation_change_deg == pytest.approx(1.5, abs=1e-6)
    assert change["cam3"].focal_change_pct == 0.0 and change["cam3"].projection_change_px > 1.0
    assert change["cam0"].projection_change_px == pytest.approx(0.0, abs=1e-6)
    # Every pair with cam2 moved by 1.5 deg: 3 of 6 pairs fail AUC@1, none fails at 2..3 deg.
    assert pose_agreement(rig, moved)["auc3"] == pytest.approx(100 * (3 + 6 + 6) / 18)
    assert pose_agreement(rig, rig)["auc3"] == 100.0


def test_report_names_missing_cameras_and_warnings(rig):
    partial = copy.deepcopy(rig)
    del partial.cameras["cam3"]
    partial.failed_cameras = ["cam3"]
    partial.quality.warnings = ["the 5 calibration runs disagree"]
    text = rig_report(partial, rig, "before")
    assert "not registered: cam3" in text and "warning: the 5 calibration runs disagree" in text
    assert "missing from this calibration: cam3" in text
    assert "over its 6 camera pair(s)" in text  # pairs with cam3 count as failures
    assert "lenses cam3 fisheye" in rig_report(rig)


def test_overall_lines_give_the_time_offsets_and_how_they_were_found(rig):
    rig.quality.input = {"source": "videos", "path": "/rec",
                            "time_offsets_s": {"cam0": 0.0, "cam1": 0.7},
                            "time_offsets_estimated": {"cam0": {"correlation": 1.0},
                                                       "cam1": {"correlation": 0.88}}}
    line = next(li for li in overall_lines(rig) if li.startswith("time offsets"))
    assert "cam1 +0.700 (correlation 0.88)" in line and "found from the images' motion" in line
    rig.quality.input = {"source": "topics", "topics": ["/a", "/b"],
                            "stamp_offsets_s": {"cam0": 0.0, "cam1": -0.2}}
    assert "time offsets (s, ahead of the others): cam0 +0.000, cam1 -0.200" in overall_lines(rig)
    rig.quality.input = {"source": "images", "path": "/traps",
                            "time_offsets_s": {"cam0": 0.0, "cam1": 3607.5},
                            "time_offsets_estimated": {"cam0": {"paired_shots": 12},
                                                       "cam1": {"paired_shots": 11}}}
    line = next(li for li in overall_lines(rig) if li.startswith("time offsets"))
    assert "cam1 +3607.500 (11 shots paired)" in line and "from the capture times" in line


def _upright_rig(with_floor: bool):
    """Three upright cameras at floor-frame (x, y, height) (0, 0, 1), (1, 0, 2), (2, 0.5, 1.5),
    all looking along the floor's +y at a textured wall at y = 3."""
    from densecalib_ros.core.types import CameraIntrinsics, RigCalibration, RigCamera

    cam_from_floor_rotation = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])
    lens = CameraIntrinsics("RADIAL", 640, 480, np.array([500.0, 320, 240, 0, 0]))
    cam_from_floor = {}
    for name, position in (("cam0", (0, 0, 1)), ("cam1", (1, 0, 2)), ("cam2", (2, 0.5, 1.5))):
        pose = np.eye(4)
        pose[:3, :3] = cam_from_floor_rotation
        pose[:3, 3] = -cam_from_floor_rotation @ np.array(position, dtype=float)
        cam_from_floor[name] = pose
    floor_from_rig = np.linalg.inv(cam_from_floor["cam0"])
    quality = RigQuality(floor={"floor_from_rig": floor_from_rig.ravel().tolist(),
                                "num_points": 100, "rms": 0.01, "camera_heights": {}}
                         if with_floor else None)
    rig = RigCalibration("cam0", {n: RigCamera(n, lens, p @ floor_from_rig)
                                  for n, p in cam_from_floor.items()},
                         quality=quality, metric_scale=True)
    xs, zs = np.meshgrid(np.linspace(-1, 3, 60), np.linspace(0, 3, 40))
    wall_floor = np.column_stack([xs.ravel(), np.full(xs.size, 3.0), zs.ravel(), np.ones(xs.size)])
    wall_rig = (wall_floor @ np.linalg.inv(floor_from_rig).T)[:, :3]
    return rig, wall_rig


def _dots(panel):
    """Pixel centre (x, y) of each camera's dot in a layout panel."""
    import cv2

    from densecalib_ros.core.products.layout_plot import camera_colours

    out = []
    for colour in camera_colours(3):
        mask = np.all(panel == colour, axis=2).astype(np.uint8)
        core = cv2.erode(mask, np.ones((5, 5), np.uint8))  # the filled dot, not lines or text
        ys, xs = np.nonzero(core)
        assert len(xs), colour
        out.append((xs.mean(), ys.mean()))
    return np.array(out)


def test_layout_plot_shows_the_cameras_from_above_and_the_side():
    from densecalib_ros.core.products.layout_plot import PANEL_PX, draw_layout, half_fov_rad

    rig, wall = _upright_rig(with_floor=True)
    assert half_fov_rad(rig.cameras["cam0"].intrinsics, 0) == pytest.approx(np.arctan(320 / 500))
    image = draw_layout(rig, wall)
    assert image.shape == (PANEL_PX, 2 * PANEL_PX, 3)
    top, side = image[:, :PANEL_PX], image[:, PANEL_PX:]
    dots = _dots(top)
    assert dots[0, 0] < dots[1, 0] < dots[2, 0]  # floor x to the right
    assert dots[2, 1] < dots[0, 1] - 30 and abs(dots[0, 1] - dots[1, 1]) < 3  # cam2: further y
    rows = np.nonzero(np.all(top[40:-60] == (150, 150, 150), axis=2))[0] + 40  # no title, bar
    assert len(rows) > 50 and rows.max() < dots[:, 1].min()  # the wall seen edge-on, beyond
    heights = _dots(side)[:, 1]  # image y: smaller is higher
    assert heights[1] < heights[2] < heights[0]
    # no floor: "up" from the upright cameras' image-up, x along cam0's view: the same heights
    rig, wall = _upright_rig(with_floor=False)
    side = draw_layout(rig, wall)[:, PANEL_PX:]
    heights = _dots(side)[:, 1]
    assert heights[1] < heights[2] < heights[0]
    assert abs((heights[0] - heights[1]) - 2 * (heights[0] - heights[2])) < 4  # 1 m vs 0.5 m


def test_report_plot_command(tmp_path, caplog):
    import cv2

    from densecalib_ros.cli import main
    from densecalib_ros.core.io.export import write_calibration_files

    rig, _ = _upright_rig(with_floor=True)
    write_calibration_files(rig, tmp_path / "calib")
    assert main(["report", str(tmp_path / "calib"), "--plot", str(tmp_path / "rig.png")]) == 0
    assert cv2.imread(str(tmp_path / "rig.png")).shape == (640, 1280, 3)
    assert "without scene points" in caplog.text  # no COLMAP model saved with this one
    assert main(["report", str(tmp_path / "calib"), "--plot", str(tmp_path / "rig.jpg")]) == 2
    assert "give a .png file name" in caplog.text


def _read_ascii_ply(path):
    """(vertex table (N, 6): x y z r g b, faces (F, 3), comments) of an ASCII PLY file."""
    lines = path.read_text().splitlines()
    assert lines[:2] == ["ply", "format ascii 1.0"]
    end = lines.index("end_header")
    counts = {line.split()[1]: int(line.split()[2]) for line in lines[:end]
              if line.startswith("element ")}
    rows = lines[end + 1:]
    assert len(rows) == counts["vertex"] + counts["face"]
    vertices = np.array([[float(v) for v in row.split()] for row in rows[:counts["vertex"]]])
    faces = np.array([[int(v) for v in row.split()] for row in rows[counts["vertex"]:]])
    assert (faces[:, 0] == 3).all()
    return vertices, faces[:, 1:], [line for line in lines[:end] if line.startswith("comment")]


def test_scene_ply_has_the_cameras_as_pyramids_and_the_points(tmp_path, caplog):
    """export --format ply: each camera a pyramid with its apex at the camera's floor-frame
    position and its base through the rays of the image corners, the wall points at y = 3."""
    from densecalib_ros.cli import main
    from densecalib_ros.core.io.export import write_calibration_files
    from densecalib_ros.core.products.scene_ply import PYRAMID_FRACTION, scene_ply

    rig, wall = _upright_rig(with_floor=True)
    path = tmp_path / "scene.ply"
    path.write_text(scene_ply(rig, wall))
    vertices, faces, comments = _read_ascii_ply(path)
    assert len(vertices) == 15 + len(wall) and len(faces) == 12 and faces.max() < 15
    assert "floor frame" in comments[0] and "metres" in comments[0]
    depth = PYRAMID_FRACTION * 2.0  # the cameras span 2 m in x
    for i, position in enumerate([(0, 0, 1), (1, 0, 2), (2, 0.5, 1.5)]):
        apex, base = vertices[5 * i, :3], vertices[5 * i + 1:5 * i + 5, :3]
        np.testing.assert_allclose(apex, position, atol=1e-9)
        offsets = base - apex  # looking along +y; image x = floor x, image up = floor z
        np.testing.assert_allclose(offsets[:, 1], depth, atol=1e-9)
        np.testing.assert_allclose(offsets[0], [-depth * 320 / 500, depth, depth * 240 / 500],
                                   atol=1e-9)  # the top-left corner: left and up
        np.testing.assert_allclose(offsets[2], [depth * 320 / 500, depth, -depth * 240 / 500],
                                   atol=1e-9)
    np.testing.assert_allclose(vertices[15:, 1], 3.0, atol=1e-6)
    assert (vertices[15:, 3:] == 128).all() and not (vertices[:15, 3:] == 128).all()
    colours = np.random.default_rng(0).integers(0, 256, (len(wall), 3))
    path.write_text(scene_ply(rig, wall, colours))
    np.testing.assert_array_equal(_read_ascii_ply(path)[0][15:, 3:], colours)

    write_calibration_files(rig, tmp_path / "calib")  # no COLMAP model: the cameras alone
    assert main(["export", str(tmp_path / "calib"), "--format", "ply", "--out",
                 str(tmp_path / "cameras.ply")]) == 0
    assert len(_read_ascii_ply(tmp_path / "cameras.ply")[0]) == 15
    assert "without scene points" in caplog.text


def test_corner_rays_of_a_fisheye_keep_their_angle():
    from densecalib_ros.core.products.scene_ply import corner_rays
    from densecalib_ros.core.types import CameraIntrinsics

    def angles(focal):
        lens = CameraIntrinsics("OPENCV_FISHEYE", 640, 480,
                                np.array([focal, focal, 320, 240, 0, 0, 0, 0.0]))
        return np.degrees(np.arccos(corner_rays(lens)[:, 2]))

    np.testing.assert_allclose(angles(400.0), np.degrees(400 / 400.0))  # equidistant: r / f
    np.testing.assert_allclose(angles(200.0), 80.0)  # past 80 deg: held at 80


def test_layout_plot_against_another_calibration_rings_where_a_camera_was():
    """--against: the other calibration's cameras as grey rings joined to the cameras now; cam2,
    0.3 m further along the floor's x now, has its ring 0.3 m to the left of its dot."""
    import cv2

    from densecalib_ros.core.errors import InputError
    from densecalib_ros.core.products.layout_plot import (PANEL_PX, _BEFORE, centres_as_in,
                                                          draw_layout)

    rig, wall = _upright_rig(with_floor=True)
    before = copy.deepcopy(rig)
    floor_from_rig = np.asarray(rig.quality.floor["floor_from_rig"]).reshape(4, 4)
    shift_rig = np.linalg.inv(floor_from_rig)[:3, :3] @ [-0.3, 0.0, 0.0]  # 0.3 m back in floor x
    before.cameras["cam2"].cam_from_rig[:3, 3] -= before.cameras["cam2"].cam_from_rig[:3, :3] @ \
        shift_rig
    moved = centres_as_in(rig, before) - centres_as_in(rig, rig)
    np.testing.assert_allclose(np.linalg.norm(moved, axis=1), [0, 0, 0.3], atol=1e-9)
    top = draw_layout(rig, wall, against=before)[:, :PANEL_PX]
    dots = _dots(top)
    px_per_m = dots[1, 0] - dots[0, 0]  # cam0 and cam1 are 1 m apart in x
    ring = np.nonzero(cv2.inRange(top, np.array(_BEFORE) - 40, np.array(_BEFORE) + 40))
    was = dots[2] - [0.3 * px_per_m, 0.0]
    near = np.hypot(ring[1] - was[0], ring[0] - was[1]) < 10
    assert near.sum() > 20  # the ring around where cam2 was
    # an up-to-scale calibration is brought to this one's unit (by the median of the cameras'
    # distance ratios: with a moved camera among only two, that is a compromise)
    scaled = copy.deepcopy(rig)
    scaled.metric_scale = False
    for cam in scaled.cameras.values():
        cam.cam_from_rig[:3, 3] *= 3.0
    np.testing.assert_allclose(centres_as_in(rig, scaled), centres_as_in(rig, rig), atol=1e-9)
    before.reference_camera = "cam1"  # rig frames of different cameras: refused
    with pytest.raises(InputError, match="different reference cameras"):
        draw_layout(rig, wall, against=before)


def test_report_json_is_strict_json_and_against_needs_common_cameras(rig, tmp_path, caplog,
                                                                      capsys):
    """A figure that could not be measured (NaN) is null in every JSON densecalib prints or
    writes: jq and browsers reject NaN tokens. --against a calibration of other cameras is an
    error, not "AUC 0"."""
    import json

    from densecalib_ros.cli import main
    from densecalib_ros.core.io.export import write_calibration_files

    def strict(text):
        return json.loads(text, parse_constant=lambda token: pytest.fail(f"{token} in JSON"))

    rig.cameras["cam1"].quality = CameraQuality(float("nan"), 0, float("nan"), 0)
    rig.quality.reprojection_rms_px = float("inf")
    write_calibration_files(rig, tmp_path / "calib")
    saved = strict((tmp_path / "calib" / "calibration.json").read_text())
    assert saved["quality"]["reprojection_rms_px"] is None
    capsys.readouterr()
    assert main(["report", str(tmp_path / "calib"), "--json",
                 "--against", str(tmp_path / "calib")]) == 0
    printed = strict(capsys.readouterr().out)
    assert printed["pose_agreement"]["auc3"] == pytest.approx(100.0)

    other = copy.deepcopy(rig)
    other.cameras = {f"other{i}": cam for i, cam in enumerate(rig.cameras.values())}
    other.reference_camera = "other0"
    write_calibration_files(other, tmp_path / "other")
    assert main(["report", str(tmp_path / "calib"), "--against", str(tmp_path / "other")]) == 2
    assert "share no camera name" in caplog.text
