"""Rectified stereo pairs (core.products.stereo; `densecalib export --format
ros-stereo|opencv-stereo`): the files, read as camera_info_manager and OpenCV read them and used as
stereo_image_proc and image_geometry use them (undistort + rectify each pixel with R and P, depth
from disparity with the right camera's Tx), put every point of the scene on one row in both images
at its true depth; pairs that cannot be rectified are refused with what to do."""
import json
import logging
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from sfm_fixtures import pose as _pose

from densecalib_ros.cli import main
from densecalib_ros.core.errors import InputError
from densecalib_ros.core.io.export import calibration_to_dict
from densecalib_ros.core.method.known_intrinsics import read_known_intrinsics
from densecalib_ros.core.products.stereo import stereo_pair
from densecalib_ros.core.types import CameraIntrinsics, RigCalibration, RigCamera

LENSES = {
    "pinhole": (CameraIntrinsics("RADIAL", 1024, 768,
                                 np.array([810.0, 515.3, 380.2, -0.12, 0.03])),
                CameraIntrinsics("RADIAL", 1024, 768,
                                 np.array([795.0, 509.9, 385.0, 0.04, -0.01]))),
    "fisheye": (CameraIntrinsics("OPENCV_FISHEYE", 1280, 960, np.array(
                    [402.0, 403.5, 641.0, 478.5, 0.05, -0.02, 0.004, -0.0007])),
                CameraIntrinsics("OPENCV_FISHEYE", 1280, 960, np.array(
                    [398.0, 399.0, 636.0, 482.0, 0.04, -0.01, 0.002, -0.0004]))),
}


def _rig(lens="pinhole", right_pose=None, metric=True):
    """Camera "b" 12 cm right of the reference "a", slightly turned; listed first so that the
    automatic left-to-right order has something to do."""
    a, b = LENSES[lens]
    pose_b = _pose([1, -3, 2], [-0.12, 0.004, 0.01]) if right_pose is None else right_pose
    return RigCalibration("a", {"b": RigCamera("b", b, pose_b), "a": RigCamera("a", a, np.eye(4))},
                          metric_scale=metric)


def _write(rig, tmp_path):
    path = tmp_path / "calibration.json"
    path.write_text(json.dumps(calibration_to_dict(rig)))
    return path


def _rectified(rig, name, pts_rig, info, fisheye):
    """Pixels of rig-frame points in camera `name` (COLMAP's projection, OpenCV pixel centres),
    rectified as image_geometry's rectifyPoint does with the camera_info dict."""
    cam = rig.cameras[name]
    x_cam = pts_rig @ cam.cam_from_rig[:3, :3].T + cam.cam_from_rig[:3, 3]
    pixels = cam.intrinsics.to_pycolmap().img_from_cam(x_cam) - 0.5
    k = np.array(info["camera_matrix"]["data"]).reshape(3, 3)
    d = np.array(info["distortion_coefficients"]["data"])
    r = np.array(info["rectification_matrix"]["data"]).reshape(3, 3)
    p = np.array(info["projection_matrix"]["data"]).reshape(3, 4)
    undistort = cv2.fisheye.undistortPoints if fisheye else cv2.undistortPoints
    return undistort(pixels.reshape(-1, 1, 2), k, d, R=r, P=p).reshape(-1, 2)


def _scene(seed=0, n=300):
    return np.random.default_rng(seed).uniform([-1, -1, 2], [1, 1, 6], (n, 3))


