"""Recalibration: warm start from the previous calibration, change report, refusal when worse."""
import copy
import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np
import pytest

from densecalib_ros.core.monitor.change import calibration_change
from densecalib_ros.core.config import make_config
from densecalib_ros.core.metrics import evaluate_calibration
from densecalib_ros.core import run_calibration
from densecalib_ros.core.recalibration import CalibrationRejectedError, recalibrate
from densecalib_ros.core.synthetic import RigSpec, generate_rig
from densecalib_ros.core.types import CameraIntrinsics, RigCamera
from sfm_fixtures import turned_image


def _rotz(deg):
    a = np.radians(deg)
    T = np.eye(4)
    T[:2, :2] = [[np.cos(a), -np.sin(a)], [np.sin(a), np.cos(a)]]
    return T


@pytest.fixture(scope="module")
def rig():
    return generate_rig(RigSpec(lenses="ideal", num_cameras=4, camera_model="RADIAL", width=640, height=480,
                                seed=3))


@pytest.fixture(scope="module")
def config():
    return make_config("regular", matcher="sift", sfm__num_threads=1)


def _bumped(calibration, name, deg=2.0, focal_factor=1.03):
    """The calibration with one camera rotated by `deg` and its focal scaled."""
    bumped = copy.deepcopy(calibration)
    cam = bumped.cameras[name]
    cam.cam_from_rig = _rotz(deg) @ cam.cam_from_rig
    cam.intrinsics.params[0] *= focal_factor
    return bumped


def test_change_report_points_at_the_bumped_camera(rig):
    truth = rig.ground_truth()
    change = calibration_change(truth, _bumped(truth, "cam2", 2.0, 1.03))
    assert change["cam2"].rotation_change_deg == pytest.approx(2.0, abs=1e-6)
    assert change["cam2"].focal_change_pct == pytest.approx(3.0, abs=1e-6)
    for other in ("cam0", "cam1", "cam3"):
        assert change[other].rotation_change_deg < 1e-4  # only one of its pairs changed
        assert change[other].focal_change_pct == pytest.approx(0.0, abs=1e-9)
        assert change[other].projection_change_px == pytest.approx(0.0, abs=1e-6)
    # A 3 % focal change moves a pixel 3 % of its distance from the principal point: a few px.
    assert 2.0 < change["cam2"].projection_change_px < 0.03 * 640


def test_recalibration_starts_from_previous_and_recovers_truth(rig, config):
    truth = rig.ground_truth()
    previous = _bumped(truth, "cam1", 2.0, 1.03)  # the camera was bumped and refocused since
    previous.quality.reprojection_rms_px = 0.8
    result = recalibrate([rig.images[0]], rig.names, config, previous)
    assert result.rig.quality.init == "previous calibration"
    metrics = evaluate_calibration(result.rig, truth)
    assert metrics["num_registered"] == 4
    assert metrics["auc3"] >= 80.0 and metrics["median_focal_err"] <= 0.02
    # The report says the bumped camera changed by about the bump.
    change = result.rig.quality.change_vs_previous
    assert max(change, key=lambda n: change[n]["rotation_change_deg"]) == "cam1"
    assert 1.0 < change["cam1"]["rotation_change_deg"] < 3.0
    assert "cam1" in result.rig.quality.change_summary


def test_worse_result_is_refused_so_the_previous_stays(rig, config):
    previous = copy.deepcopy(run_calibration([rig.images[0]], rig.names, config).rig)
    extra = previous.cameras["cam3"]
    previous.cameras["cam_gone"] = RigCamera("cam_gone", CameraIntrinsics(
        extra.intrinsics.model, 640, 480, extra.intrinsics.params.copy()), extra.cam_from_rig)
    with pytest.raises(CalibrationRejectedError, match="cam_gone"):
        recalibrate([rig.images[0]], rig.names, config, previous)


def test_recalibration_uses_only_the_frame_sets_since_a_bump():
    """A buffer holding two frame sets from before cam2 was turned by 2 deg and two from after:
    the sets from before fit the previous calibration and are left out, and the new calibration
    has cam2 where it is now. (Calibrated with all four, the result was refused as worse than
    the previous one, RMS 4.1 px: the old sets contradict the new.)"""
    from densecalib_ros.core.metrics import relative_pose_errors

    rig = generate_rig(RigSpec(lenses="ideal", num_cameras=4, camera_model="RADIAL", width=640, height=480,
                               num_time_steps=4, seed=5))
    truth = rig.ground_truth()
    truth.quality.reprojection_rms_px = 0.5
    turn = _rotz(2.0)[:3, :3] @ np.array([[1, 0, 0], [0, np.cos(0.02), -np.sin(0.02)],
                                          [0, np.sin(0.02), np.cos(0.02)]])
    frame_sets = [list(fs) for fs in rig.images]
    for t in (2, 3):
        frame_sets[t][2] = turned_image(frame_sets[t][2], truth.cameras["cam2"].intrinsics, turn)
    now = copy.deepcopy(truth)
    now.cameras["cam2"].cam_from_rig[:3, :3] = turn @ now.cameras["cam2"].cam_from_rig[:3, :3]
    now.cameras["cam2"].cam_from_rig[:3, 3] = turn @ now.cameras["cam2"].cam_from_rig[:3, 3]
    config = make_config("regular", matcher="sift", sfm__num_threads=1)
    result = recalibrate(frame_sets, rig.names, config, truth)
    assert result.rig.quality.frame_sets_before_change == 2
    est = {n: c.cam_from_rig for n, c in result.rig.cameras.items()}
    errors_now = relative_pose_errors(est, {n: c.cam_from_rig for n, c in now.cameras.items()})
    assert max(e.rot_err_deg for e in errors_now) < 0.5, errors_now
    change = result.rig.quality.change_vs_previous
    assert max(change, key=lambda n: change[n]["rotation_change_deg"]) == "cam2"
    # the same four sets with nothing changed: all are used
    unchanged = recalibrate([list(fs) for fs in rig.images], rig.names, config, truth)
    assert unchanged.rig.quality.frame_sets_before_change is None
