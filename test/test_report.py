"""The calibration report (core.products.report, core.monitor.change): what it says about a known
rig."""
import copy

import numpy as np
import pytest

from densecalib_ros.core.monitor.change import calibration_change, pose_agreement
from densecalib_ros.core.products.report import (TABLE_COLUMNS, PrincipalPoint,
                                                 camera_centres_in_rig, camera_table,
                                                 intrinsics_note, layout_table, overall_lines,
                                                 principal_point_case, rig_report, short_names,
                                                 shortened_line)
from densecalib_ros.core.io.export import calibration_from_dict, calibration_to_dict
from densecalib_ros.core.products.scale import apply_known_baseline
from densecalib_ros.core.types import CameraIntrinsics, CameraQuality, RigQuality

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


def _blocks(table):
    """The camera table's blocks (intrinsics, fit), each {camera: {column: value}}; the
    distortion column (several words) whole, its wrapped lines joined."""
    blocks, rows, header = [], None, None
    for line in table.splitlines():
        if line.startswith("camera "):
            header, rows = line.split(), {}
            blocks.append(rows)
        elif rows is not None and line.strip() and not line.startswith(" ") and \
                not line.startswith("names shortened"):
            words = line.split()
            if len(blocks) == 2:  # the fit block: distortion after the fit's four numbers
                words = words[:5] + [" ".join(words[5:])]
            rows[words[0]] = dict(zip(header, words))
            last = words[0]
        elif rows is not None and line.startswith(" ") and header[-1] == "distortion":
            rows[last]["distortion"] += " " + line.strip()
        else:
            rows = None if not line.strip() else rows
    return blocks


def test_camera_table_names_each_models_parameters(rig):
    rig.cameras["cam0"].quality.focal_std_px = 3.14
    rig.cameras["cam3"].quality.focal_std_px = 0.52
    rig.cameras["cam3"].quality.principal_point_std_px = 0.71
    rig.cameras["cam3"].quality.projection_std_px = 0.333
    intrinsics, fit = _blocks(camera_table(rig))
    assert set(intrinsics) == set(fit) == set(rig.cameras)
    assert intrinsics["cam0"]["f_std"] == "3.1" and intrinsics["cam0"]["pp_std"] == "-"
    assert intrinsics["cam3"]["f_std"] == "0.5" and intrinsics["cam3"]["pp_std"] == "0.7"
    assert intrinsics["cam3"]["proj_std"] == "0.33" and intrinsics["cam0"]["proj_std"] == "-"
    assert intrinsics["cam1"]["f_std"] == "-"
    assert intrinsics["cam3"]["pp_from"] == "images"  # refined in a final adjustment
    assert intrinsics["cam0"]["pp_from"] == "held"  # sigmas, none for the point: held
    assert intrinsics["cam1"]["pp_from"] == "-"  # off the centre, no sigmas: the file won't say
    k = rig.cameras["cam0"].intrinsics
    assert fit["cam0"]["distortion"] == f"k1={k.params[3]:.4g} k2={k.params[4]:.4g}"
    assert all(f"k{i}=" in fit["cam3"]["distortion"] for i in range(1, 5))
    assert intrinsics["cam3"]["model"] == "OPENCV_FISHEYE"
    assert intrinsics["cam0"]["focal_px"] == f"{k.params[0]:.1f}"
    # OpenCV pixels, as the written files: COLMAP's cx less 0.5
    assert intrinsics["cam0"]["cx"] == f"{k.params[1] - 0.5:.1f}"
    assert fit["cam0"]["rms_px"] == "0.50" and fit["cam0"]["obs3+"] == "400"
    # the sigmas of a held principal point say what they include (files written before: nothing)
    rig.cameras["cam0"].intrinsics.params[1:3] = [320.0, 240.0]  # held at the image centre
    assert "include where a real principal point" not in intrinsics_note(rig)
    rig.quality.held_pp_std_fraction = 0.01
    note = intrinsics_note(rig)
    assert "f_std and proj_std of cam0 include" in note and "1 % of the long side" in note
    assert "principal point held exactly at the image centre: cam0" in note
    assert note in rig_report(rig)
    # a calibration whose runs disagree says its sigmas include their spread
    assert "calibration runs, which disagree" not in note
    # a calibration that records the point as held gives it the spread as its own sigma
    rig.cameras["cam0"].quality.principal_point_std_px = 6.4
    rig.cameras["cam0"].quality.principal_point_held = True
    assert principal_point_case(rig, "cam0") == PrincipalPoint.CENTRE
    assert _blocks(camera_table(rig))[0]["cam0"]["pp_std"] == "6.4"
    assert "pp_std of cam0 is where a real principal point may lie, and their f_std and " \
        "proj_std include it: 1 % of the long side" in intrinsics_note(rig).replace("\n  ", " ")
    rig.cameras["cam0"].intrinsics.params[1:3] = [330.0, 250.0]  # held where it started
    assert principal_point_case(rig, "cam0") == PrincipalPoint.HELD
    assert calibration_from_dict(calibration_to_dict(rig)).cameras[
        "cam0"].quality.principal_point_held is True
    rig.quality.sigmas_runs_spread = 5
    assert "include how far the 5 calibration runs, which disagree, scatter" in \
        intrinsics_note(rig).replace("\n  ", " ")
    # and where the second matcher's refined calibration stood apart, that it includes its
    assert "not kept" not in intrinsics_note(rig)
    rig.quality.sigmas_matchers_spread = "asift"
    assert "widened where the calibration on asift's matches, not kept, stands further" in \
        intrinsics_note(rig).replace("\n  ", " ")