@pytest.mark.parametrize("lens", ["pinhole", "fisheye"])
def test_ros_stereo_files_put_points_on_one_row_at_their_depth(lens, tmp_path, capsys):
    rig = _rig(lens)
    out = tmp_path / "stereo"
    assert main(["export", str(_write(rig, tmp_path)), "--format", "ros-stereo",
                 "--out", str(out)]) == 0
    assert "a left, b right" in capsys.readouterr().out
    left, right = (yaml.safe_load((out / f"{n}.yaml").read_text()) for n in ("a", "b"))
    assert left["camera_name"] == "a" and right["distortion_model"] == left["distortion_model"]
    assert left["distortion_model"] == ("equidistant" if lens == "fisheye" else "plumb_bob")
    pts = _scene()
    ul = _rectified(rig, "a", pts, left, lens == "fisheye")
    ur = _rectified(rig, "b", pts, right, lens == "fisheye")
    # epipolar lines are rows (cv2.undistortPoints' iterations leave ~1e-4 px)
    assert np.abs(ul[:, 1] - ur[:, 1]).max() < 1e-3
    p_left = np.array(left["projection_matrix"]["data"]).reshape(3, 4)
    p_right = np.array(right["projection_matrix"]["data"]).reshape(3, 4)
    assert p_left[0, 3] == 0 and p_right[1, 3] == 0 and p_right[0, 3] < 0
    # image_geometry's StereoCameraModel: baseline = -Tx / fx', Z = fx' B / (d - (cx_l - cx_r))
    baseline = -p_right[0, 3] / p_right[0, 0]
    assert baseline == pytest.approx(np.linalg.norm([-0.12, 0.004, 0.01]), rel=1e-9)
    depth = p_left[0, 0] * baseline / (ul[:, 0] - ur[:, 0] - (p_left[0, 2] - p_right[0, 2]))
    r_left = np.array(left["rectification_matrix"]["data"]).reshape(3, 3)
    true_depth = (pts @ r_left.T)[:, 2]  # rig frame = camera a
    assert np.abs(depth / true_depth - 1).max() < 1e-5


def test_a_degenerate_opencv_view_falls_back_to_a_centred_one(caplog):
    """A fisheye seeing beyond 180 deg across its diagonal (f = 95 px at 320x240) makes
    cv2.fisheye.stereoRectify's view degenerate (principal point hundreds of pixels outside the
    image); the pair then gets a centred view with the same rotations that still puts points
    on one row at their depth, and Q gives them back."""
    lens = CameraIntrinsics("OPENCV_FISHEYE", 320, 240,
                            np.array([95.0, 96.0, 161.0, 119.0, 0.03, -0.01, 0.002, 0.0]))
    pose = _pose([2, -4, 1], [-0.3, 0.01, 0.02])
    rig = RigCalibration("a", {"a": RigCamera("a", lens, np.eye(4)),
                               "b": RigCamera("b", lens, pose)}, metric_scale=True)
    caplog.set_level(logging.WARNING)
    rect = stereo_pair(rig, None)
    assert "degenerate" in caplog.text
    for p in (rect.projection_left, rect.projection_right):
        assert np.allclose(p[:2, 2], [159.5, 119.5]) and p[0, 0] == pytest.approx(95.5)
    pts = _scene()
    pts = pts[pts[:, 2] > 3]
    infos = {name: {"camera_matrix": {"data": k.ravel()}, "distortion_coefficients": {"data": d},
                    "rectification_matrix": {"data": r.ravel()},
                    "projection_matrix": {"data": p.ravel()}}
             for name, k, d, r, p in (
                 ("a", rect.k_left, rect.d_left, rect.rect_from_left, rect.projection_left),
                 ("b", rect.k_right, rect.d_right, rect.rect_from_right, rect.projection_right))}
    ul, ur = (_rectified(rig, n, pts, infos[n], True) for n in ("a", "b"))
    assert np.abs(ul[:, 1] - ur[:, 1]).max() < 1e-6
    xyd = np.column_stack([ul, ul[:, 0] - ur[:, 0]]).reshape(-1, 1, 3)
    got = cv2.perspectiveTransform(xyd, rect.disparity_to_depth).reshape(-1, 3)
    assert np.abs(got - pts @ rect.rect_from_left.T).max() < 1e-6


