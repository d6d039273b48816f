"""Consensus over differently seeded calibrations: the disagreement measure and the medoid (the
pipeline's use of it is tested in test_pipeline.py)."""
import numpy as np
import pytest

from densecalib_ros.core.consensus import (UNREGISTERED_PAIR_DEG, WARN_DISAGREEMENT_DEG,
                                           disagreement_warning, medoid, pair_disagreement_deg,
                                           rig_disagreement_deg)
from densecalib_ros.core.types import CameraIntrinsics, RigCalibration, RigCamera

NAMES = ["a", "b", "c"]


def _rotation_z(deg):
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def _rig(c_yaw_deg=0.0, c_shift=(0.0, 0.0, 0.0), names=NAMES):
    cam = CameraIntrinsics("RADIAL", 640, 480, np.array([500.0, 320, 240, 0, 0]))
    poses = {"a": np.eye(4), "b": np.eye(4), "c": np.eye(4)}
    poses["b"][:3, 3] = [-1.0, 0, 0]
    poses["c"][:3, :3] = _rotation_z(c_yaw_deg)
    poses["c"][:3, 3] = np.array([-2.0, 0, 0]) + c_shift
    return RigCalibration("a", {n: RigCamera(n, cam, poses[n]) for n in names})


def test_disagreement_measures_rotation_and_translation_direction():
    assert rig_disagreement_deg(_rig(), _rig(), NAMES) == pytest.approx(0.0, abs=1e-6)
    # c turned by 10 deg: the pairs (a, c) and (b, c) differ by 10 deg in rotation.
    assert pair_disagreement_deg(_rig(), _rig(10.0), "a", "c") == pytest.approx(10.0)
    assert pair_disagreement_deg(_rig(), _rig(10.0), "a", "b") == pytest.approx(0.0, abs=1e-6)
    assert rig_disagreement_deg(_rig(), _rig(10.0), NAMES) == pytest.approx(20.0 / 3)
    # c moved sideways by 2 * tan(5 deg): the direction a -> c turns by 5 deg.
    moved = _rig(c_shift=(0.0, 2.0 * np.tan(np.radians(5.0)), 0.0))
    assert pair_disagreement_deg(_rig(), moved, "a", "c") == pytest.approx(5.0)
    # Scale does not matter (reconstructions have none).
    scaled = _rig(c_shift=(-2.0, 0.0, 0.0))
    assert pair_disagreement_deg(_rig(), scaled, "a", "c") == pytest.approx(0.0, abs=1e-6)
    # A camera one run did not register counts as far apart.
    assert pair_disagreement_deg(_rig(), _rig(names=["a", "b"]), "a", "c") == \
        UNREGISTERED_PAIR_DEG


def test_medoid_is_the_majority_answer():
    rigs = [_rig(30.0), _rig(0.2), _rig(0.0), _rig(-0.1), _rig(names=["a", "b"])]
    best, D = medoid(rigs, NAMES)
    assert best == 2 and D.shape == (5, 5) and np.allclose(D, D.T)
    assert D[0, 2] == pytest.approx(20.0) and np.all(np.diag(D) == 0)


def test_users_are_warned_when_runs_disagree_beyond_auc3_threshold():
    assert WARN_DISAGREEMENT_DEG == 3.0
    assert disagreement_warning(0.4, 3) is None and disagreement_warning(3.0, 5) is None
    message = disagreement_warning(12.5, 5)
    assert "5 calibration runs disagree" in message and "12.5 deg" in message
    assert "frame sets" in message and "share-intrinsics" in message