def _named_rig(names, model="OPENCV_FISHEYE"):
    """Cameras of one lens model at poses of gt_rig, with the fit and sigmas a calibration
    records."""
    cams, poses = gt_rig(len(names), model=model, seed=2)
    out = gt_calibration(names, cams, poses)
    for cam in out.cameras.values():
        cam.quality = CameraQuality(0.43, 12345, 0.91, 4321, focal_std_px=1.23,
                                    principal_point_std_px=2.5, projection_std_px=0.456)
    return out


def test_camera_table_fits_100_columns_with_ten_long_named_fisheye_cameras():
    """Ten fisheye cameras (fx/fy apart, four coefficients) named as an arena names them: every
    line of the table and its notes within 100 columns, each camera on its own row under a
    shortened name that still tells it apart, the full names listed; eight coefficients
    (FULL_OPENCV) wrap under their column."""
    names = [f"arena_north_east_ceiling_cam_{i:02d}" for i in range(10)]
    rig = _named_rig(names)
    for cam in rig.cameras.values():
        cam.intrinsics.params[1] = cam.intrinsics.params[0] * 1.003  # fy: not fx
        cam.intrinsics.params[4:8] = [-0.0123456, 0.00123456, -1.23456e-05, 2.3456e-06]
    table = camera_table(rig) + "\n" + intrinsics_note(rig)
    assert max(len(line) for line in table.splitlines()) <= TABLE_COLUMNS == 100
    intrinsics, fit = _blocks(camera_table(rig))
    assert len(intrinsics) == len(fit) == 10  # ten distinct short names
    assert all(name.endswith(f"cam_{i:02d}") for i, name in enumerate(intrinsics))
    assert all("/" in row["focal_px"] for row in intrinsics.values())
    assert all(f"k{i}=" in row["distortion"] for row in fit.values() for i in range(1, 5))
    middle = table.split("names shortened: ~ stands for '")[1].split("'")[0]  # all lost one
    assert {short.replace("~", middle) for short in intrinsics} == set(names)
    assert max(len(line) for line in rig_report(rig).splitlines()
               if not line.startswith(("from ", "warning"))) <= 100
    wide = _named_rig(["a_rather_long_camera_name_0", "a_rather_long_camera_name_1",
                       "a_rather_long_camera_name_2"], model="RADIAL")
    for cam in wide.cameras.values():
        cam.intrinsics = CameraIntrinsics("FULL_OPENCV", 4000, 3000, np.r_[
            3012.3, 3015.6, 2001.2, 1498.7, np.linspace(-0.0123456, 0.0123456, 8)])
    table = camera_table(wide)
    assert max(len(line) for line in table.splitlines()) <= 100
    fit = _blocks(table)[1]
    assert all(f"k{i}=" in row["distortion"] for row in fit.values() for i in range(1, 7))
    assert all("p1=" in row["distortion"] for row in fit.values())
    # names alike at their head and tail: the split moves until they read apart
    short = short_names([f"same_prefix_{c}_and_the_same_long_suffix" for c in "ab"], 12)
    assert len(set(short.values())) == 2 and all(len(v) <= 12 for v in short.values())
    assert short_names(["cam0", "a_name_of_twenty_chars"], 12)["cam0"] == "cam0"
    names = ["left_front_camera_0001", "right_rear_camera_0002", "top"]  # each loses another
    listed = " ".join(shortened_line(short_names(names, 12)))
    assert all(f"= {name}" in listed for name in names[:2]) and "top" not in listed


