"""Cameras calibrated as units of one model where their own intrinsics leave the rig undetermined
(with_one_model, the policy core.pipeline runs after the second matcher's).

Most rigs are one camera model bought three or four times (trail cameras, webcams, the units of a
motion-capture ring). Calibrated with each camera's own focal length and distortion, three or four
cameras far apart leave the SfM a valley of rigs that fit the matches alike, and the consensus
runs stand degrees apart; one set of intrinsics for all of them takes (N - 1) focal lengths and
distortions out of that valley. EXIF says which cameras are one model where the files carry it
(core.io.exif.identical_unit_groups); videos and generated frames do not, and the images alone
cannot prove it. What they can show is that one model fits the matches as well as N of them. So
where the runs disagree beyond consensus.WARN_DISAGREEMENT_DEG and the cameras could be one model
(one image size, one lens model, nothing the user said of their intrinsics or units), the same
matches are calibrated again as one model, and that calibration is kept where its runs agree
(within WARN_DISAGREEMENT_DEG: the assumption is worth making only where it determines the rig),
it is better determined than the other (second_matcher.better_determined), and its SfM, one
model, fits the keypoint matches no worse than multistart.WORSE_FIT_RATIO times the SfM with each
camera's own intrinsics: the factor between rigs that are alternatives and rigs that are wrong,
which lenses that differ grossly make one model. The keypoint matches (about a pixel of noise)
cannot tell lenses a few percent apart in focal length or distortion from one model, which the
dense image correspondences (a tenth of that) can. So where the refinement on the images adjusts
these lenses (focal_determination.lenses_adjusted), its one-camera test must have judged the units
one camera (core.method.image_refinement: three or more cameras of one size, their held-out
correspondences fitted as one camera and as several); a rig the test could not judge (too few dense
correspondences, fewer than three cameras) keeps its own intrinsics. Where it does not adjust them
(a forward-facing fisheye rig) the fit to the keypoint matches decides alone (docs/design-notes.md,
One model from the images). The calibration's record says the units were assumed and why
(RigQuality.identical_units).

The calibration as one model is kept only where its runs agree, so its runs end once their first
ones are judged apart (first_runs_apart), as the second matcher's first runs do: more runs would
only delay the answer (docs/design-notes.md, One model from the images: sooner).
"""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Callable, Optional, Sequence

import numpy as np

from ..config import PipelineConfig
from ..errors import CalibrationError
from ..method.multistart import HELD_OUT_TRUNCATION_PX, WORSE_FIT_RATIO, cost_truncation_px
from ..method.focal_determination import lenses_adjusted
from ..method.prior_adjustment import SUPPORTED_MODELS
from ..types import RigCalibration, Tracks
from .consensus import WARN_DISAGREEMENT_DEG, common_track_costs, standing_disagreement_deg
from .second_matcher import better_determined


def one_model_applies(config: PipelineConfig, camera_names: Sequence[str],
                      image_sizes: Sequence[tuple[int, int]], fresh: bool = True) -> bool:
    """Whether the cameras could be units of one model the user did not name: a fresh
    calibration with consensus runs (their disagreement is the sign), of cameras of one image
    size and one lens model, with no intrinsics given, no identical units named, intrinsics not
    shared already, and the user not saying they differ (CameraData.units_from_images)."""
    sfm = config.sfm
    return (fresh and config.cameras.units_from_images and config.consensus_runs > 1
            and len(camera_names) >= 2
            and len(set(map(tuple, image_sizes))) == 1
            and len(set(sfm.models(len(camera_names)))) == 1
            and not config.cameras.known_intrinsics and not intrinsics_shared(config))


def intrinsics_shared(config: PipelineConfig) -> bool:
    """Whether the cameras' intrinsics are shared already: units named (by EXIF or the user) or
    assumed here, or --share-intrinsics."""
    return bool(config.cameras.identical_units or config.sfm.share_intrinsics
                or config.sfm.shared_intrinsics_groups)


