"""What a calibration returns (CalibrationResult, with what its run's SfM did: SfMRecord) and how
an SfM state becomes one: the rig in its frame and units (rig_from_state), the COLMAP model
saved with it.

Rig frame: the reference camera is the first camera of `camera_names` that was registered, so the
rig frame stays the same camera across recalibrations (unless that camera fails). Translations
are scaled so that the median distance of the other cameras from the reference camera is 1
(the reconstruction has no metric scale).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace
from typing import Optional, Sequence

import numpy as np
import pycolmap

from .errors import NotEnoughCamerasError
from .method.reconstruction import (SfMState, build_reconstruction, camera_quality,
                                    reprojection_errors)
from .products.scale import move_model_to_rig_frame
from .types import RigCalibration, RigCamera, RigQuality, Tracks

log = logging.getLogger(__name__)


@dataclass
class SfMRecord:
    """What one run's SfM did, for the quality record (core.stages.record): the pipeline and
    preset, its time, the cameras in the order it registered them, the keypoint-match tracks it
    was refined on and the cameras that refinement moved (core.robust.placement), the global
    pipeline's start, gauge camera, outliers and residuals per stage (else {}), and how given
    intrinsics fit the scene (core.method.known_intrinsics; None without any)."""

    pipeline: str
    preset: str
    sfm_runtime_s: float
    view_order: list
    match_tracks: int = 0
    moved_cameras: list = field(default_factory=list)
    global_sfm: dict = field(default_factory=dict)
    given_intrinsics_fit: Optional[dict] = None


@dataclass
class CalibrationResult:
    """A calibrated rig plus what produced it.

    reconstruction: the final pycolmap Reconstruction (one image per registered camera, named by
    camera), in the rig frame and the rig's units (its image poses are the cameras' cam_from_rig),
    for export as a COLMAP model."""

    rig: RigCalibration
    reconstruction: pycolmap.Reconstruction
    tracks: Tracks  # the tracks SfM ran on (after the F_err filter)
    focal_init_px: np.ndarray  # (C,) initial focal lengths
    sfm: Optional[SfMRecord] = None
    stats: dict = field(default_factory=dict)
    # The final SfM state (on the keypoint-match tracks when the rig was refined on them): what
    # a later search (core.robust.focal_hops) continues from.
    state: Optional[SfMState] = None
    # The focal multi-start's starts that a later run on another sample needs, where its starts
    # all ended in one rig (core.method.multistart.settled_starts); None where they did not.
    settled_starts: Optional[list] = None


def rig_from_state(state: SfMState, camera_names: Sequence[str], failed: Sequence[int],
                   quality: Optional[RigQuality] = None) -> RigCalibration:
    """The registered cameras of `state` as a RigCalibration (module docstring: reference camera
    and scale). Raises NotEnoughCamerasError with fewer than two registered cameras."""
    registered = state.registered()
    if len(registered) < 2:
        raise NotEnoughCamerasError(
            f"Only {len(registered)} camera(s) could be registered "
            f"({', '.join(camera_names[c] for c in registered) or 'none'}): a rig needs two. "
            "Check that the cameras overlap and see textured scene content.")
    ref = registered[0]
    rig_from_world = state.cam_from_world[ref]
    world_from_rig = np.linalg.inv(rig_from_world)
    cam_from_rig = {c: state.cam_from_world[c] @ world_from_rig for c in registered}
    dist = [np.linalg.norm(np.linalg.inv(T)[:3, 3]) for c, T in cam_from_rig.items() if c != ref]
    scale = 1.0 / np.median(dist) if np.median(dist) > 0 else 1.0
    errors = reprojection_errors(state)
    cameras = {}
    for c in registered:
        T = cam_from_rig[c].copy()
        T[:3, 3] *= scale
        cameras[camera_names[c]] = RigCamera(camera_names[c], state.camera(c), T,
                                             camera_quality(state, c, errors))
    finite = errors[np.isfinite(errors)]
    overall = quality.copy() if quality is not None else RigQuality()
    overall.update(
        reprojection_rms_px=float(np.sqrt(np.mean(finite ** 2))) if len(finite) else float("nan"),
        num_points=int(state.point_mask().sum()), num_observations=int(len(finite)),
        num_registered=len(registered), num_cameras=state.num_cameras)
    return RigCalibration(reference_camera=camera_names[ref], cameras=cameras,
                          failed_cameras=[camera_names[c] for c in sorted(failed)],
                          quality=overall)


def result_with_state(result: CalibrationResult, state: SfMState,
                      camera_names: Sequence[str]) -> CalibrationResult:
    """`result` with its rig and reconstruction rebuilt from another state of the same cameras
    (the fit figures recomputed; what the run recorded kept)."""
    failed = [camera_names.index(n) for n in result.rig.failed_cameras]
    rig = rig_from_state(state, camera_names, failed, result.rig.quality)
    return replace(result, rig=rig, reconstruction=saved_model(state, camera_names, rig),
                   state=state)


def saved_model(state: SfMState, camera_names: Sequence[str], rig: RigCalibration):
    """The pycolmap.Reconstruction of `state` (what OUT/colmap holds) in `rig`'s frame and units,
    so its points and cameras combine with calibration.json as they are."""
    reconstruction, _ = build_reconstruction(state, camera_names)
    move_model_to_rig_frame(reconstruction, rig)
    return reconstruction
