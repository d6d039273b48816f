"""Undistortion (core.products.undistort, `densecalib undistort`): our remap tables equal OpenCV's
initUndistortRectifyMap for the same camera (pinhole and fisheye), a fisheye's view is capped by
max_fov, and the command writes images and a pinhole calibration with the same extrinsics."""
import json
import logging

import cv2
import numpy as np
import pytest

from densecalib_ros.cli import main
from densecalib_ros.core.io.camera_info import ros_camera_info
from densecalib_ros.core.io.export import calibration_to_dict, read_calibration
from densecalib_ros.core.types import CameraIntrinsics, RigCalibration, RigCamera, RigQuality
from densecalib_ros.core.products.undistort import pinhole_for, undistortion_maps

RADIAL = CameraIntrinsics("RADIAL", 320, 240, np.array([260.0, 163.0, 118.5, -0.18, 0.04]))
FISHEYE = CameraIntrinsics("OPENCV_FISHEYE", 320, 240,
                           np.array([95.0, 96.0, 161.0, 119.0, 0.03, -0.01, 0.002, 0.0]))


def _write_calibration(rig, folder):
    folder.mkdir()
    (folder / "calibration.json").write_text(json.dumps(calibration_to_dict(rig)))
    return folder


def _write_video(path, frames, fps):
    """An MJPG .avi of BGR frames (H, W, 3) uint8."""
    height, width = frames[0].shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, (width, height))
    for frame in frames:
        writer.write(frame)
    writer.release()


def _opencv_maps(source, target):
    info = ros_camera_info("c", source)
    k = np.array(info["camera_matrix"]["data"]).reshape(3, 3)
    d = np.array(info["distortion_coefficients"]["data"])
    k_new = np.array(ros_camera_info("c", target)["camera_matrix"]["data"]).reshape(3, 3)
    size = (target.width, target.height)
    if info["distortion_model"] == "equidistant":
        return cv2.fisheye.initUndistortRectifyMap(k, d, np.eye(3), k_new, size, cv2.CV_32FC1)
    return cv2.initUndistortRectifyMap(k, d, None, k_new, size, cv2.CV_32FC1)


@pytest.mark.parametrize("source", [RADIAL, FISHEYE], ids=["radial", "fisheye"])
def test_maps_equal_opencv(source):
    target = pinhole_for(source, max_fov_deg=100.0)
    ours = undistortion_maps(source, target)
    theirs = _opencv_maps(source, target)
    inside = (ours[0] >= 0) & (ours[0] < source.width - 1) & (ours[1] >= 0) & \
        (ours[1] < source.height - 1)
    assert inside.mean() > 0.5
    for a, b in zip(ours, theirs):
        assert np.abs(a[inside] - b[inside]).max() < 0.01


def test_pinhole_keeps_the_focal_and_caps_a_fisheye_view():
    assert pinhole_for(RADIAL).params.tolist() == [260.0, 260.0, 160.0, 120.0]
    # the fisheye's own focal (95.5 px) spans 118.4 deg across 320 px: under a 120 deg cap it stays
    assert pinhole_for(FISHEYE, max_fov_deg=120.0).params[0] == pytest.approx(95.5)
    narrow = pinhole_for(FISHEYE, max_fov_deg=60.0)
    assert 2 * np.degrees(np.arctan(160.0 / narrow.params[0])) == pytest.approx(60.0)


