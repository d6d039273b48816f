"""The floor under a rig (core.products.floor, `calibrate --floor`): among the planes of its scene
points, the one with every camera above it that faces their image-up (or, seen from straight above,
the largest they all look down on); walls, a ceiling and a smaller table top are passed over; a
generated room calibrated from its images gets its true floor, camera heights in metres with a
known baseline, and anipose's world becomes the floor frame; `densecalib floor` finds it again
in a written calibration."""
import json
import tomllib

import cv2
import numpy as np
import pytest

from densecalib_ros.cli import main
from densecalib_ros.core.errors import InputError
from densecalib_ros.core.io.export import read_calibration
from densecalib_ros.core.products.floor import find_floor
from densecalib_ros.core.synthetic import RigSpec, generate_rig, write_rig
from densecalib_ros.core.types import CameraIntrinsics, RigCalibration, RigCamera, RigQuality

LENS = CameraIntrinsics("RADIAL", 640, 480, np.array([500.0, 320.0, 240.0, 0.0, 0.0]))


def _camera(centre, target, up=(0.0, 0.0, 1.0)):
    """cam_from_world of an upright camera (image x horizontal) at centre looking at target."""
    z = np.asarray(target, float) - centre
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    if np.linalg.norm(x) < 1e-9:  # looking straight down: any yaw
        x = np.array([1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    pose = np.eye(4)
    pose[:3, :3] = np.stack([x, np.cross(z, x), z])
    pose[:3, 3] = -pose[:3, :3] @ centre
    return pose


def _room(rng):
    """World points (z up, metres) of a 6 x 4 x 3 m room: floor (z = 0), a table top (z = 0.8,
    smaller), the ceiling and the far wall, each with a little noise."""
    def patch(n, x, y, z):
        return np.column_stack([rng.uniform(*x, n) if isinstance(x, tuple) else np.full(n, x),
                                rng.uniform(*y, n) if isinstance(y, tuple) else np.full(n, y),
                                rng.uniform(*z, n) if isinstance(z, tuple) else np.full(n, z)])
    pts = np.vstack([patch(900, (-3, 3), (-2, 2), 0.0), patch(300, (-0.6, 0.6), (-0.4, 0.4), 0.8),
                     patch(700, (-3, 3), (-2, 2), 3.0), patch(1200, (-3, 3), 2.0, (0, 3))])
    return pts + rng.normal(0, 0.003, pts.shape)


def _rig(poses_world):
    """RigCalibration of cam_from_world poses, the rig frame = the first camera's."""
    rig_from_world = poses_world[0]
    cams = {f"cam{i}": RigCamera(f"cam{i}", LENS, p @ np.linalg.inv(rig_from_world))
            for i, p in enumerate(poses_world)}
    return RigCalibration("cam0", cams), rig_from_world


def _check(floor, rig_from_world, heights):
    rig_from_floor = np.linalg.inv(floor.floor_from_rig)
    up_rig = rig_from_world[:3, :3] @ [0.0, 0.0, 1.0]
    assert np.degrees(np.arccos(rig_from_floor[:3, 2] @ up_rig)) < 0.5
    for name, h in heights.items():
        assert floor.camera_heights[name] == pytest.approx(h, abs=0.01)


def test_floor_not_wall_ceiling_or_table():
    rng = np.random.default_rng(0)
    world = _room(rng)
    centres = [np.array([x, -1.8, 1.6]) for x in (-2.0, 0.0, 2.0)]  # side cameras, 30 deg down
    poses = [_camera(c, [0.0, 1.0, 0.0]) for c in centres]
    rig, rig_from_world = _rig(poses)
    pts_rig = world @ rig_from_world[:3, :3].T + rig_from_world[:3, 3]
    floor = find_floor(pts_rig, rig)
    _check(floor, rig_from_world, {f"cam{i}": 1.6 for i in range(3)})
    assert 850 <= floor.num_points <= 960 and floor.rms < 0.005
    # the floor frame's x is the reference camera's view laid flat on the floor
    rig_from_floor = np.linalg.inv(floor.floor_from_rig)
    flat_view = np.array([2.0, 2.8, 0.0]) / np.hypot(2.0, 2.8)  # cam0 (-2, -1.8) -> (0, 1)
    assert rig_from_floor[:3, 0] @ (rig_from_world[:3, :3] @ flat_view) > 0.9999


def test_top_view_rig_takes_the_largest_plane_all_cameras_look_down_on():
    rng = np.random.default_rng(1)
    world = _room(rng)
    world = world[world[:, 2] < 2.0]  # no ceiling points: the cameras hang below it
    poses = [_camera(np.array([x, y, 2.5]), [x, y, 0.0]) for x, y in ((-1, 0), (1, 0.5), (0, -1))]
    for pose, yaw in zip(poses, (0.0, 2.0, 4.0)):  # image-ups any way round
        c, s = np.cos(yaw), np.sin(yaw)
        pose[:3] = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]]) @ pose[:3]
    rig, rig_from_world = _rig(poses)
    pts_rig = world @ rig_from_world[:3, :3].T + rig_from_world[:3, 3]
    with pytest.raises(InputError, match="use the top view"):  # their image-ups say nothing
        find_floor(pts_rig, rig)
    floor = find_floor(pts_rig, rig, view="top")
    _check(floor, rig_from_world, {f"cam{i}": 2.5 for i in range(3)})


