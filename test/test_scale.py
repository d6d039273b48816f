"""Metric scale from a known baseline (core.scale)."""
import numpy as np
import pytest

from densecalib_ros.core.errors import InputError
from densecalib_ros.core.pipeline import CalibrationResult
from densecalib_ros.core.scale import apply_known_baseline, camera_distance, with_known_baseline

from sfm_fixtures import gt_calibration, gt_rig

NAMES = ["cam0", "cam1", "cam2", "cam3"]


def _result(rig):
    return CalibrationResult(rig=rig, reconstruction=None, tracks=None, focal_init_px=None)


def test_known_baseline_scales_every_distance_and_leaves_the_input_alone():
    rig = gt_calibration(NAMES, *gt_rig(4, seed=2))
    before = camera_distance(rig, "cam1", "cam3") / camera_distance(rig, "cam0", "cam2")
    metric = with_known_baseline(_result(rig), "cam0", "cam2", 0.5).rig
    assert metric.metric_scale and not rig.metric_scale
    assert camera_distance(metric, "cam0", "cam2") == pytest.approx(0.5)
    assert camera_distance(metric, "cam1", "cam3") / 0.5 == pytest.approx(before)
    for name in NAMES:  # rotations and intrinsics are untouched
        np.testing.assert_array_equal(metric.cameras[name].cam_from_rig[:3, :3],
                                      rig.cameras[name].cam_from_rig[:3, :3])
    with pytest.raises(InputError, match="must be > 0"):
        apply_known_baseline(rig, "cam0", "cam2", 0.0)


def test_a_baseline_camera_that_did_not_register_leaves_the_rig_up_to_scale_with_a_warning():
    rig = gt_calibration(NAMES, *gt_rig(4, seed=2))
    del rig.cameras["cam3"]
    rig.failed_cameras = ["cam3"]
    out = with_known_baseline(_result(rig), "cam0", "cam3", 0.5).rig
    assert not out.metric_scale
    assert "cam3 did not register" in out.quality["warnings"][0]
