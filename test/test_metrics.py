"""Metrics on poses and cameras with known, analytic errors."""
import math

import numpy as np
import pytest

from densecalib_ros.core.metrics import (auc, evaluate_calibration, focal_errors, PairError,
                                         projection_map_error, relative_pose_errors)
from densecalib_ros.core.types import CameraIntrinsics, RigCalibration, RigCamera


def rot_z(deg):
    a = math.radians(deg)
    return np.array([[math.cos(a), -math.sin(a), 0], [math.sin(a), math.cos(a), 0], [0, 0, 1]])


def rot_y(deg):
    a = math.radians(deg)
    return np.array([[math.cos(a), 0, math.sin(a)], [0, 1, 0], [-math.sin(a), 0, math.cos(a)]])


def pose(rotation, centre):
    """4x4 cam_from_world of a camera with cam_from_world rotation `rotation` at world `centre`."""
    t = np.eye(4)
    t[:3, :3] = rotation
    t[:3, 3] = -rotation @ np.asarray(centre, float)
    return t


def ring_rig(n=4):
    """n cameras on a circle of radius 1 looking inwards-ish (yaw varies), cam_from_world."""
    return {f"cam{k}": pose(rot_y(20.0 * k), [math.cos(k), 0.1 * k, math.sin(k)]) for k in range(n)}


def similarity(poses, scale, rotation, translation):
    """The same cameras in a new world gauge x_new = scale * rotation @ x + translation, with camera
    coordinates scaled by `scale` too (what an SfM reconstruction of arbitrary scale returns)."""
    out = {}
    for k, t in poses.items():
        m = np.eye(4)
        m[:3, :3] = t[:3, :3] @ rotation.T
        m[:3, 3] = scale * t[:3, 3] - m[:3, :3] @ translation
        out[k] = m
    return out


def test_identical_and_gauge_invariant():
    gt = ring_rig()
    est = similarity(gt, 3.7, rot_z(33) @ rot_y(-12), np.array([5.0, -2.0, 1.0]))
    errs = relative_pose_errors(est, gt)
    assert len(errs) == 6
    assert max(e.rot_err_deg for e in errs) < 1e-6
    assert max(e.trans_dir_err_deg for e in errs) < 1e-6
    assert auc(errs, 3) == pytest.approx(100.0)


def test_rotating_one_camera_about_its_axis():
    gt = ring_rig()
    est = {k: v.copy() for k, v in gt.items()}
    # Rotate camera 2 by 5 deg about its own optical axis: its centre stays where it is.
    est["cam2"] = pose(rot_z(5.0) @ gt["cam2"][:3, :3], -gt["cam2"][:3, :3].T @ gt["cam2"][:3, 3])
    for e in relative_pose_errors(est, gt):
        expected = 5.0 if "cam2" in (e.i, e.j) else 0.0
        assert e.rot_err_deg == pytest.approx(expected, abs=1e-6)
        if "cam2" not in (e.i, e.j):
            assert e.trans_dir_err_deg == pytest.approx(0.0, abs=1e-6)


def test_flipped_translation_is_180_unless_folded():
    gt = {"a": pose(np.eye(3), [0, 0, 0]), "b": pose(np.eye(3), [1, 0, 0])}
    est = {"a": pose(np.eye(3), [0, 0, 0]), "b": pose(np.eye(3), [-1, 0, 0])}
    (e,) = relative_pose_errors(est, gt)
    assert e.rot_err_deg == pytest.approx(0.0, abs=1e-9)
    assert e.trans_dir_err_deg == pytest.approx(180.0)
    (f,) = relative_pose_errors(est, gt, fold_translation_sign=True)
    assert f.trans_dir_err_deg == pytest.approx(0.0, abs=1e-6)


def test_zero_length_translations():
    gt = {"a": pose(np.eye(3), [0, 0, 0]), "b": pose(rot_z(10), [0, 0, 0])}
    est = {"a": pose(np.eye(3), [0, 0, 0]), "b": pose(rot_z(10), [1, 0, 0])}
    (e,) = relative_pose_errors(est, gt)
    assert e.trans_dir_err_deg == 0.0  # no true direction: rotation only
    (e2,) = relative_pose_errors(gt, est)
    assert e2.trans_dir_err_deg == 180.0  # degenerate estimate