def test_no_floor_is_an_error():
    """Level cameras facing a wall see what cameras looking down on a floor see; upright, the
    wall is no floor, and nothing else is."""
    rng = np.random.default_rng(2)
    wall = np.column_stack([rng.uniform(-3, 3, 500), np.full(500, 2.0), rng.uniform(0, 3, 500)])
    poses = [_camera(np.array([x, -2.0, 1.5]), [x, 2.0, 1.5]) for x in (-1.0, 1.0)]  # level
    rig, rig_from_world = _rig(poses)
    with pytest.raises(InputError, match="No floor found.*500 points, tilt 90 deg"):
        find_floor(wall @ rig_from_world[:3, :3].T + rig_from_world[:3, 3], rig)


def test_calibrate_floor_on_a_generated_room(tmp_path, capsys):
    rig = generate_rig(RigSpec(lenses="ideal", num_cameras=4, camera_model="RADIAL", width=640, height=480,
                               num_time_steps=2, seed=1))
    write_rig(rig, tmp_path / "images")
    baseline = float(np.linalg.norm(rig.center(0) - rig.center(1)))
    out = tmp_path / "out"
    assert main(["calibrate", "--images", str(tmp_path / "images"), "--out", str(out),
                 "--floor", "--known-baseline", "cam0", "cam1", str(baseline),
                 "--consensus-runs", "1", "--threads", "1"]) == 0
    calibration = read_calibration(out)
    floor = calibration.quality.floor
    rig_from_floor = np.linalg.inv(np.array(floor["floor_from_rig"]).reshape(4, 4))
    up_rig = rig.cam_from_world[0][:3, :3] @ [0.0, 0.0, 1.0]  # the scene's floor is z = 0
    assert np.degrees(np.arccos(rig_from_floor[:3, 2] @ up_rig)) < 1.0
    for i, name in enumerate(rig.names):
        assert floor["camera_heights"][name] == pytest.approx(rig.center(i)[2], rel=0.02)
    assert main(["report", str(out)]) == 0
    assert "floor: " in capsys.readouterr().out
    assert main(["export", str(out), "--format", "anipose", "--out", str(tmp_path / "c.toml")]) == 0
    toml = tomllib.loads((tmp_path / "c.toml").read_text())
    for i, name in enumerate(rig.names):
        cam = toml[f"cam_{i}"]
        rot = cv2.Rodrigues(np.array(cam["rotation"]))[0]
        centre = -rot.T @ np.array(cam["translation"])  # in anipose's world: the floor frame
        assert centre[2] == pytest.approx(rig.center(i)[2], rel=0.02)
    assert "world = the floor frame" in (tmp_path / "c.toml").read_text()

    # `densecalib floor` finds it again in the saved model of a calibration made without it
    path = out / "calibration.json"
    data = json.loads(path.read_text())
    data["quality"].pop("floor")
    data["quality"]["warnings"] = ["no floor frame: (as if not found)"]
    path.write_text(json.dumps(data))
    assert main(["floor", str(out), "--dry-run"]) == 0
    assert "floor: " in capsys.readouterr().out and json.loads(path.read_text()) == data
    assert main(["floor", str(out)]) == 0
    again = read_calibration(out).quality
    assert again.warnings == []
    np.testing.assert_allclose(again.floor["floor_from_rig"], floor["floor_from_rig"],
                               atol=1e-9)
    # without the model there are no scene points: an error, the file untouched
    bare = tmp_path / "bare"
    bare.mkdir()
    (bare / "calibration.json").write_text(json.dumps(data))
    assert main(["floor", str(bare)]) == 2
    assert json.loads((bare / "calibration.json").read_text()) == data


def test_a_recalibration_that_lost_the_floor_says_so():
    """Exports would change their world from the floor frame to the rig frame without a word."""
    from densecalib_ros.core.products.floor import warn_if_floor_lost

    lens = CameraIntrinsics("RADIAL", 640, 480, np.array([500.0, 320.0, 240.0, 0.0, 0.0]))
    cameras = {n: RigCamera(n, lens, np.eye(4)) for n in ("a", "b")}
    floor = {"floor_from_rig": np.eye(4).ravel().tolist(), "num_points": 10, "rms": 0.01,
             "camera_heights": {"a": 1.0, "b": 1.0}}
    previous = RigCalibration("a", cameras, quality=RigQuality(floor=floor))
    new = RigCalibration("a", cameras)
    warn_if_floor_lost(new, None, "add --floor")
    warn_if_floor_lost(new, RigCalibration("a", cameras), "add --floor")
    assert new.quality.warnings == []
    warn_if_floor_lost(new, previous, "add --floor")
    assert new.quality.warnings == [
        "no floor frame: the previous calibration had one, this one has none; add --floor"]
    kept = RigCalibration("a", cameras, quality=RigQuality(floor=floor))
    warn_if_floor_lost(kept, previous, "add --floor")
    assert kept.quality.warnings == []
