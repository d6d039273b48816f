"""A calibration from frame sets, as its stages (core.stages) in one sequence: the inputs checked
and the configuration resolved, the frame sets matched, the matches calibrated (consensus runs,
focal hops, refinement on the images) under the second matcher's policy and, where the cameras'
own intrinsics leave the rig undetermined, again as units of one model (core.robust.one_model);
the calibration kept refused where its runs do not determine the rig (core.stages.record.refusal),
else its quality record and warnings made. The rig's frame and units: core.calibration_result.
"""
from __future__ import annotations

import time
from typing import Callable, Optional, Sequence

import numpy as np

from .calibration_result import CalibrationResult
from .config import PipelineConfig
from .method.prior_adjustment import SUPPORTED_MODELS
from .progress import Progress, estimated_run_s, stoppable
from .robust.one_model import with_one_model
from .robust.second_matcher import with_matchers_apart, with_second_matcher
from .stages.attempt import Attempt, Calibrator
from .stages.inputs import RigImages, prepare
from .stages.matching import match_rig
from .errors import UndeterminedRigError
from .stages.record import finish, refusal
from .types import RigCalibration, Tracks


def run_calibration(frame_sets: Sequence[Sequence[np.ndarray]], camera_names: Sequence[str],
                    config: PipelineConfig, *, matcher=None,
                    previous: Optional[RigCalibration] = None,
                    progress=None, identity_tracks: Optional[Tracks] = None) -> CalibrationResult:
    """Calibrate a rig from synchronised frame sets.

    frame_sets[t][c]: camera c's image at time t, (H, W, 3) uint8 RGB or (H, W) uint8 gray.
    matcher: an already loaded core.method.matching.Matcher of config.matcher to reuse (else it
    is created and loaded here). previous: a previous calibration of the same cameras; its focal
    lengths replace the initial-focal estimate (recalibration; see core.recalibration for
    starting from its poses). progress: a core.progress.Progress (stages, time left, a stop
    token) or a callback for its messages. identity_tracks: correspondences by identity (pose
    keypoints: core.method.identity_tracks) each run uses beside the image matches. Raises
    CalibrationError subclasses (UndeterminedRigError: refused, stages.record.refusal), and
    CalibrationCancelled where the progress's stop token was
    set."""
    started = time.perf_counter()
    progress = Progress.of(progress)
    images = prepare(frame_sets, camera_names, config, progress)
    progress.plan(planned_stages(images.config, len(images.camera_names)),
                  estimated_run_s(images.image_sizes, len(frame_sets),
                                  images.config.max_image_side_px))
    calibrators: dict[str, Calibrator] = {}
    try:
        with stoppable(progress):
            calibrate = _calibrate_with(images, matcher, previous, progress, calibrators,
                                        identity_tracks)
            kept, rematch = with_second_matcher(calibrate, images.config, images.camera_names,
                                                fresh=previous is None, say=progress.say)
            kept, one_model = with_one_model(kept, _again_with(images, kept, progress,
                                                               calibrators),
                                             images.camera_names, images.image_sizes,
                                             fresh=previous is None, say=progress.say)
    finally:
        for calibrator in calibrators.values():
            calibrator.close()
    units_apart_deg = one_model.one_apart_deg if one_model is not None else None
    if one_model is None or not one_model.kept:  # the calibration the matchers compared
        with_matchers_apart(kept.result.rig, rematch, progress.say)
    refused = refusal(kept.result.rig, kept.config, images.camera_names, kept.consensus,
                      kept.matched.keypoint_tracks, units_apart_deg)
    if refused:
        raise UndeterminedRigError(refused)
    finish(kept.result, images, kept.config, kept.consensus, rematch,
           kept.matched.keypoint_tracks, time.perf_counter() - started, progress,
           keypoints=kept.matched.identity_tracks is not None, units_apart_deg=units_apart_deg)
    progress.finish()
    return kept.result


def calibrate_rig(frame_sets: Sequence[Sequence[np.ndarray]], camera_names: Sequence[str],
                  config: PipelineConfig, *, matcher=None,
                  previous: Optional[RigCalibration] = None, progress=None) -> RigCalibration:
    """run_calibration(...).rig: the calibrated rig only."""
    return run_calibration(frame_sets, camera_names, config, matcher=matcher, previous=previous,
                           progress=progress).rig


def planned_stages(config: PipelineConfig, num_cameras: int) -> list[str]:
    """The stages a calibration with `config` runs (core.progress.STAGE_SHARES): the matching,
    the calibration, and where its lenses allow, the refinement on the images."""
    refines = config.refine_on_images and all(m in SUPPORTED_MODELS
                                              for m in config.sfm.models(num_cameras))
    return ["match", "calibrate"] + (["refine"] if refines else [])


def _again_with(images: RigImages, kept: Attempt, progress: Progress, calibrators: dict
                ) -> Callable[..., Attempt]:
    """calibrate_as(config, until) for with_one_model: kept's matches calibrated again with
    `config`, its consensus runs ended by `until` (its calibrator closed with the others, and
    the dense correspondences' first pass of kept's taken over)."""
    def calibrate_as(config: PipelineConfig, until: Callable) -> Attempt:
        progress.extend(planned_stages(config, len(images.camera_names))[1:])  # no matching
        calibrators["one model"] = Calibrator(images, kept.matched, config, progress,
                                              same_matches=calibrators.get(kept.config.matcher))
        return calibrators["one model"].calibrate(until)
    return calibrate_as


def _calibrate_with(images: RigImages, matcher, previous: Optional[RigCalibration],
                    progress: Progress, calibrators: dict, identity_tracks: Optional[Tracks]
                    ) -> Callable[..., Attempt]:
    """calibrate(matcher name, until, refine_cut_short=True) for with_second_matcher: that
    matcher's frame sets matched once (the given, loaded `matcher` reused for the configured
    one), each call going on with its consensus runs (stages.attempt.Calibrator.calibrate)."""
    def calibrate(name: str, until: Optional[Callable], refine_cut_short: bool = True
                  ) -> Attempt:
        if name not in calibrators:
            config = images.config if name == images.config.matcher else \
                images.config.with_options(matcher=name)
            if calibrators:  # a second matcher: its stages come on top of the plan
                progress.extend(planned_stages(config, len(images.camera_names)))
            matched = match_rig(images, config, progress,
                                matcher if name == images.config.matcher else None,
                                identity_tracks=identity_tracks)
            calibrators[name] = Calibrator(images, matched, config, progress, previous)
        return calibrators[name].calibrate(until, refine_cut_short)
    return calibrate