def test_command_writes_images_and_pinhole_calibration(tmp_path, capsys, caplog):
    pose = np.eye(4)
    pose[:3, 3] = [0.4, 0.0, 0.0]
    rig = RigCalibration("a", {"a": RigCamera("a", RADIAL, np.eye(4)),
                               "b": RigCamera("b", FISHEYE, pose)}, metric_scale=True)
    calib = _write_calibration(rig, tmp_path / "calib")
    images = tmp_path / "images"
    for name in ("a", "b"):
        (images / name).mkdir(parents=True)
        for t in range(2):
            cv2.imwrite(str(images / name / f"{t:04d}.jpg"), np.full((240, 320, 3), 90, np.uint8))
    out = tmp_path / "undistorted"
    assert main(["undistort", str(calib), "--images", str(images), "--out", str(out)]) == 0
    assert "4 undistorted image(s) of 2 camera(s)" in capsys.readouterr().out
    assert cv2.imread(str(out / "b" / "0001.png")).shape == (240, 320, 3)
    result = read_calibration(out)
    assert {c.intrinsics.model for c in result.cameras.values()} == {"PINHOLE"}
    assert np.allclose(result.cameras["b"].cam_from_rig, pose) and result.metric_scale
    assert "distortion_model: plumb_bob" in (out / "b.yaml").read_text()
    # a wrong size is refused and leaves the earlier output untouched
    cv2.imwrite(str(images / "a" / "0000.jpg"), np.zeros((100, 100, 3), np.uint8))
    assert main(["undistort", str(calib), "--images", str(images), "--out", str(out)]) == 2
    assert (out / "b" / "0001.png").exists()
    # a calibration that is not an earlier output of undistort is not replaced
    other = _write_calibration(rig, tmp_path / "other")
    with caplog.at_level(logging.ERROR):
        assert main(["undistort", str(calib), "--images", str(images), "--out", str(other)]) == 2
    assert "holds a calibration, not an earlier output of undistort" in caplog.text
    assert sorted(p.name for p in other.iterdir()) == ["calibration.json"]


