"""Undistortion (core.undistort, `densecalib undistort`): our remap tables equal OpenCV's
initUndistortRectifyMap for the same camera (pinhole and fisheye), a fisheye's view is capped by
max_fov, and the command writes images and a pinhole calibration with the same extrinsics."""
import json

import cv2
import numpy as np
import pytest

from densecalib_ros.cli import main
from densecalib_ros.core.export import calibration_to_dict, read_calibration, ros_camera_info
from densecalib_ros.core.types import CameraIntrinsics, RigCalibration, RigCamera
from densecalib_ros.core.undistort import pinhole_for, undistortion_maps

RADIAL = CameraIntrinsics("RADIAL", 320, 240, np.array([260.0, 163.0, 118.5, -0.18, 0.04]))
FISHEYE = CameraIntrinsics("OPENCV_FISHEYE", 320, 240,
                           np.array([95.0, 96.0, 161.0, 119.0, 0.03, -0.01, 0.002, 0.0]))


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


def test_command_writes_images_and_pinhole_calibration(tmp_path, capsys):
    pose = np.eye(4)
    pose[:3, 3] = [0.4, 0.0, 0.0]
    rig = RigCalibration("a", {"a": RigCamera("a", RADIAL, np.eye(4)),
                               "b": RigCamera("b", FISHEYE, pose)}, metric_scale=True)
    calib = tmp_path / "calib"
    calib.mkdir()
    (calib / "calibration.json").write_text(json.dumps(calibration_to_dict(rig)))
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