def runs_apart_deg(rig: Optional[RigCalibration]) -> Optional[float]:
    """How far the calibration's consensus runs stand apart (standing_disagreement_deg) where it
    exceeds WARN_DISAGREEMENT_DEG, else None."""
    if rig is None:
        return None
    apart = standing_disagreement_deg(rig.quality)
    return apart if apart is not None and apart > WARN_DISAGREEMENT_DEG else None


def as_one_model(config: PipelineConfig, camera_names: Sequence[str], why: str
                 ) -> PipelineConfig:
    """`config` (resolved for camera_names) with every camera a unit of one model, `why`."""
    return config.with_options(
        cameras__identical_units=((tuple(camera_names), why),),
        sfm__shared_intrinsics_groups=(tuple(range(len(camera_names))),))


def judged_one_camera(refinement, camera_names: Sequence[str]) -> bool:
    """Whether the refinement on the images (a stages.refinement.RefinementRecord, None where it
    did not run) judged camera_names one camera: every one of them in a group its one-camera
    test found one camera."""
    verdicts = getattr(refinement, "one_camera", None) or {}
    ones = {name for group, one in verdicts.items() if one for name in group}
    return set(camera_names) <= ones


def judged_several(refinement, camera_names: Sequence[str]) -> bool:
    """Whether the refinement on the images (as judged_one_camera) found two or more of
    camera_names several cameras."""
    verdicts = getattr(refinement, "one_camera", None) or {}
    return any(not one and len(set(group) & set(camera_names)) >= 2
               for group, one in verdicts.items())


def refined_on_images(config: PipelineConfig, camera_names: Sequence[str],
                      rig: RigCalibration) -> bool:
    """Whether the refinement on the images adjusts these cameras' lenses (config's) in a rig
    laid out as `rig` (focal_determination.lenses_adjusted)."""
    models = config.sfm.models(len(camera_names))
    return config.refine_on_images and all(m in SUPPORTED_MODELS for m in models) and \
        lenses_adjusted(models, [cam.cam_from_rig[:3, :3] for cam in rig.cameras.values()])


def first_runs_apart(needs_verdict: bool) -> Callable[[object], bool]:
    """The consensus runs' rule for the calibration as one model (ConsensusRuns.run's `until`):
    end once the first runs, judged (consensus.EARLY_STOP_RUNS), stand apart beyond
    WARN_DISAGREEMENT_DEG refined on the dense image correspondences (runs the images do not
    bring together stay apart however many more are made, second_matcher.
    first_runs_undetermined), or, where the images could not refine them and the calibration
    would need the refinement's verdict to be kept (needs_verdict: lenses it adjusts,
    refined_on_images), on the keypoint matches: a refinement that reaches no run cannot judge
    the units one camera. Not a bound: further runs siding with the one the fit keeps could
    still bring the runs into agreement; the rule takes that risk, as the second matcher's does."""
    def apart(runs) -> bool:
        if runs.judged_apart_deg is not None:
            return runs.judged_apart_deg > WARN_DISAGREEMENT_DEG
        return needs_verdict and runs.apart_on_matches_deg is not None and \
            runs.apart_on_matches_deg > WARN_DISAGREEMENT_DEG
    return apart


def fit_costs_px(rigs: Sequence[RigCalibration], tracks: Optional[Tracks],
                 camera_names: Sequence[str], config: PipelineConfig) -> np.ndarray:
    """Each rig's truncated reprojection cost of the keypoint matches (a common seeded sample,
    consensus.common_track_costs, truncated as choose_run truncates raw matches); NaN where
    there are none."""
    if tracks is None or not tracks.num_tracks:
        return np.full(len(rigs), np.nan)
    truncation = np.minimum(cost_truncation_px(config.sfm, len(camera_names)),
                            HELD_OUT_TRUNCATION_PX)
    return common_track_costs(rigs, [tracks], camera_names, truncation, config.sampling.seed)


