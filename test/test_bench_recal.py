"""The bench's recalibration method: a bumped previous calibration is recalibrated from images."""
import os
from dataclasses import replace

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np
import pytest

from densecalib_ros.eval.bench import RECAL_METHOD, perturbed_calibration, run_method
from densecalib_ros.eval.tables import summarize_error_sigma_ratios
from densecalib_ros.eval.datasets import scene_from_synthetic
from densecalib_ros.core.metrics import relative_pose_errors
from densecalib_ros.core.synthetic import RigSpec, generate_rig


@pytest.fixture(scope="module")
def scene():
    rig = generate_rig(RigSpec(lenses="ideal", num_cameras=4, width=640, height=480, seed=3))
    return scene_from_synthetic(rig, "recal-test")


def test_perturbation_rotates_and_moves_every_camera(scene):
    bumped = perturbed_calibration(scene.gt, 2.0, 0.05)
    gt = {n: c.cam_from_rig for n, c in scene.gt.cameras.items()}
    errs = relative_pose_errors({n: c.cam_from_rig for n, c in bumped.cameras.items()}, gt)
    rot = np.array([e.rot_err_deg for e in errs])
    assert np.all(rot > 0.1) and np.all(rot <= 4.0 + 1e-9)  # two 2-deg rotations per pair at most
    for name, cam in bumped.cameras.items():
        R = cam.cam_from_rig[:3, :3]
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
        angle = np.degrees(np.arccos(np.clip((np.trace(R.T @ gt[name][:3, :3]) - 1) / 2, -1, 1)))
        assert angle == pytest.approx(2.0, abs=1e-6)


def test_recalibration_method_recovers_truth(scene):
    record = run_method(RECAL_METHOD, scene, num_threads=1)
    assert record["status"] == "ok", record["message"]
    assert record["message"] == "started from previous calibration"
    assert record["metrics"]["num_registered"] == 4
    assert record["metrics"]["auc3"] >= 80.0
    # The uncertainty check: every camera's focal and projection errors against their sigmas,
    # pooled per method.
    for kind in ("focal", "projection"):
        values = record["error_sigma_ratios"][kind]
        assert len(values) == 4 and all(np.isfinite(r) and r >= 0 for r in values), kind
    ratios = record["error_sigma_ratios"]["focal"]
    check = summarize_error_sigma_ratios([{"results": [record]}])
    assert check[RECAL_METHOD]["focal"]["n"] == 4
    assert check[RECAL_METHOD]["focal"]["median"] == pytest.approx(np.median(ratios))
    # a scene whose reference is an SfM estimate is pooled on a line of its own
    check = summarize_error_sigma_ratios([{"results": [record]},
                                          {"results": [record], "reference_is_estimate": True}])
    assert check[RECAL_METHOD]["focal"]["n"] == 4
    assert check[RECAL_METHOD + " (SfM references)"]["focal"]["n"] == 4


def test_principal_point_ratio_is_the_larger_axis_error_over_the_sigma():
    """The uncertainty check's principal point: a camera whose cx is 3 px and cy 1 px off, with a
    sigma of 2 px, gives 1.5; a camera whose principal point was held (no sigma) gives none."""
    import copy

    from densecalib_ros.core.method.uncertainty import error_sigma_ratios
    from densecalib_ros.core.synthetic import RigSpec, generate_rig
    from densecalib_ros.core.types import CameraQuality

    truth = generate_rig(RigSpec(num_cameras=3, camera_model="RADIAL", width=320, height=240,
                                 seed=3)).ground_truth()
    rig = copy.deepcopy(truth)
    first, second = list(rig.cameras.values())[:2]
    params = first.intrinsics.params.copy()
    params[list(first.intrinsics.to_pycolmap().principal_point_idxs())] += (3.0, -1.0)
    first.intrinsics = replace(first.intrinsics, params=params)
    first.quality = CameraQuality(0.5, 100, 0.5, principal_point_std_px=2.0)
    second.quality = CameraQuality(0.5, 100, 0.5)
    assert error_sigma_ratios(rig, truth)["principal_point"] == [pytest.approx(1.5)]
