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

import copy
import logging
from typing import Optional, Sequence

import numpy as np

from .calibration_result import CalibrationResult
from .config import PipelineConfig
from .errors import CalibrationError
from .monitor.change import calibration_change, change_summary
from .monitor.consistency import DEFAULT_TOLERANCE_PX, sets_since_change
from .monitor.reference_views import fits_per_frame_set_and_view
from .pipeline import (calibrate_from_matches, checked_and_matched, record_info_strips,
                       with_point_colours)
from .progress import Progress, say_progress
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
                progress: Progress = None,
                previous_views: Optional[dict] = None) -> CalibrationResult:
    """Calibrate a rig that has a previous calibration (see the module doc); `previous_views`:
    its reference views (core.monitor.reference_views), which also tell a frame set taken since a
    change (a turn along the epipolar lines, a refocus of a camera of two). The result's
    rig.quality gains "init" (what the accepted run started from), "change_vs_previous" (per
    camera) and "change_summary". Raises CalibrationRejectedError when the best new result is worse
    than `previous`, and the pipeline's CalibrationError subclasses when calibration fails."""
    camera_names = list(camera_names)
    # Every frame set matched whole: each is judged against the previous calibration on its own.
    image_sizes, strips, ignored, match_sets = checked_and_matched(
        frame_sets, camera_names, config, matcher, progress, each_on_its_own=True)
    before_change = sets_since_change(fits_per_frame_set_and_view(
        previous, camera_names, match_sets, frame_sets, previous_views or {},
        DEFAULT_TOLERANCE_PX))
    if before_change:
        say_progress(progress, f"the first {before_change} of {len(match_sets)} frame sets fit "
                               "the previous calibration and the later ones do not: the rig "
                               f"changed in between; calibrating from the "
                               f"{len(match_sets) - before_change} since")
        frame_sets, match_sets = frame_sets[before_change:], match_sets[before_change:]

    result, why_not_previous = None, None
    if all(n in previous.cameras for n in camera_names):
        warm = copy.deepcopy(config)
        warm.pipeline, warm.sfm.global_init, warm.sfm.b_err_px = "global", "previous", None
        try:
            result = calibrate_from_matches(match_sets, image_sizes, camera_names, warm,
                                            previous=previous, frame_sets=frame_sets,
                                            ignored=ignored, progress=progress)
            why_not_previous = worse_than(result.rig, previous)
        except CalibrationError as exc:
            why_not_previous = str(exc)
        if why_not_previous is None:
            result.rig.quality.init = "previous calibration"
        else:
            result = None
            say_progress(progress, f"starting from the previous calibration did not work "
                           f"({why_not_previous}); calibrating from scratch")
    else:
        why_not_previous = "the previous calibration lacks some of the cameras"
    if result is None:
        result = calibrate_from_matches(match_sets, image_sizes, camera_names, config,
                                        previous=None, frame_sets=frame_sets, ignored=ignored,
                                        progress=progress)
        result.rig.quality.init = f"from scratch ({why_not_previous})"
        worse = worse_than(result.rig, previous)
        if worse is not None:
            raise CalibrationRejectedError(
                f"The new calibration is worse than the previous one ({worse}); the previous "
                "calibration is kept. Check that every camera sees the shared scene (lens covered, "
                "out of focus, moved away?) and calibrate again.")
    change = calibration_change(previous, result.rig)
    result.rig.quality.change_vs_previous = {n: vars(c) for n, c in change.items()}
    result.rig.quality.change_summary = change_summary(change)
    say_progress(progress, result.rig.quality.change_summary)
    if before_change:
        result.rig.quality.frame_sets_before_change = before_change
    with_point_colours(result, frame_sets)
    record_info_strips(result, strips)
    return result