@dataclass(frozen=True)
class OneModel:
    """What the one-model policy did: how far the runs stood apart with each camera's own
    intrinsics and as one model (deg; None where that calibration failed or its runs agree),
    each kept rig's cost on the keypoint matches (px), and whether the one model's was kept."""

    own_apart_deg: float
    one_apart_deg: Optional[float]
    own_cost_px: float
    one_cost_px: float
    kept: bool

    def why(self) -> str:
        """The reason the record gives for the units assumed (a kept one model's runs agree)."""
        return (f"assumed from the images: with each camera's own intrinsics the calibration "
                f"runs stood {self.own_apart_deg:.1f} deg apart, as one model they agree, "
                f"fitting the keypoint matches as well ({self.one_cost_px:.2f} px against "
                f"{self.own_cost_px:.2f} px); name the units (--share-intrinsics) if they are "
                "known")


def with_one_model(kept, calibrate_as: Callable[..., object],
                   camera_names: Sequence[str], image_sizes: Sequence[tuple[int, int]], fresh: bool,
                   say: Callable[[str], None]) -> tuple[object, Optional[OneModel]]:
    """(the calibration to keep, what the policy did or None where it did not run).

    kept: the calibration so far (a stages.attempt.Attempt: .rig, .sfm_rig, .config, .matched,
    .refinement); calibrate_as(config, until) calibrates kept's matches with `config`, its
    consensus runs ended by `until` (first_runs_apart). Where one_model_applies and
    the kept calibration's runs stand apart (runs_apart_deg), they are calibrated again as one
    model and that calibration kept where its runs agree, it is better determined, its SfM fits
    the keypoint matches within WORSE_FIT_RATIO of the other's, and, for lenses the refinement on
    the images adjusts, its one-camera test judged them one camera (module docstring). Not tried
    where kept's own refinement judged them several cameras already."""
    own_apart = runs_apart_deg(kept.rig)
    if own_apart is None or not one_model_applies(kept.config, camera_names, image_sizes, fresh):
        return kept, None
    if judged_several(kept.refinement, camera_names):  # its refinement told them apart already
        say(f"the calibration runs stand {own_apart:.1f} deg apart; the refinement on the images "
            "told the cameras apart, so they are not calibrated again as one model")
        return kept, None
    say(f"the calibration runs stand {own_apart:.1f} deg apart and the cameras could be units of "
        "one model (one image size and lens): calibrating them again as one model")
    needs_verdict = refined_on_images(kept.config, camera_names, kept.rig)
    try:
        one = calibrate_as(as_one_model(kept.config, camera_names, "assumed from the images"),
                           first_runs_apart(needs_verdict))
    except CalibrationError as exc:
        say(f"as one model the calibration failed ({exc}); kept each camera's own intrinsics")
        return kept, None
    own_cost, one_cost = fit_costs_px([kept.sfm_rig or kept.rig, one.sfm_rig or one.rig],
                                      kept.matched.keypoint_tracks, camera_names, kept.config)
    outcome = OneModel(own_apart, runs_apart_deg(one.rig), float(own_cost), float(one_cost),
                       False)
    fits = bool(np.isfinite([own_cost, one_cost]).all()) and one_cost <= WORSE_FIT_RATIO * own_cost
    agree = outcome.one_apart_deg is None
    refuted = refined_on_images(kept.config, camera_names, one.rig) and \
        not judged_one_camera(one.refinement, camera_names)
    keep = fits and agree and not refuted and better_determined(one.rig, kept.rig)
    first = f"its first {one.consensus.num_runs} runs" if getattr(one, "cut_short", False) \
        else "runs"
    how = (f"{first} {outcome.one_apart_deg:.1f} deg apart" if not agree else
           "runs in agreement") + \
        f", its SfM {one_cost:.2f} px on the keypoint matches against {own_cost:.2f} px"
    if not keep:
        why = ("fits the matches clearly worse" if not fits else
               "the refinement on the images did not judge them one camera" if refuted else
               "the rig still undetermined" if not agree else "no better determined")
        say(f"as one model: {how}; {why}: kept each camera's own intrinsics")
        return kept, outcome
    outcome = replace(outcome, kept=True)
    say(f"as one model: {how}; kept the cameras as units of one model")
    one.config = as_one_model(kept.config, camera_names, outcome.why())
    return one, outcome
