"""One calibration job, as the command and the node run it.

A front end (`densecalib calibrate`, `densecalib_node`) gathers the images and options in its own
terms and maps them once into a CalibrationRequest; `run_job` does the rest of what a user calls
a calibration: a fresh calibration or a recalibration from the previous one, the metric scale
(the baseline given, else the previous calibration's), the floor, the warnings that a
recalibration lost the scale or the floor, and the provenance. Where the result is written stays
with the front end (a folder the user named; the node's timestamped folders and `latest`).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Optional, Sequence

import numpy as np

from .config import PipelineConfig
from .errors import InputError, NotEnoughCamerasError
from .progress import Progress
from .types import RigCalibration

if TYPE_CHECKING:  # the pipeline imports pycolmap: on use only
    from .calibration_result import CalibrationResult
    from .method.identity_tracks import IdentityTracks

log = logging.getLogger(__name__)


@dataclass
class CalibrationRequest:
    """What to calibrate and what to add to the result.

    frame_sets[t][c]: camera c's image of moment t (uint8 RGB (H, W, 3) or gray (H, W)).
    previous: the current calibration of these cameras: the job recalibrates from it (a worse
        result is refused: core.recalibration); previous_views: its reference views.
    known_baseline: (camera_a, camera_b, metres) between the two cameras' centres; None: the
        previous calibration's baseline where it was scaled by one, else up to scale.
    floor: "upright" or "top" to find the floor frame (core.products.floor); floor_hint: what finds
        it again in the front end's terms, said when a recalibration lost the previous floor.
    source: what the images came from, recorded as the provenance (core.io.export).
    matcher: a loaded matcher to reuse (the node keeps one across calibrations).
    keypoints: pose keypoints as correspondences by identity (core.method.identity_tracks), used
        beside the images' matches, or alone where frame_sets is empty (then every camera's image
        size must be in keypoints.image_sizes). A fresh calibration only."""

    frame_sets: Sequence[Sequence[np.ndarray]]
    camera_names: list[str]
    config: PipelineConfig
    source: dict
    previous: Optional[RigCalibration] = None
    previous_views: dict = field(default_factory=dict)
    known_baseline: Optional[tuple[str, str, float]] = None
    floor: Optional[str] = None
    floor_hint: str = "find it with the floor option"
    matcher: object = None
    keypoints: Optional["IdentityTracks"] = None


@dataclass
class JobResult:
    calibration: "CalibrationResult"
    # camera -> its image of the last frame set (core.monitor.reference_views)
    reference_views: dict

    @property
    def rig(self) -> RigCalibration:
        return self.calibration.rig


def run_job(request: CalibrationRequest, progress=None) -> JobResult:
    """Calibrate as `request` says (module docstring). progress: a core.progress.Progress (the
    stages and time left; its stop token stops the job) or a callback for its messages. Raises
    CalibrationError subclasses (CalibrationRejectedError: a recalibration worse than the
    previous calibration), and CalibrationCancelled where the stop token was set."""
    from .io.export import record_provenance
    from .products.floor import record_floor, warn_if_floor_lost
    from .pipeline import run_calibration
    from .recalibration import recalibrate
    from .io.reference_view_files import latest_views
    from .products.scale import warn_if_scale_lost, with_known_baseline

    r, progress = request, Progress.of(progress)
    if r.keypoints is not None and r.previous is not None:
        raise InputError("Keypoints are used in a fresh calibration; a recalibration from the "
                         "previous one uses its images only: leave out the keypoints, or the "
                         "previous calibration to calibrate afresh.")
    if not r.frame_sets:
        result = _from_keypoints(r, progress)
    elif r.previous is not None:
        result = recalibrate(r.frame_sets, r.camera_names, r.config, r.previous,
                             matcher=r.matcher, progress=progress,
                             previous_views=r.previous_views)
    else:
        result = run_calibration(r.frame_sets, r.camera_names, r.config, matcher=r.matcher,
                                 progress=progress, identity_tracks=r.keypoints and
                                 r.keypoints.tracks)
    baseline = r.known_baseline or previous_baseline(r.previous)
    if baseline:
        result = with_known_baseline(result, *baseline)
    warn_if_scale_lost(result.rig, r.previous)
    if r.floor:
        record_floor(result, r.floor)
    warn_if_floor_lost(result.rig, r.previous, r.floor_hint)
    record_provenance(result.rig, r.source)
    progress.check()  # the last moment a stop leaves nothing to undo: the front end writes next
    views = latest_views(r.frame_sets, r.camera_names, result.rig) if r.frame_sets else {}
    return JobResult(result, views)


def _from_keypoints(r: CalibrationRequest, progress: Progress) -> "CalibrationResult":
    """A calibration from the keypoints alone (no images): their tracks are the SfM's, and the
    ones it judges and refines the rig on (stages.runs.calibrate_from_tracks); warned as a
    calibration from images is of a camera left out, a lens unlike a real one or folding before
    its corner, and focal lengths the correspondences leave open."""
    from .method.focal_determination import loose_focal_warning, weak_focal_warning
    from .method.plausibility import corner_fold_warning, unlike_lens_warning
    from .stages.record import unregistered_warning
    from .stages.runs import calibrate_from_tracks

    sizes = r.keypoints.image_sizes if r.keypoints is not None else []
    unknown = [n for n, size in zip(r.camera_names, sizes) if not size]
    if r.keypoints is None or unknown or len(sizes) != len(r.camera_names):
        raise InputError("Without images, a calibration needs keypoints and every camera's "
                         f"image size{': unknown for ' + ', '.join(unknown) if unknown else ''} "
                         "(give it, e.g. --image-size 1280x720 or NAME=1280x720).")
    try:
        result = calibrate_from_tracks(r.keypoints.tracks, sizes, r.camera_names, r.config,
                                       progress=progress, match_tracks=r.keypoints.tracks)
    except NotEnoughCamerasError as exc:
        raise NotEnoughCamerasError(
            f"{exc} From the keypoints alone: they do not agree on one rig within the "
            "adjustment's outlier gates (a tool's error of tens of pixels, or joints swapped "
            "left for right). Give the videos beside them (--videos), more frames, or one "
            "camera's intrinsics (--intrinsics NAME=PATH).") from exc
    rig = result.rig
    for warning in (unregistered_warning(rig), unlike_lens_warning(rig), weak_focal_warning(rig),
                    loose_focal_warning(rig, "the keypoints"), corner_fold_warning(rig)):
        if warning:
            log.warning("%s", warning)
            rig.quality.warnings.append(warning)
    return result


def previous_baseline(previous: Optional[RigCalibration]) -> Optional[tuple[str, str, float]]:
    """The known baseline a metric previous calibration was scaled with, or None."""
    scale = (previous.quality.scale_from_baseline
             if previous is not None and previous.metric_scale else None)
    if not scale:
        return None
    log.info("metric scale as in the previous calibration: %s-%s = %s m", *scale["cameras"],
             scale["baseline_m"])
    return (*scale["cameras"], float(scale["baseline_m"]))
