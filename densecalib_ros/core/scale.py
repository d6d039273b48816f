"""Metric scale from a known baseline: SfM recovers the rig only up to scale."""
from __future__ import annotations

import copy

import numpy as np

from .errors import InputError
from .types import RigCalibration


def camera_distance(rig: RigCalibration, camera_a: str, camera_b: str) -> float:
    """Distance between the optical centres of two cameras, in the rig's translation units."""
    for name in (camera_a, camera_b):
        if name not in rig.cameras:
            raise InputError(f"Camera {name!r} is not in the calibration (calibrated cameras: "
                             f"{', '.join(rig.cameras)}).")
    centres = [np.linalg.inv(rig.cameras[n].cam_from_rig)[:3, 3] for n in (camera_a, camera_b)]
    return float(np.linalg.norm(centres[0] - centres[1]))


def apply_known_baseline(rig: RigCalibration, camera_a: str, camera_b: str,
                         baseline_m: float) -> RigCalibration:
    """A copy of `rig` with every cam_from_rig translation scaled so that the optical centres of
    `camera_a` and `camera_b` are `baseline_m` metres apart; marks the result metric."""
    if not baseline_m > 0:
        raise InputError(f"The known baseline must be > 0 metres, got {baseline_m}.")
    if camera_a == camera_b:
        raise InputError(f"The known baseline needs two different cameras, got {camera_a!r} twice.")
    distance = camera_distance(rig, camera_a, camera_b)
    if not distance > 1e-12:
        raise InputError(f"Cameras {camera_a!r} and {camera_b!r} share one optical centre in the "
                         "calibration: choose two cameras that are apart to fix the scale.")
    scaled = copy.deepcopy(rig)
    for cam in scaled.cameras.values():
        cam.cam_from_rig = np.array(cam.cam_from_rig, dtype=np.float64)
        cam.cam_from_rig[:3, 3] *= baseline_m / distance
    scaled.metric_scale = True
    scaled.quality["scale_from_baseline"] = {"cameras": [camera_a, camera_b],
                                             "baseline_m": float(baseline_m),
                                             "factor": float(baseline_m / distance)}
    return scaled