def test_opencv_stereo_file_holds_the_pair_and_reads_back(tmp_path, capsys):
    rig = _rig("pinhole")
    out = tmp_path / "stereo.yml"
    assert main(["export", str(_write(rig, tmp_path)), "--format", "opencv-stereo",
                 "--pair", "a", "b", "--out", str(out)]) == 0
    fs = cv2.FileStorage(str(out), cv2.FILE_STORAGE_READ)
    rot, t = fs.getNode("R").mat(), fs.getNode("T").mat().ravel()
    b_from_a = rig.cameras["b"].cam_from_rig
    assert np.allclose(rot, b_from_a[:3, :3], atol=1e-12) and np.allclose(t, b_from_a[:3, 3])
    # E: x_b^T E x_a = 0 for normalised coordinates of any scene point
    pts = _scene()
    xa = pts / pts[:, 2:]
    xb_cam = pts @ rot.T + t
    xb = xb_cam / xb_cam[:, 2:]
    assert np.abs(np.einsum("ij,jk,ik->i", xb, fs.getNode("E").mat(), xa)).max() < 1e-12
    # Q: (x, y, disparity) of rectified pixels -> the point in the rectified left frame
    info = {k: {"data": fs.getNode(key).mat().ravel().tolist()} for k, key in (
        ("camera_matrix", "K1"), ("distortion_coefficients", "D1"),
        ("rectification_matrix", "R1"), ("projection_matrix", "P1"))}
    ul = _rectified(rig, "a", pts, info, False)
    info.update({k: {"data": fs.getNode(key).mat().ravel().tolist()} for k, key in (
        ("camera_matrix", "K2"), ("distortion_coefficients", "D2"),
        ("rectification_matrix", "R2"), ("projection_matrix", "P2"))})
    ur = _rectified(rig, "b", pts, info, False)
    xyd = np.column_stack([ul, ul[:, 0] - ur[:, 0]]).reshape(-1, 1, 3)
    got = cv2.perspectiveTransform(xyd, fs.getNode("Q").mat()).reshape(-1, 3)
    assert np.abs(got - pts @ fs.getNode("R1").mat().T).max() < 1e-4
    assert fs.getNode("image_width").real() == 1024 and fs.getNode("fisheye_model").real() == 0
    # read back as given intrinsics, named by the file itself
    known = read_known_intrinsics([str(out)])
    assert set(known) == {"a", "b"}
    for name, intr in known.items():
        x = pts @ rig.cameras[name].cam_from_rig[:3, :3].T + rig.cameras[name].cam_from_rig[:3, 3]
        assert (intr.width, intr.height) == (1024, 768)
        assert np.abs(intr.to_pycolmap().img_from_cam(x)
                      - rig.cameras[name].intrinsics.to_pycolmap().img_from_cam(x)).max() < 1e-6


def test_pair_order_and_refusals(tmp_path, caplog):
    rig = _rig("pinhole")
    assert (stereo_pair(rig, None).left, stereo_pair(rig, None).right) == ("a", "b")
    # a named pair in the wrong order: OpenCV rectifies it (negative disparities), ROS refuses it
    assert stereo_pair(rig, ["b", "a"], left_to_right=False).right_is_right is False
    with pytest.raises(InputError, match="--pair a b"):
        stereo_pair(rig, ["b", "a"])
    vertical = _rig("pinhole", _pose([0, 0, 0], [0.0, -0.15, 0.0]))
    with pytest.raises(InputError, match="one above the other.*opencv-stereo"):
        stereo_pair(vertical, None)
    assert not stereo_pair(vertical, None, left_to_right=False).horizontal
    mixed = RigCalibration("a", {"a": RigCamera("a", LENSES["pinhole"][0], np.eye(4)),
                                 "b": RigCamera("b", LENSES["fisheye"][0],
                                                _pose([0, 0, 0], [-0.1, 0, 0]))})
    with pytest.raises(InputError, match="mix a fisheye and a pinhole.*undistort"):
        stereo_pair(mixed, None)
    sizes = RigCalibration("a", {"a": RigCamera("a", LENSES["pinhole"][0], np.eye(4)),
                                 "b": RigCamera("b", CameraIntrinsics("RADIAL", 640, 480, np.array(
                                     [500.0, 320.0, 240.0, 0.0, 0.0])),
                                     _pose([0, 0, 0], [-0.1, 0, 0]))})
    with pytest.raises(InputError, match="different image sizes"):
        stereo_pair(sizes, None)
    with pytest.raises(InputError, match="no camera 'c'.*b, a"):
        stereo_pair(rig, ["a", "c"])
    three = RigCalibration("a", dict(rig.cameras, c=RigCamera("c", LENSES["pinhole"][0],
                                                              _pose([0, 0, 0], [0.1, 0, 0]))))
    with pytest.raises(InputError, match="3 cameras.*--pair LEFT RIGHT"):
        stereo_pair(three, None)
    assert (stereo_pair(three, ["c", "a"]).left, stereo_pair(three, ["c", "a"]).right) == ("c", "a")
    calib = _write(rig, tmp_path)
    caplog.set_level(logging.WARNING)
    assert main(["export", str(calib), "--format", "ros-stereo", "--pair", "b", "a",
                 "--out", str(tmp_path / "s")]) == 2
    assert main(["export", str(calib), "--format", "kalibr", "--pair", "a", "b",
                 "--out", str(tmp_path / "k.yaml")]) == 2
    assert main(["export", str(calib), "--format", "opencv-stereo", "--alpha", "2",
                 "--out", str(tmp_path / "s.yml")]) == 2
    assert not (tmp_path / "s").exists() and not (tmp_path / "s.yml").exists()
    assert "--pair a b" in caplog.text and "goes with --format" in caplog.text
    assert "alpha must lie in [0, 1]" in caplog.text