def test_missing_camera_gives_inf_and_fails_auc():
    gt = ring_rig(3)
    est = {k: v for k, v in gt.items() if k != "cam1"}
    errs = relative_pose_errors(est, gt)
    assert sum(math.isinf(e.rot_err_deg) and math.isinf(e.trans_dir_err_deg) for e in errs) == 2
    assert auc(errs, 30) == pytest.approx(100.0 / 3.0)


def test_auc_formula():
    zero = [PairError("a", "b", 0.0, 0.0)] * 4
    assert auc(zero, 30) == 100.0
    # Error 15 passes thresholds 16..30 (strictly below): 15 of 30.
    fifteen = [PairError("a", "b", 15.0, 3.0)] * 4
    assert auc(fifteen, 30) == pytest.approx(50.0)
    assert auc(fifteen, 3) == 0.0
    # Max of rotation and translation: 2.5 passes threshold 3 only -> 1/3.
    assert auc([PairError("a", "b", 0.1, 2.5)], 3) == pytest.approx(100.0 / 3.0)
    assert auc([], 30) == 0.0


def test_projection_map_identical_and_focal_1_percent():
    cam = CameraIntrinsics("PINHOLE", 320, 240, np.array([300.0, 300.0, 160.0, 120.0]))
    same = projection_map_error(cam, cam)
    assert same["max_px"] < 1e-9 and same["num_points"] > 0
    est = CameraIntrinsics("PINHOLE", 320, 240, np.array([303.0, 303.0, 160.0, 120.0]))
    res = projection_map_error(cam, est, grid_step_px=16)
    xs, ys = np.arange(0.5, 320, 16), np.arange(0.5, 240, 16)
    xy = np.stack(np.meshgrid(xs, ys), -1).reshape(-1, 2)
    dist = np.linalg.norm(xy - [160.0, 120.0], axis=1)
    # A pixel at distance d from the principal point moves by exactly 1% of d.
    assert res["mean_px"] == pytest.approx(0.01 * dist.mean(), rel=1e-9)
    assert res["max_px"] == pytest.approx(0.01 * dist.max(), rel=1e-9)


def test_projection_map_across_models_and_wide_fisheye():
    # RADIAL with zero distortion is the same map as PINHOLE with fx = fy.
    pin = CameraIntrinsics("PINHOLE", 320, 240, np.array([250.0, 250.0, 160.0, 120.0]))
    rad = CameraIntrinsics("RADIAL", 320, 240, np.array([250.0, 160.0, 120.0, 0.0, 0.0]))
    assert projection_map_error(pin, rad)["max_px"] < 1e-9
    # 190-deg equidistant fisheye: corners lie beyond 90 deg and are left out, not mis-scored.
    fish = CameraIntrinsics("OPENCV_FISHEYE", 640, 480,
                            np.array([110.0, 110.0, 320.0, 240.0, 0, 0, 0, 0]))
    res = projection_map_error(fish, fish)
    assert 0.3 < res["fraction_used"] < 1.0
    assert res["max_px"] < 1e-6


def test_focal_errors_and_evaluate_calibration():
    gt_cams = ring_rig(3)
    cam = CameraIntrinsics("RADIAL", 320, 240, np.array([300.0, 160.0, 120.0, 0.0, 0.0]))
    cam_fish = CameraIntrinsics("OPENCV_FISHEYE", 320, 240,
                                np.array([100.0, 110.0, 160.0, 120.0, 0, 0, 0, 0]))
    gt = RigCalibration("cam0", {n: RigCamera(n, cam, p) for n, p in gt_cams.items()})
    est_cam = CameraIntrinsics("RADIAL", 320, 240, np.array([306.0, 160.0, 120.0, 0.0, 0.0]))
    est = RigCalibration("cam0", {n: RigCamera(n, est_cam, p) for n, p in gt_cams.items()
                                  if n != "cam2"}, failed_cameras=["cam2"])
    assert focal_errors({"f": cam_fish}, {"f": CameraIntrinsics(
        "OPENCV_FISHEYE", 320, 240, np.array([105.0, 105.0, 160.0, 120.0, 0, 0, 0, 0]))}) == {
        "f": pytest.approx(0.0)}
    res = evaluate_calibration(est, gt)
    assert res["num_registered"] == 2 and res["num_cameras"] == 3
    assert res["auc30"] == pytest.approx(100.0 / 3.0)
    assert res["median_focal_err"] == pytest.approx(0.02)
    assert res["median_proj_err_px"] > 0
    assert res["cameras"]["cam2"]["registered"] is False