def test_principal_point_wording_says_what_was_done_to_each(rig):
    """One camera per case, as a calibration records it: estimated by the images' folds; resting
    on its prior off the centre (cx 324.0, cy 231.1 OpenCV on 640x480: not "held at the image
    centre"); held exactly at the centre by a final adjustment; given by the user; a ground
    truth's camera (no quality: not said)."""
    names = ["folds", "prior", "centre", "given", "truth"]
    rig = _named_rig(names, model="RADIAL")
    lens = CameraIntrinsics("RADIAL", 640, 480, np.array([500.0, 320.0, 240.0, -0.05, 0.01]))
    for name in names:
        rig.cameras[name].intrinsics = copy.deepcopy(lens)
    rig.cameras["folds"].quality.estimated_intrinsics = ["f", "k1", "k2", "cx", "cy"]
    rig.cameras["folds"].intrinsics.params[1:3] = [327.25, 236.5]
    rig.cameras["prior"].quality.estimated_intrinsics = ["f", "k1", "k2", "aspect", "p1", "p2"]
    rig.cameras["prior"].intrinsics.params[1:3] = [324.5, 231.6]  # COLMAP: OpenCV + 0.5
    rig.cameras["centre"].quality.principal_point_std_px = None  # held: no sigma of its own
    rig.quality.given_intrinsics = {"given": "RADIAL"}
    rig.cameras["truth"].quality = None
    rig.cameras["truth"].intrinsics.params[1:3] = [330.0, 250.0]
    rig.quality.update(principal_point_prior_std_fraction=0.01, held_pp_std_fraction=0.01)
    assert {n: principal_point_case(rig, n) for n in names} == {
        "folds": PrincipalPoint.ESTIMATED, "prior": PrincipalPoint.PRIOR,
        "centre": PrincipalPoint.CENTRE, "given": PrincipalPoint.GIVEN,
        "truth": PrincipalPoint.UNKNOWN}
    intrinsics = _blocks(camera_table(rig))[0]
    assert {n: intrinsics[n]["pp_from"] for n in names} == {
        "folds": "images", "prior": "prior", "centre": "centre", "given": "given", "truth": "-"}
    assert (intrinsics["prior"]["cx"], intrinsics["prior"]["cy"]) == ("324.0", "231.1")
    assert (intrinsics["centre"]["cx"], intrinsics["centre"]["cy"]) == ("319.5", "239.5")
    note = intrinsics_note(rig).replace("\n  ", " ")
    lines = {line.split(":")[0]: line for line in note.splitlines()}
    assert lines["principal point estimated from the images"].endswith(": folds")
    prior = next(line for line in lines.values() if "resting on its prior" in line)
    assert "1 % of the long side around the image centre" in prior
    assert prior.endswith("prior (+4.5, -8.4 px from the centre)") and "centre:" not in prior
    assert lines["principal point held exactly at the image centre"].endswith(": centre")
    assert lines["principal point given (--intrinsics) and kept"].endswith(": given")
    assert "truth (+10.0, +10.0 px from the centre)" in note
    assert "pixel aspect estimated (fx/fy): prior" in note
    assert "decentering distortion estimated (p1, p2: held-out correspondences asked for it): " \
           "prior" in note and note.count("decentering") == 1
    assert "f_std and proj_std of centre include" in note  # its sigmas carry the offset
    rig.quality.change_summary = "focal up to +0.1 %"  # a recalibration: the prior may be moved
    assert "or a previous calibration's estimate" in intrinsics_note(rig).replace("\n  ", " ")


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
    assert rows["cam0"][5] == "-"  # the reference camera's rotation defines the frame
    rig.cameras["cam3"].quality = CameraQuality(0.3, 100, 0.5, rotation_std_deg=0.0421)
    rows = {line.split()[0]: line.split()[1:] for line in layout_table(rig).splitlines()[1:]}
    assert rows["cam3"][5] == "0.042"
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


def upright_rig(with_floor: bool):
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

    rig, wall = upright_rig(with_floor=True)
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


def test_corner_rays_of_a_lens_folding_before_its_corner_stop_at_the_fold():
    """Caliscope's webcams come out with a distortion that folds just short of their corners
    (plausibility.corner_fold_warning); the corners have no ray, and NaN frusta broke the
    layout plot's limits. They take the widest ray the model has in their direction."""
    from densecalib_ros.core.products.scene_ply import corner_rays
    from densecalib_ros.core.types import CameraIntrinsics

    # r_d = r (1 - 0.3 r^2) folds at r = 1.054 (r_d 0.703), short of the corner's 1.147
    webcam = CameraIntrinsics("RADIAL", 1280, 720, np.array([640.0, 640, 360, -0.3, 0.0]))
    assert np.isnan(webcam.to_pycolmap().cam_from_img(np.array([[0.0, 0.0]]))).all()
    rays = corner_rays(webcam)
    assert np.isfinite(rays).all()
    tan_off_axis = np.linalg.norm(rays[:, :2], axis=1) / rays[:, 2]
    # just inside the fold's undistorted radius (r_d at 99 % of the fold's: r = 0.967)
    assert ((tan_off_axis > 0.95) & (tan_off_axis < 1.054)).all()


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