@pytest.mark.parametrize("lens", [RADIAL, FISHEYE], ids=["radial", "fisheye"])
def test_stereo_pair_is_rectified_as_opencv_rectifies_it(lens, tmp_path, capsys):
    """--stereo-pair: the images are resampled as cv2.initUndistortRectifyMap (fisheye: its
    cv2.fisheye version) resamples them with the pair's R and P from `export --format
    ros-stereo`, and the calibration written is the rectified pair: PINHOLE cameras from P, the
    right one translated along x only, with no rotation."""
    import yaml
    from scipy.spatial.transform import Rotation

    pose = np.eye(4)
    pose[:3, :3] = Rotation.from_euler("xyz", [2, -4, 1], degrees=True).as_matrix()
    pose[:3, 3] = [-0.3, 0.01, 0.02]
    third = np.eye(4)
    third[:3, 3] = [0.0, -0.3, 0.0]
    floor_from_rig = np.eye(4)
    floor_from_rig[:3, :3] = Rotation.from_euler("xyz", [-100, 3, 20], degrees=True).as_matrix()
    floor_from_rig[:3, 3] = [0.2, -0.1, 1.4]

    def height(calibration, name):  # of the camera's centre, in its calibration's floor frame
        centre = np.linalg.inv(calibration.cameras[name].cam_from_rig)[:, 3]
        return (np.reshape(calibration.quality.floor["floor_from_rig"], (4, 4)) @ centre)[2]

    rig = RigCalibration("a", {"a": RigCamera("a", lens, np.eye(4)),
                               "b": RigCamera("b", lens, pose),
                               "c": RigCamera("c", RADIAL, third)}, metric_scale=True,
                         quality=RigQuality(floor={
                             "floor_from_rig": floor_from_rig.ravel().tolist(), "num_points": 100,
                             "rms": 0.01, "camera_heights": {"a": 1.0, "b": 1.0, "c": 1.0}}))
    calib = tmp_path / "calibration.json"
    calib.write_text(json.dumps(calibration_to_dict(rig)))
    images = tmp_path / "images"
    images.mkdir()
    rng = np.random.default_rng(3)
    texture = cv2.resize(rng.integers(0, 256, (30, 40, 3), dtype=np.uint8), (320, 240),
                         interpolation=cv2.INTER_CUBIC)
    for name in ("a", "b", "c"):
        cv2.imwrite(str(images / f"{name}.png"), texture)
    out = tmp_path / "rectified"
    assert main(["undistort", str(calib), "--images", str(images), "--out", str(out),
                 "--stereo-pair", "a", "b"]) == 0
    assert "2 rectified image(s) of 2 camera(s)" in capsys.readouterr().out
    # the pair named right camera first would come out mirrored (negative disparities): refused
    assert main(["undistort", str(calib), "--images", str(images), "--out",
                 str(tmp_path / "reversed"), "--stereo-pair", "b", "a"]) == 2
    assert not (tmp_path / "reversed").exists()
    assert main(["export", str(calib), "--format", "ros-stereo", "--pair", "a", "b",
                 "--out", str(tmp_path / "stereo")]) == 0
    result = read_calibration(out)
    assert sorted(result.cameras) == ["a", "b"] and result.reference_camera == "a"
    right = result.cameras["b"].cam_from_rig
    np.testing.assert_allclose(right[:3, :3], np.eye(3), atol=1e-9)
    assert right[0, 3] == pytest.approx(-np.linalg.norm([-0.3, 0.01, 0.02]))
    assert np.abs(right[1:3, 3]).max() < 1e-9
    for name in ("a", "b"):  # the floor frame follows the new rig frame
        assert height(result, name) == pytest.approx(height(rig, name), abs=1e-9)
    assert sorted(result.quality.floor["camera_heights"]) == ["a", "b"]
    for name in ("a", "b"):
        info = yaml.safe_load((tmp_path / "stereo" / f"{name}.yaml").read_text())
        k = np.array(info["camera_matrix"]["data"]).reshape(3, 3)
        d = np.array(info["distortion_coefficients"]["data"])
        r = np.array(info["rectification_matrix"]["data"]).reshape(3, 3)
        p = np.array(info["projection_matrix"]["data"]).reshape(3, 4)
        init = cv2.fisheye.initUndistortRectifyMap if lens is FISHEYE else \
            cv2.initUndistortRectifyMap
        map_x, map_y = init(k, d, r, p, (320, 240), cv2.CV_32FC1)
        np.testing.assert_allclose(result.cameras[name].intrinsics.params,
                                   [p[0, 0], p[1, 1], p[0, 2] + 0.5, p[1, 2] + 0.5])
        theirs = cv2.remap(texture, map_x, map_y, cv2.INTER_LINEAR,
                           borderMode=cv2.BORDER_CONSTANT)
        ours = cv2.imread(str(out / f"{name}.png"))
        inside = (map_x > 1) & (map_x < 318) & (map_y > 1) & (map_y < 238)
        assert inside.mean() > 0.6
        assert np.abs(ours[inside].astype(int) - theirs[inside]).max() <= 1
        # its camera_info is the rectified pair's: the right one's P carries the baseline
        # (Tx = -f B), which stereo_image_proc reads
        written = yaml.safe_load((out / f"{name}.yaml").read_text())
        np.testing.assert_allclose(written["projection_matrix"]["data"], p.ravel(), atol=1e-9)
        np.testing.assert_allclose(written["rectification_matrix"]["data"], np.eye(3).ravel())
        assert written["distortion_coefficients"]["data"] == [0.0] * 5


def test_command_undistorts_videos_frame_by_frame(tmp_path, capsys, caplog):
    """--videos: every frame of each camera's video, resampled with the same tables as the
    images are (compared frame by frame with the image path on the decoded input frames), at
    the same frame rate; a missing camera is skipped, a video of another size refused."""
    rig = RigCalibration("a", {"a": RigCamera("a", FISHEYE, np.eye(4)),
                               "b": RigCamera("b", RADIAL, np.eye(4))})
    calib = _write_calibration(rig, tmp_path / "calib")
    rng = np.random.default_rng(0)
    texture = cv2.resize(rng.integers(0, 255, (24, 32, 3), dtype=np.uint8), (320, 240),
                         interpolation=cv2.INTER_CUBIC)
    videos = tmp_path / "videos"
    videos.mkdir()
    _write_video(videos / "a.avi", [np.roll(texture, 7 * k, axis=1) for k in range(6)], 15.0)
    out = tmp_path / "undistorted"
    assert main(["undistort", str(calib), "--videos", str(videos), "--out", str(out),
                 "--codec", "MJPG"]) == 0
    assert "1 undistorted video(s) (6 frames) of 1 camera(s)" in capsys.readouterr().out
    target = read_calibration(out).cameras["a"].intrinsics
    assert target.model == "PINHOLE" and "b" not in read_calibration(out).cameras
    map_x, map_y = undistortion_maps(FISHEYE, target)
    source, result = cv2.VideoCapture(str(videos / "a.avi")), cv2.VideoCapture(str(out / "a.avi"))
    assert result.get(cv2.CAP_PROP_FPS) == pytest.approx(15.0)
    for _ in range(6):
        expected = cv2.remap(source.read()[1], map_x, map_y, cv2.INTER_LINEAR,
                             borderMode=cv2.BORDER_CONSTANT).astype(float)
        got = result.read()[1].astype(float)
        assert got.shape == (target.height, target.width, 3)
        assert 10 * np.log10(255 ** 2 / np.mean((got - expected) ** 2)) > 30  # PSNR, dB
    assert not result.read()[0]
    _write_video(videos / "b.avi", [np.zeros((120, 160, 3), np.uint8)], 15.0)
    with caplog.at_level("ERROR"):
        assert main(["undistort", str(calib), "--videos", str(videos), "--out", str(out)]) == 2
    assert "b.avi is 160x120, but its camera was calibrated at 320x240" in caplog.text
    assert (out / "a.avi").exists()  # the earlier output is untouched