def test_unscaled_rig_and_converged_pair_are_written_with_warnings(caplog):
    caplog.set_level(logging.WARNING)
    rig = _rig("pinhole", _pose([0, -35, 0], [-0.12, 0.0, 0.02]), metric=False)
    rect = stereo_pair(rig, None)
    assert rect.right_is_right and max(rect.rectifying_rotation_deg()) > 17
    assert "no metric scale" in caplog.text and "far from parallel" in caplog.text


SHARED_DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


@pytest.mark.data
def test_real_fisheye_pair_rectifies_and_measures_as_well_as_its_target_calibration(tmp_path):
    """Target-free calibration of the real fisheye bag (20 of the 46 stereo pairs, scene only),
    exported as ROS stereo camera_info: on the 23 pairs the bag does not hold, the checkerboard's
    corners land on one rectified row at least as well as with the set's two target-based
    calibrations of those very images, and the board's squares measure within 3 % of what the
    target-based stereo calibration measures at the same baseline
    (core.products.stereo_checkerboard, `densecalib bench-stereo`)."""
    from densecalib_ros.core.io.export import read_calibration
    from densecalib_ros.core.products.stereo_checkerboard import (corner_pairs, evaluate,
                                                                  row_error_mrad, ros_yaml_camera)

    folder = SHARED_DATA / "ros_fisheye_stereo_checkerboard" / "stereo"
    bag = SHARED_DATA / "ros2bag_fisheye_stereo_derived" / "fisheye_stereo_bag"
    if not (folder.exists() and bag.exists()):
        pytest.skip(f"shared data absent: {folder} or {bag}")
    out = tmp_path / "out"
    assert main(["calibrate", "--bag", str(bag), "--topics", "/stereo/left/image_raw",
                 "/stereo/right/image_raw", "--preset", "fisheye", "--known-baseline",
                 "stereo_left", "stereo_right", "0.11705", "--out", str(out)]) == 0
    assert main(["export", str(out), "--format", "ros-stereo", "--out",
                 str(tmp_path / "stereo")]) == 0
    figures = evaluate(folder, read_calibration(out))
    assert figures["pairs"] >= 15
    rows = figures["row_error_mrad"]
    assert rows["ours"] <= min(rows["cam_stereo.yml"], rows["left/right.yaml"]), rows
    exported = [ros_yaml_camera(tmp_path / "stereo" / f"stereo_{s}.yaml")
                for s in ("left", "right")]  # the files as written give the same figure
    assert row_error_mrad(corner_pairs(folder, range(1, 46, 2)), *exported) == \
        pytest.approx(rows["ours"], rel=1e-6)
    sizes = figures["square_size"]
    assert sizes["ours"] == pytest.approx(sizes["cam_stereo.yml"], rel=0.03), sizes
    # our sigmas held against both references, which stand apart themselves (the left focal
    # lengths by 1.3 %, the principal points by 3-4 px)
    apart = figures["references_apart"]
    assert set(apart) == {"stereo_left", "stereo_right"}
    assert 0.5 < apart["stereo_left"]["focal_pct"] < 3.0, apart
    assert all(1.0 < a["pp_px"] < 10.0 for a in apart.values()), apart
    ratios = figures["error_sigma_ratios"]
    assert set(ratios) == {"cam_stereo.yml", "left/right.yaml"}
    assert all(len(r["focal"]) == 2 and len(r["projection"]) == 2 for r in ratios.values())
