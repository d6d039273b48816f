"""Metric scale from a known baseline: SfM recovers the rig only up to scale."""
from __future__ import annotations

import copy
import dataclasses
import logging

import numpy as np

from .errors import InputError
from .types import RigCalibration

log = logging.getLogger(__name__)


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


def scale_reconstruction_to_baseline(reconstruction, camera_a: str, camera_b: str,
                                     baseline_m: float) -> None:
    """Scale a pycolmap.Reconstruction in place (about its world origin: camera centres and
    points) so that the images named camera_a and camera_b are baseline_m metres apart, so the
    COLMAP model written beside a metric calibration is metric too. Its world frame is the SfM
    frame, whose unit differs from the rig file's, hence a factor of its own."""
    import pycolmap

    centres = {im.name: np.asarray(im.projection_center()) for im in reconstruction.images.values()}
    distance = float(np.linalg.norm(centres[camera_a] - centres[camera_b]))
    reconstruction.transform(pycolmap.Sim3d(baseline_m / distance, pycolmap.Rotation3d(),
                                            np.zeros(3)))


def with_known_baseline(result, camera_a: str, camera_b: str, baseline_m: float):
    """A pipeline CalibrationResult made metric: its rig scaled by apply_known_baseline (a copy)
    and its reconstruction scaled to match (in place). When a baseline camera did not register,
    the result stays up to scale with a warning in rig.quality["warnings"] (the calibration of
    the other cameras is still worth keeping)."""
    missing = [c for c in (camera_a, camera_b) if c not in result.rig.cameras]
    if missing:
        warning = (f"no metric scale: {', '.join(missing)} did not register, so the known "
                   f"baseline {camera_a}-{camera_b} cannot be applied; the rig is up to scale")
        log.warning("%s", warning)
        result.rig.quality.setdefault("warnings", []).append(warning)
        return result
    rig = apply_known_baseline(result.rig, camera_a, camera_b, baseline_m)
    if result.reconstruction is not None:
        scale_reconstruction_to_baseline(result.reconstruction, camera_a, camera_b, baseline_m)
    return dataclasses.replace(result, rig=rig)