def test_stereo_pair_videos_are_rectified(tmp_path, capsys):
    """--videos with --stereo-pair: both videos' frames rectified with the pair's tables, the
    output calibration the rectified pair (the right camera translated along x only)."""
    pose = np.eye(4)
    pose[:3, 3] = [-0.3, 0.01, 0.02]
    rig = RigCalibration("a", {"a": RigCamera("a", RADIAL, np.eye(4)),
                               "b": RigCamera("b", RADIAL, pose)}, metric_scale=True)
    calib = _write_calibration(rig, tmp_path / "calib")
    videos = tmp_path / "videos"
    videos.mkdir()
    for name in ("a", "b"):
        _write_video(videos / f"{name}.avi", [np.full((240, 320, 3), 40 * k, np.uint8)
                                              for k in range(4)], 10.0)
    out = tmp_path / "rectified"
    assert main(["undistort", str(calib), "--videos", str(videos), "--out", str(out),
                 "--stereo-pair", "a", "b"]) == 0
    assert "2 rectified video(s) (8 frames) of 2 camera(s)" in capsys.readouterr().out
    pair = read_calibration(out)
    right_from_left = pair.cameras["b"].cam_from_rig
    assert np.allclose(right_from_left[:3, :3], np.eye(3), atol=1e-9)
    assert np.allclose(right_from_left[1:3, 3], 0.0, atol=1e-9)
    for name in ("a", "b"):
        cap = cv2.VideoCapture(str(out / f"{name}.mp4"))
        assert int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) == 4


@pytest.mark.parametrize("options, message", [
    (["--alpha", "0.5"], "--alpha goes with --stereo-pair"),
    (["--codec", "MJPG"], "--codec goes with --videos"),
    (["--stereo-pair", "a", "b", "--max-fov", "10"], "a stereo pair's view is --alpha's"),
    (["--max-fov", "180"], "--max-fov 180: give an angle between 0 and 180 deg")])
def test_options_of_another_mode_are_refused(tmp_path, caplog, options, message):
    """Each of these was taken and ignored (--max-fov beside --stereo-pair changed nothing)."""
    pose = np.eye(4)
    pose[:3, 3] = [-0.4, 0.0, 0.0]
    rig = RigCalibration("a", {"a": RigCamera("a", RADIAL, np.eye(4)),
                               "b": RigCamera("b", RADIAL, pose)})
    calib = _write_calibration(rig, tmp_path / "calib")
    (tmp_path / "images").mkdir()
    for name in ("a", "b"):
        cv2.imwrite(str(tmp_path / "images" / f"{name}.png"), np.full((240, 320, 3), 90, np.uint8))
    with caplog.at_level(logging.ERROR):
        assert main(["undistort", str(calib), "--images", str(tmp_path / "images"), "--out",
                     str(tmp_path / "out"), *options]) == 2
    assert message in caplog.text and not (tmp_path / "out").exists()
