"""Recalibration: calibrate again when a rig already has a good calibration.

Cameras get bumped or refocused; most of the time they moved a little. So the new calibration
first starts from the previous one (global SfM initialised from its poses and intrinsics, samples
scored with its triangulation angles: fast and accurate when the change is small). If that does not
give an acceptable result (a camera missing, reprojection error much larger than before), it
calibrates from scratch on the same matches. A result that is still worse than the previous
calibration is refused with CalibrationRejectedError, so callers keep the last good calibration.
Either way the result says how much every camera changed.

The frame sets may straddle the change: a node's buffer holds the last seconds of images, and a
camera bumped a moment before the service call leaves most of them from before. Calibrated
together, the old images pull the rig back to where it was. So each frame set is first held
against the previous calibration (core.monitor.consistency, as `check` does); when sets that fit it
are followed by sets that do not, the rig changed in between, and only the sets since the change are
calibrated (quality.frame_sets_before_change counts the ones left out).
"""
from __future__ import annotations

import logging
import time
from typing import Optional, Sequence

import numpy as np

from .calibration_result import CalibrationResult
from .config import PipelineConfig
from .errors import CalibrationError
from .monitor.change import calibration_change, change_summary
from .monitor.consistency import DEFAULT_TOLERANCE_PX, sets_since_change
from .monitor.reference_views import fits_per_frame_set_and_view
from .pipeline import planned_stages
from .progress import Progress, estimated_run_s, stoppable
from .stages.attempt import Attempt, Calibrator
from .stages.inputs import RigImages, prepare
from .stages.matching import Matched, match_rig
from .stages.record import finish
from .types import RigCalibration

log = logging.getLogger(__name__)

# A new calibration is "worse" when its reprojection RMS exceeds both of these (different images
# give somewhat different residuals, so only a clear degradation counts).
MAX_RMS_RATIO = 2.0
MAX_RMS_INCREASE_PX = 1.0


class CalibrationRejectedError(CalibrationError):
    """The new calibration is worse than the previous one, which stays in force."""


def worse_than(new: RigCalibration, previous: RigCalibration) -> Optional[str]:
    """Why `new` is worse than `previous`, or None when it is acceptable."""
    lost = [n for n in previous.cameras if n not in new.cameras]
    if lost:
        return f"camera(s) {', '.join(lost)} calibrated before but not now"
    rms_new, rms_old = new.quality.fit_rms_px(), previous.quality.fit_rms_px()
    if np.isfinite(rms_old) and not (rms_new <= max(MAX_RMS_RATIO * rms_old,
                                                    rms_old + MAX_RMS_INCREASE_PX)):
        return f"reprojection RMS {rms_new:.2f} px against {rms_old:.2f} px before"
    return None


def recalibrate(frame_sets: Sequence[Sequence[np.ndarray]], camera_names: Sequence[str],
                config: PipelineConfig, previous: RigCalibration, *, matcher=None,
                progress=None, previous_views: Optional[dict] = None) -> CalibrationResult:
    """Calibrate a rig that has a previous calibration (see the module doc); `previous_views`:
    its reference views (core.monitor.reference_views), which also tell a frame set taken since a
    change (a turn along the epipolar lines, a refocus of a camera of two). The result's
    rig.quality gains "init" (what the accepted run started from), "change_vs_previous" (per
    camera) and "change_summary". Raises CalibrationRejectedError when the best new result is worse
    than `previous`, the pipeline's CalibrationError subclasses when calibration fails, and
    CalibrationCancelled where the progress's stop token was set."""
    started = time.perf_counter()
    progress = Progress.of(progress)
    with stoppable(progress):
        attempt, images, init, before_change = _recalibrated(frame_sets, camera_names, config,
                                                              previous, matcher, progress,
                                                              previous_views)
    result = attempt.result
    change = calibration_change(previous, result.rig)
    result.rig.quality.update(init=init, change_vs_previous={n: vars(c) for n, c in
                                                             change.items()},
                              change_summary=change_summary(change),
                              frame_sets_before_change=before_change or None)
    progress.say(result.rig.quality.change_summary)
    finish(result, images, attempt.config, attempt.consensus, None,
           attempt.matched.keypoint_tracks, time.perf_counter() - started, progress)
    progress.finish()
    return result


def _recalibrated(frame_sets, camera_names, config: PipelineConfig, previous: RigCalibration,
                  matcher, progress: Progress, previous_views: Optional[dict]
                  ) -> tuple[Attempt, RigImages, str, int]:
    """(the calibration kept, the images it was made from, what it started from, how many frame
    sets before a change were left out): recalibrate's stages."""
    images = prepare(frame_sets, camera_names, config, progress)
    progress.plan(planned_stages(images.config, len(images.camera_names)),
                  estimated_run_s(images.image_sizes, len(frame_sets),
                                  images.config.max_image_side_px))
    # Every frame set matched whole: each is judged against the previous calibration on its own.
    matched = match_rig(images, images.config, progress, matcher, each_on_its_own=True)
    images, matched, before_change = _since_change(images, matched, previous, previous_views,
                                                   progress)
    attempt, why_not_previous = None, "the previous calibration lacks some of the cameras"
    if all(n in previous.cameras for n in images.camera_names):
        attempt, why_not_previous = _from_previous(images, matched, previous, progress)
    init = "previous calibration"
    if attempt is None:
        attempt = _calibrated(Calibrator(images, matched, images.config, progress))
        init = f"from scratch ({why_not_previous})"
        worse = worse_than(attempt.rig, previous)
        if worse is not None:
            raise CalibrationRejectedError(
                f"The new calibration is worse than the previous one ({worse}); the previous "
                "calibration is kept. Check that every camera sees the shared scene (lens "
                "covered, out of focus, moved away?) and calibrate again.")
    return attempt, images, init, before_change


def _since_change(images: RigImages, matched: Matched, previous: RigCalibration,
                  previous_views: Optional[dict], progress: Progress
                  ) -> tuple[RigImages, Matched, int]:
    """The frame sets (and their matches) since the rig changed, where earlier ones still fit
    the previous calibration and later ones do not; and how many were left out (module doc)."""
    before_change = sets_since_change(fits_per_frame_set_and_view(
        previous, list(images.camera_names), matched.match_sets, images.frame_sets,
        previous_views or {}, DEFAULT_TOLERANCE_PX))
    if not before_change:
        return images, matched, 0
    progress.say(f"the first {before_change} of {len(matched.match_sets)} frame sets fit the "
                 "previous calibration and the later ones do not: the rig changed in between; "
                 f"calibrating from the {len(matched.match_sets) - before_change} since")
    return images.since(before_change), matched.since(before_change), before_change


def _from_previous(images: RigImages, matched: Matched, previous: RigCalibration,
                   progress: Progress) -> tuple[Optional[Attempt], Optional[str]]:
    """(the calibration started from the previous one's poses and intrinsics, None) where it
    is acceptable (worse_than), else (None, why not)."""
    warm = images.config.with_options(pipeline="global", sfm__global_init="previous",
                                      sfm__b_err_px=None)
    try:
        attempt = _calibrated(Calibrator(images, matched, warm, progress, previous))
        why_not = worse_than(attempt.rig, previous)
    except CalibrationError as exc:
        attempt, why_not = None, str(exc)
    if why_not is None:
        return attempt, None
    progress.say(f"starting from the previous calibration did not work ({why_not}); "
                 "calibrating from scratch")
    return None, why_not


def _calibrated(calibrator: Calibrator) -> Attempt:
    """calibrator's calibration, its work run ahead stopped whatever came of it."""
    try:
        return calibrator.calibrate()
    finally:
        calibrator.close()
