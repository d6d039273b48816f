"""The calibration pipeline end to end: frame sets -> matches -> sampled tracks -> two-view
geometry, F_err filter, initial focals -> SfM (incremental or global) -> RigCalibration
(core.calibration_result: the rig's frame and units)."""
from __future__ import annotations

import copy
import logging
import time
from dataclasses import replace
from typing import Callable, NamedTuple, Optional, Sequence

import numpy as np

from .calibration_result import (CalibrationResult, result_with_state, rig_from_state,
                                 saved_model, unregistered_warning, warn_user)
from .config import PipelineConfig, resolve_camera_lenses
from .errors import (CalibrationError, FocalInitError, InputError, NotEnoughOverlapError,
                     TooFewCamerasGivenError)
from .method.all_matches import keypoint_tracks, refine_on_tracks
from .method.dense_matches import DenseAhead
from .method.focal_determination import (loose_focal_warning, one_camera_hint,
                                         weak_focal_warning)
from .method.focal_start import (eq2_start, initial_focals, start_focals,
                                 with_known_intrinsics)
from .method.frame_checks import check_frame_sets
from .method.incremental import initial_intrinsics
from .method.known_intrinsics import (check_known_intrinsics, describe as describe_known,
                                      given_intrinsics_fit, given_intrinsics_warnings)
from .method.masks import ignored_regions, info_strips
from .method.multistart import MULTISTART_MAX_TRACKS, run_incremental
from .method.plausibility import unlike_lens_warning
from .method.reconstruction import SfMState, colour_points
from .method.twoview import epipolar_filter, fundamental_matrices
from .method.view_graph import pair_track_counts
from .method.uncertainty import add_uncertainty, estimated_principal_points
from .progress import Progress, StageClock, say_progress
from .robust.placement import repair_placements
from .types import RigCalibration, RigQuality, SiteMatchSet, Tracks

log = logging.getLogger(__name__)


def calibrate_from_tracks(tracks: Tracks, image_sizes: Sequence[tuple[int, int]],
                          camera_names: Sequence[str], config: PipelineConfig, *,
                          two_view: Optional[dict] = None, focal_px: Optional[np.ndarray] = None,
                          previous: Optional[RigCalibration] = None,
                          match_tracks: Optional[Tracks] = None,
                          known_focals: bool = False,
                          only_starts: Optional[Sequence[str]] = None,
                          progress: Progress = None) -> CalibrationResult:
    """Calibrate from sampled tracks.

    tracks: (T, C, 2) COLMAP px; image_sizes: (width, height) per camera; two_view: {(i, j):
    TwoViewGeometry} (estimated here from the tracks when None); focal_px: (C,) initial focal
    lengths (estimated from the F's when None); previous: the calibration the global pipeline
    starts from when config.sfm.global_init is "previous" (recalibration); match_tracks: every
    keypoint match as tracks (all_matches.keypoint_tracks), on which the incremental focal
    multi-start and the global pipeline's choice of start are judged (a seeded sample) and the
    found rig is refined last, after cameras the matches contradict are moved (placement.py)
    (None: none of these); known_focals: focal_px are known ones (the user's, EXIF), not eq. 2's;
    only_starts: the incremental focal multi-start's starts to run (an earlier run's settled
    ones, run_incremental), None for all.

    Known focals add a start to the SfM's focal multi-start; they do not take the eq. 2 start's
    place. The path SfM takes depends on the start, not only on how close it is: from the true
    focals (no distortion yet) a rig can choose another first pair, whose relative pose the
    unmodelled distortion turned, and end wrong where eq. 2's shorter focals end right
    (docs/design-notes.md, Known focals as a start)."""
    start = time.perf_counter()
    C = len(camera_names)
    config = resolve_camera_lenses(config, camera_names)
    _check_tracks(tracks, image_sizes, C)
    seed = config.sampling.seed
    filtered, two_view = _epipolar_filtered(tracks, two_view, config, camera_names, progress)
    if focal_px is None:
        focal_px = initial_focals(filtered, two_view, image_sizes)
    focal_px = np.asarray(focal_px, dtype=np.float64)
    say_progress(progress, "initial focals [px]: " + ", ".join(
        f"{n}={f:.0f}" for n, f in zip(camera_names, focal_px)))
    init = with_known_intrinsics(initial_intrinsics(image_sizes, focal_px, config.sfm.models(C)),
                                 config, camera_names)
    extra_starts = eq2_start(filtered, two_view, image_sizes, config, camera_names, progress) \
        if known_focals else None
    validation = None
    if match_tracks is not None and match_tracks.num_tracks:
        validation = match_tracks.sample(MULTISTART_MAX_TRACKS, seed)
    settled = None  # the global pipeline's choice of start is not a focal multi-start
    if config.pipeline == "global":
        from .method.global_sfm import run_global
        sfm = run_global(filtered, init, camera_names, config.sfm, seed=seed, progress=progress,
                         previous=previous, validation_tracks=validation,
                         extra_starts=extra_starts)
    else:
        sfm = run_incremental(filtered, init, camera_names, config.sfm, seed=seed,
                              progress=progress, validation_tracks=validation,
                              extra_starts=extra_starts, only_starts=only_starts)
        settled = sfm.settled_starts
    state, moved = sfm.state, []
    if match_tracks is not None and match_tracks.num_tracks:
        state, moved = _refined_on_matches(state, match_tracks, camera_names, config, progress)
    fit = given_intrinsics_fit(state, camera_names, config.sfm.num_threads)
    runtime = time.perf_counter() - start
    rig = rig_from_state(state, camera_names, sfm.failed, RigQuality(
        pipeline=config.pipeline, preset=config.preset, sfm_runtime_s=runtime,
        view_order=[camera_names[c] for c in sfm.view_order],
        match_tracks=0 if match_tracks is None else match_tracks.num_tracks,
        moved_cameras=moved))
    if config.pipeline == "global":
        rig.quality.update(**sfm.quality.to_dict())  # init, gauge camera, BA stage residuals
    if fit:
        rig.quality.given_intrinsics_fit = fit  # judged in calibrate_from_matches
    reconstruction = saved_model(state, camera_names, rig)
    say_progress(progress, f"registered {len(rig.cameras)}/{C} cameras, reprojection RMS "
                   f"{rig.quality.reprojection_rms_px:.2f} px, {rig.quality.num_points} "
                   f"points ({runtime:.1f} s)")
    return CalibrationResult(rig=rig, reconstruction=reconstruction, tracks=filtered,
                             focal_init_px=focal_px, state=state,
                             settled_starts=settled)


def _check_tracks(tracks: Tracks, image_sizes: Sequence[tuple[int, int]], C: int) -> None:
    if tracks.num_cameras != C or len(image_sizes) != C:
        raise InputError(f"{C} camera names but tracks for {tracks.num_cameras} cameras and "
                         f"{len(image_sizes)} image sizes.")
    if C < 2:
        raise TooFewCamerasGivenError(f"A rig needs at least two cameras, got {C}.")
    if tracks.num_tracks == 0:
        raise NotEnoughOverlapError(
            "No correspondences survived cycle sampling: the cameras' views do not overlap enough "
            "or the scene lacks texture. Point the cameras at a shared, textured scene or add "
            "frame sets.")


def _epipolar_filtered(tracks: Tracks, two_view: Optional[dict], config: PipelineConfig,
                       camera_names: Sequence[str], progress: Progress) -> tuple[Tracks, dict]:
    """(the tracks within F_err of every pair's epipolar lines, the two-view geometry used:
    two_view, or estimated from the tracks where it has no F the filter needs)."""
    C = len(camera_names)
    if two_view is None or (config.sfm.f_err_px is not None and
                            not any(g.F_ji is not None for g in two_view.values())):
        two_view = fundamental_matrices(tracks, config.sampling.seed)
    _check_one_group(two_view, camera_names)
    filtered = epipolar_filter(tracks, two_view, config.sfm.pair_f_err_px)
    if config.sfm.f_err_px is not None:
        f_err = f"{config.sfm.f_err_px} px"
    elif config.sfm.pinhole_f_err_px is not None and \
            len(config.sfm.mixed_rig_pinhole_cameras(C)) >= 2:
        f_err = f"{config.sfm.pinhole_f_err_px} px between pinhole cameras"
    else:
        f_err = "off"
    say_progress(progress, f"{filtered.num_tracks} of {tracks.num_tracks} tracks pass the epipolar "
                           f"filter (F_err {f_err})")
    return filtered, two_view


def _refined_on_matches(state: SfMState, match_tracks: Tracks, camera_names: Sequence[str],
                        config: PipelineConfig, progress: Progress) -> tuple[SfMState, list[str]]:
    """The SfM's cameras on every keypoint match: cameras the matches contradict moved
    (core.robust.placement), then refined (core.method.all_matches); and the cameras moved."""
    state = state.on_tracks(match_tracks)
    moved = repair_placements(state, camera_names, lambda m: say_progress(progress, m))
    state = refine_on_tracks(state, match_tracks, camera_names, config.sfm, config.sampling.seed)
    say_progress(progress, f"refined on all {match_tracks.num_tracks} keypoint-match tracks: "
                           f"{int(state.point_mask().sum())} points")
    return state, moved


def _check_one_group(two_view: dict, camera_names: Sequence[str]) -> None:
    """DisconnectedViewGraphError when the cameras form two or more groups of at least two that
    share no two-view geometry: SfM would calibrate one group (which one, by chance) and call the
    others failed. A lone camera without geometry is left to fail on its own (named failed)."""
    from .method.view_graph import connected_components, disconnected_error

    edges = [k for k, g in two_view.items() if g.F_ji is not None]
    groups = connected_components(len(camera_names), edges)
    if sum(len(g) >= 2 for g in groups) > 1:
        raise disconnected_error(groups, camera_names, "two-view geometry")


def match_frame_sets(frame_sets: Sequence[Sequence[np.ndarray]], config: PipelineConfig, *,
                     matcher=None, progress: Progress = None,
                     camera_names: Optional[Sequence[str]] = None,
                     strips: Optional[dict] = None, ignored: Optional[list] = None,
                     each_on_its_own: bool = False) -> list:
    """One SiteMatchSet per frame set. matcher: an already loaded core.method.matching.Matcher to
    reuse (else config.matcher is created and loaded here). With config.cameras.masks (then
    camera_names is needed), matches on masked regions are dropped (core.method.masks), and on the
    info strips found (`strips` as info_strips gives them; None: looked for here); `ignored`:
    those regions as ignored_regions gives them, when already resolved. With config.matcher in
    config.new_content_matchers, frame sets after the first are matched only where they show
    something new (core.method.new_content), unless each_on_its_own: every frame set whole, for
    what judges each on its own (a check, a recalibration: a camera may have moved in between)."""
    from .method.masks import apply_masks
    from .method.matching import create_matcher
    from .method.new_content import describe as describe_regions
    from .method.new_content import new_content_regions

    if ignored is None:
        if strips is None:
            strips = info_strips(frame_sets, camera_names, config)
        ignored = ignored_regions(frame_sets, camera_names, config, strips)

    if matcher is None:
        matcher = create_matcher(config.matcher, max_image_side_px=config.max_image_side_px)
        matcher.load()
    regions = new_content_regions(frame_sets) \
        if config.matcher in config.new_content_matchers and not each_on_its_own else None
    match_sets, clock = [], StageClock(len(frame_sets))
    for t, frames in enumerate(frame_sets):
        where = next(regions) if regions is not None else None
        if where is not None and ignored:  # nothing to detect where no match may lie
            where = [r if r is None or skip is None else r & ~skip
                     for r, skip in zip(where, ignored)]
        if where is not None and t > 0:
            log.info("frame set %d: matched on %s of the images (what earlier frame sets did "
                     "not show)", t + 1, describe_regions(where))
        if where is not None and all(r is not None and not r.any() for r in where):
            match_sets.append(SiteMatchSet(  # nothing new in any camera: nothing to match
                sites=[np.zeros((0, 2)) for _ in frames], pairs={},
                image_sizes=[(f.shape[1], f.shape[0]) for f in frames]))
        else:
            match_sets.append(matcher.match(list(frames), where))
        if ignored:
            log.debug("frame set %d: %d match(es) on masked regions dropped", t,
                      apply_masks(match_sets[-1], ignored))
        say_progress(progress, f"matched frame set {t + 1}/{len(frame_sets)} ({config.matcher})"
                     + clock.left(t + 1))
    return match_sets


def calibrate_from_matches(match_sets: list, image_sizes: Sequence[tuple[int, int]],
                           camera_names: Sequence[str], config: PipelineConfig, *,
                           previous: Optional[RigCalibration] = None,
                           frame_sets: Optional[Sequence[Sequence[np.ndarray]]] = None,
                           ignored: Sequence = (),
                           progress: Progress = None,
                           warn_undetermined: bool = True,
                           stop_if_incomplete: bool = False) -> CalibrationResult:
    """Sample tracks from the matches and calibrate. With config.sfm.global_init == "previous",
    the previous calibration's poses and intrinsics also give the triangulation angles that score
    the samples (paper Sec. 3.2, refinement case); otherwise only its focals are reused.
    config.cameras.lens gives cameras another lens than the preset's (config.resolve_camera_lenses).

    A fresh calibration (no previous) with config.consensus_runs > 1 repeats sampling + SfM with
    consecutive seeds and returns the medoid run (core.robust.consensus); its quality records the
    runs' disagreement. Runs that fail are skipped; if all fail, the first run's error is raised.

    With config.refine_on_all_matches and a keypoint matcher, every run's rig is refined last on
    all the matches (core.method.all_matches). With the images (frame_sets, as matched) and
    config.refine_on_images, the kept rig is refined once more on dense correspondences measured
    in them (core.method.image_refinement), away from the `ignored` regions (ignored_regions);
    where the consensus runs disagreed, so is the runner-up, and their warning stands only if it
    still disagrees (_refine_runner_up). warn_undetermined: warn where a camera was not
    registered (calibration_result.unregistered_warning) or the focal lengths come out looser
    than the calibration aims at (focal_determination.loose_focal_warning); off where another
    matcher may be tried for that (_calibrated), which then warns for the rig it keeps.
    stop_if_incomplete: end the consensus at the first run that comes out where it leaves a camera
    unregistered (_consensus_runs; for _calibrated, which tries another matcher then)."""
    config = resolve_camera_lenses(config, camera_names)
    known = check_known_intrinsics(config.cameras.known_intrinsics or {}, camera_names, image_sizes)
    config = replace(config, cameras=replace(config.cameras, known_intrinsics=known))
    match_tracks = None
    if config.refine_on_all_matches:
        match_tracks = keypoint_tracks(match_sets, len(camera_names), seed=config.sampling.seed)
    refines_on_images = frame_sets is not None and config.refine_on_images
    ahead = _dense_ahead(frame_sets, camera_names, config, match_tracks, ignored) \
        if refines_on_images else None
    refined = _RefinedRuns(frame_sets, camera_names, config, match_tracks, ignored, previous,
                           ahead) if refines_on_images else None
    consensus = None
    try:
        if previous is None and config.consensus_runs > 1:
            consensus = _consensus_calibration(match_sets, image_sizes, camera_names, config,
                                               match_tracks, progress, ahead, refined,
                                               stop_if_incomplete)
            result = consensus.result
        else:
            result = _calibrate_once(match_sets, image_sizes, camera_names, config, previous,
                                     match_tracks, progress)
        sigmas = {}
        if refined is not None and result.state is not None:
            result, sigmas = _refined_on_images(result, refined, camera_names, config, progress)
            # Runs that stopped for meeting refined (_no_more_runs) were all judged so already.
            if consensus is not None and consensus.runner_up is not None and \
                    result.rig.quality.image_refinement_tracks is not None and \
                    result.rig.quality.consensus_refined_disagreement_deg is None:
                _refine_runner_up(result, consensus, refined, camera_names, progress)
    finally:
        if ahead is not None:
            ahead.cancel()
    if consensus is not None and consensus.warning and not _runs_agree(result.rig):
        warn_user(result.rig, consensus.warning, progress)
    if result.rig.failed_cameras:
        result.rig.quality.unregistered_best_partner = _best_partners(
            result.rig.failed_cameras, match_tracks, camera_names)
    if warn_undetermined:
        warning = unregistered_warning(result.rig, _suggests_asift(config, camera_names))
        if warning:
            warn_user(result.rig, warning, progress)
    add_uncertainty(result.rig, result.reconstruction, camera_names, config, sigmas)
    if config.cameras.known_intrinsics:
        result.rig.quality.given_intrinsics = describe_known(config.cameras.known_intrinsics)
        for warning in given_intrinsics_warnings(result.rig.quality.given_intrinsics_fit or {}):
            warn_user(result.rig, warning, progress)
    for warning in (unlike_lens_warning(result.rig), weak_focal_warning(result.rig),
                    loose_focal_warning(result.rig, f"{config.matcher}'s matches")
                    if warn_undetermined else None):
        if warning:
            warn_user(result.rig, warning, progress)
    return result


def _dense_ahead(frame_sets, camera_names: Sequence[str], config: PipelineConfig,
                 match_tracks: Optional[Tracks], ignored: Sequence) -> Optional[DenseAhead]:
    """The image refinement's dense correspondences, which need only the images and the keypoint
    matches until their last checks, started on cores the rig's search leaves idle
    (dense_matches.DenseAhead). None where the refinement will not start from the keypoint
    matches or cannot apply (a fisheye lens)."""
    from .method.prior_adjustment import SUPPORTED_MODELS

    if match_tracks is None or not match_tracks.num_tracks or any(
            m not in SUPPORTED_MODELS for m in config.sfm.models(len(camera_names))):
        return None
    return DenseAhead(frame_sets, len(camera_names), match_tracks, ignored or None)


class _RefinedRuns:
    """Calibrations (their SfM states) refined on the dense image correspondences
    (core.method.image_refinement), each once: the kept run's refinement is the calibration's
    (_refined_on_images), and where consensus runs disagree on the keypoint matches, whether they
    still do refined decides the early stop (_consensus_runs), the focal hops and the warning
    (_refine_runner_up). A previous calibration's principal points that its images determined
    centre the priors; ahead: the dense correspondences as far as they were found ahead
    (_dense_ahead), or None."""

    def __init__(self, frame_sets, camera_names: Sequence[str], config: PipelineConfig,
                 match_tracks: Optional[Tracks], ignored: Sequence,
                 previous: Optional[RigCalibration], ahead: Optional[DenseAhead]):
        self.frame_sets, self.camera_names, self.config = frame_sets, camera_names, config
        self.match_tracks, self.ignored, self.ahead = match_tracks, ignored or None, ahead
        self.pp_centres = estimated_principal_points(previous)
        self._done: dict[int, tuple] = {}  # id(state) -> (state, refinement, its messages)

    def refinement(self, result: CalibrationResult, say: Optional[Callable[[str], None]] = None):
        """The ImageRefinement of result.state (None where the stage does not apply); its progress
        messages go to `say` (where given) each time it is asked for."""
        from .method.image_refinement import refine_on_images

        state = result.state
        if self._done.get(id(state), (None,))[0] is not state:
            messages: list[str] = []
            refinement = refine_on_images(state, self.frame_sets,
                                          _refinement_seeds(result, self.match_tracks),
                                          self.camera_names, self.ignored,
                                          self.config.sampling.seed, messages.append,
                                          self.pp_centres, self.ahead)
            self._done[id(state)] = (state, refinement, messages)
        _, refinement, messages = self._done[id(state)]
        for message in messages if say is not None else ():
            say(message)
        return refinement

    def rig(self, result: CalibrationResult) -> Optional[RigCalibration]:
        """result's rig refined (its cameras as `refinement` places them), None where the stage
        does not apply or there is no state to refine."""
        refinement = self.refinement(result) if result.state is not None else None
        if refinement is None:
            return None
        names = self.camera_names
        failed = [names.index(n) for n in result.rig.failed_cameras]
        return rig_from_state(refinement.state, names, failed, result.rig.quality.copy())

    def disagreement_deg(self, results: Sequence[CalibrationResult]) -> Optional[np.ndarray]:
        """The (R, R) disagreement matrix (consensus.medoid's) of the results refined; None where
        one of them could not be."""
        from .robust.consensus import medoid

        rigs = [self.rig(r) for r in results]
        if any(r is None for r in rigs):
            return None
        return medoid(rigs, self.camera_names)[1]


def _refined_on_images(result: CalibrationResult, refined: _RefinedRuns,
                       camera_names: Sequence[str], config: PipelineConfig, progress: Progress
                       ) -> tuple[CalibrationResult, dict]:
    """(result refined by core.method.image_refinement, its sigmas per camera name); the result as
    it was and no sigmas where the stage does not apply."""
    from .method.image_refinement import PP_PRIOR_STD_FRACTION

    refinement = refined.refinement(result, lambda m: say_progress(progress, m))
    if refinement is None:
        return result, {}
    # Whether given intrinsics fit the scene was judged on the keypoint matches; the dense
    # correspondences were gated against them already.
    given_fit = result.rig.quality.given_intrinsics_fit
    result = result_with_state(result, refinement.state, camera_names, config)
    if given_fit is not None:
        result.rig.quality.given_intrinsics_fit = given_fit
    result.rig.quality.update(
        image_refinement_tracks=refinement.num_tracks,
        image_refinement_noise_px=round(refinement.adjustment.noise_px, 4),
        principal_point_prior_std_fraction=PP_PRIOR_STD_FRACTION)
    for name, cam in result.rig.cameras.items():
        if name in refinement.estimated and cam.quality is not None:
            cam.quality.estimated_intrinsics = refinement.estimated[name]
    return result, refinement.uncertainty


def _refinement_seeds(result: CalibrationResult, match_tracks: Optional[Tracks]) -> Tracks:
    """What the image refinement predicts its dense correspondences from: the keypoint-match
    tracks where there are any, else the tracks the rig was found on."""
    return match_tracks if match_tracks is not None and match_tracks.num_tracks \
        else result.tracks


def _refine_runner_up(result: CalibrationResult, consensus: Consensus, refined: _RefinedRuns,
                      camera_names: Sequence[str], progress: Progress) -> None:
    """Refine the runner-up run (Consensus) on the dense image correspondences as the kept rig
    (`result`, refined) was, and record in its quality how far apart the two come out
    (consensus_refined_disagreement_deg). Runs that disagree on the keypoint matches' flat
    valley can meet in the dense correspondences' sharper minimum: then the images determine
    the rig after all, and neither a warning nor a second matcher is called for."""
    from .robust.consensus import rig_disagreement_deg

    rig = refined.rig(consensus.runner_up)
    if rig is None:
        return
    deg = rig_disagreement_deg(result.rig, rig, camera_names)
    result.rig.quality.consensus_refined_disagreement_deg = deg
    say_progress(progress, f"consensus: refined on the dense image correspondences as well, the "
                           f"run with seed {consensus.runner_up_seed} comes out {deg:.2f} deg "
                           "from the kept rig")


def _runs_agree(rig: RigCalibration) -> bool:
    """Whether the consensus runs agree as the calibration stands
    (consensus.standing_disagreement_deg)."""
    from .robust.consensus import WARN_DISAGREEMENT_DEG, standing_disagreement_deg

    deg = standing_disagreement_deg(rig.quality)
    return deg is None or deg <= WARN_DISAGREEMENT_DEG


class Consensus(NamedTuple):
    """_consensus_calibration's outcome: the kept run; where the runs disagree beyond
    WARN_DISAGREEMENT_DEG, the other run at the median disagreement from it (runner_up, with its
    seed), and the warning for the user, which stands unless the runner-up refined on the dense
    image correspondences comes out where the kept rig does (_refine_runner_up)."""
    result: CalibrationResult
    runner_up: Optional[CalibrationResult] = None
    runner_up_seed: Optional[int] = None
    warning: Optional[str] = None


def _consensus_calibration(match_sets: list, image_sizes: Sequence[tuple[int, int]],
                           camera_names: Sequence[str], config: PipelineConfig,
                           match_tracks: Optional[Tracks], progress: Progress,
                           dense_ahead: Optional[DenseAhead] = None,
                           refined: Optional[_RefinedRuns] = None,
                           stop_if_incomplete: bool = False) -> Consensus:
    """_consensus_runs' kept run (core.robust.consensus), with the runner-up and the warning
    where the runs disagree (Consensus). dense_ahead: where given, told to expect the first run's
    rig, which the runs keep where they agree. refined: where given, runs that disagree on the
    keypoint matches are judged again refined on the images (_consensus_runs); where they agree
    refined, no focal hops are searched. stop_if_incomplete: as _consensus_runs'."""
    from .method.multistart import cost_truncation_px
    from .robust.consensus import (choose_run, disagreement_warning, least_determined_pairs,
                                   rig_disagreement_deg)
    from .robust.focal_hops import hop_focals

    results, seeds, failed, settled, refined_deg = _consensus_runs(
        match_sets, image_sizes, camera_names, config, match_tracks, progress, dense_ahead,
        refined, stop_if_incomplete)
    agree_deg = _runs_agreement_deg(results[0].rig, camera_names, config)
    choice = choose_run([r.rig for r in results], [r.tracks for r in results], camera_names,
                        cost_truncation_px(config.sfm, len(camera_names)), config.sampling.seed,
                        refined_on=match_tracks, agree_deg=agree_deg,
                        first_searched_more=settled is not None)
    best, D, costs = choice.best, choice.disagreement_deg, choice.costs_px
    if choice.worse_fit:
        say_progress(progress, "consensus: the runs with seeds " + ", ".join(
            f"{seeds[k]} ({costs[k]:.2f} px)" for k in choice.worse_fit) + " fit the common "
            f"tracks clearly worse than seed {seeds[int(np.nanargmin(costs))]} "
            f"({np.nanmin(costs):.2f} px) and are not kept")
    result = results[best]
    why = (f"fits the keypoint-match tracks best ({costs[best]:.3f} px on a common sample)"
           if choice.by_fit else "agrees best with the others")
    if len(results) > 1:
        say_progress(progress, f"consensus: kept the run with seed {seeds[best]}, which {why}")
    others = np.delete(D[best], best)
    if D.max() >= agree_deg and refined_deg is None and match_tracks is not None \
            and match_tracks.num_tracks and result.state is not None:
        # The runs found different minima, which the images do not make one: search around the
        # kept one (core.robust.focal_hops).
        state, hops = hop_focals(result.state, match_tracks, camera_names, config.sfm,
                                 config.sampling.seed, lambda m: say_progress(progress, m))
        if hops:
            result = result_with_state(result, state, camera_names, config)
            result.rig.quality.focal_hops = hops
            others = np.array([rig_disagreement_deg(result.rig, r.rig, camera_names)
                               for k, r in enumerate(results) if k != best])
    result.rig.quality.update(
        consensus_runs=len(results), consensus_failed_runs=failed, consensus_seed=seeds[best],
        consensus_settled_starts=settled,
        consensus_worse_fit_runs=len(choice.worse_fit), consensus_kept_by_fit=choice.by_fit,
        consensus_disagreement_deg=float(np.median(others)) if len(others) else 0.0)
    refined_said = ""
    if refined_deg is not None and len(results) > 1:
        result.rig.quality.consensus_refined_disagreement_deg = float(
            np.median(np.delete(refined_deg[best], best)))
        refined_said = (f" ({result.rig.quality.consensus_refined_disagreement_deg:.2f} deg "
                        "refined on the dense image correspondences)")
    if len(results) > 1:
        say_progress(progress, f"consensus: median disagreement of the result with the other "
                               f"{len(results) - 1} runs "
                               f"{result.rig.quality.consensus_disagreement_deg:.2f} deg"
                               f"{refined_said}")
    on_sift = _suggests_asift(config, camera_names)
    pairs = least_determined_pairs(result.rig, [r.rig for k, r in enumerate(results)
                                                if k != best], camera_names)
    if pairs:
        result.rig.quality.consensus_least_determined_pairs_deg = {
            f"{a}/{b}": round(deg, 1) for a, b, deg in pairs}
    warning = disagreement_warning(result.rig.quality.consensus_disagreement_deg, len(results),
                                   on_sift, pairs, _shared_matches(match_tracks, camera_names),
                                   len(result.rig.cameras))
    if not warning:
        return Consensus(result)
    # The other run at the median disagreement (the upper one of an even count): the one the
    # reported disagreement is measured to.
    other_runs = [k for k in range(len(results)) if k != best]
    k = other_runs[int(np.argsort(others)[len(others) // 2])]
    return Consensus(result, results[k], seeds[k], warning)


def _consensus_runs(match_sets: list, image_sizes: Sequence[tuple[int, int]],
                    camera_names: Sequence[str], config: PipelineConfig,
                    match_tracks: Optional[Tracks], progress: Progress,
                    dense_ahead: Optional[DenseAhead] = None,
                    refined: Optional[_RefinedRuns] = None,
                    stop_if_incomplete: bool = False
                    ) -> tuple[list[CalibrationResult], list[int], int, Optional[list[str]],
                               Optional[np.ndarray]]:
    """Sampling + SfM with consecutive seeds, up to config.consensus_runs times: (the results,
    their seeds, how many runs failed, the first run's settled starts or None, and where the runs
    stopped for agreeing refined on the images, their disagreement matrix refined, else None).
    The first run's error is raised if every run fails.

    Stops early where further runs could only repeat the answer: once EARLY_STOP_RUNS runs have
    succeeded and agree (multistart.agreement_deg). Where the first run's focal multi-start
    settled (every start that fit about as well ended in one rig: multistart.settled_starts),
    later runs try only its best starts, as the focal lengths are not what is in doubt, only the
    sampling's draw; a settled first run that registered every camera is the answer alone
    (_settled_whole). Runs that disagree on the keypoint
    matches are, where `refined` is given, refined on the dense image correspondences and stop
    as well where they agree refined within AGREEMENT_DEG: the keypoint matches' valley is
    flat where the images' minimum is sharp, and there more runs would be refined to the same
    rig (docs/design-notes.md, Consensus: runs apart, refined).

    stop_if_incomplete: stop after the first run that comes out where it leaves a camera
    unregistered: where another matcher is to be tried for such a camera (_calibrated), more
    runs on these matches would only delay it, as a later sample rarely registers a camera the
    first run left out (docs/design-notes.md, A second matcher: sooner), and the runs are
    completed where the other matcher does no better."""
    from .robust.consensus import EARLY_STOP_RUNS

    results, seeds, failed, first_error, run_s, settled = [], [], 0, None, None, None
    judged = False  # whether the early stop has judged the first EARLY_STOP_RUNS runs
    for k in range(config.consensus_runs):
        if k == 1 and _settled_whole(results, settled, camera_names):
            log.info("consensus: the first run's focal multi-start settled and it registered "
                     "every camera; no more runs")
            return results, seeds, failed, settled, None
        if stop_if_incomplete and len(results) == 1 and results[0].rig.failed_cameras:
            log.info("consensus: the first run left %s unregistered; no more runs before another "
                     "matcher is tried", ", ".join(results[0].rig.failed_cameras))
            return results, seeds, failed, settled, None
        if len(results) == EARLY_STOP_RUNS and not judged:
            judged = True
            stop, refined_deg = _no_more_runs(results, camera_names, config, refined)
            if stop:  # more runs could not make the rig more accurate
                return results, seeds, failed, settled, refined_deg
        seed = config.sampling.seed + k
        run_config = copy.deepcopy(config)
        run_config.sampling.seed = seed
        # What this run will take; nothing where runs take under a second.
        took = f"; about {run_s:.0f} s each" if run_s and run_s >= 1.0 else ""
        only = f"; focal starts {' and '.join(settled)} only" if settled else ""
        say_progress(progress, f"consensus run {k + 1} of up to {config.consensus_runs} "
                               f"(sampling seed {seed}{only}{took})")
        started = time.perf_counter()
        try:
            results.append(_calibrate_once(match_sets, image_sizes, camera_names, run_config,
                                           None, match_tracks, progress if k == 0 else None,
                                           only_starts=settled))
            seeds.append(seed)
            run_s = time.perf_counter() - started
        except CalibrationError as exc:
            log.info("consensus run %d (seed %d) failed: %s", k + 1, seed, exc)
            failed += 1
            first_error = first_error or exc
        if k == 0 and results and results[0].state is not None and dense_ahead is not None:
            dense_ahead.expect(results[0].state)  # agreeing runs keep the first (medoid)
        if k == 0 and results and results[0].settled_starts:
            settled = results[0].settled_starts
            run_s = None  # the later runs try fewer starts: the first run's time says nothing
    if not results:
        raise first_error
    return results, seeds, failed, settled, None


def _settled_whole(results: Sequence[CalibrationResult], settled: Optional[list[str]],
                   camera_names: Sequence[str]) -> bool:
    """Whether the one run so far settled (multistart.settled_starts) and registered every camera:
    then another sample could only repeat it. Every start that fit about as well ended in its rig,
    so the focal lengths are not in doubt, and with every camera placed no pair is left to the
    sampling's draw; a camera left out is (another sample may register it: a run that does
    disagrees with this one by consensus.UNREGISTERED_PAIR_DEG on its pairs), so such a run is
    checked by more (docs/design-notes.md, Consensus: one settled run)."""
    return bool(settled) and len(results) == 1 and \
        len(results[0].rig.cameras) == len(camera_names)


def _no_more_runs(results: Sequence[CalibrationResult], camera_names: Sequence[str],
                  config: PipelineConfig, refined: Optional[_RefinedRuns] = None
                  ) -> tuple[bool, Optional[np.ndarray]]:
    """Whether the consensus runs so far answer alike, so that more runs could only repeat them
    (_consensus_runs): they agree within multistart.agreement_deg, or, where `refined` is given,
    refined on the dense image correspondences within AGREEMENT_DEG; with, in that case, their
    disagreement matrix refined (else None)."""
    from .method.multistart import AGREEMENT_DEG
    from .robust.consensus import medoid

    agree_deg = _runs_agreement_deg(results[0].rig, camera_names, config)
    apart_deg = medoid([r.rig for r in results], camera_names)[1].max()
    if apart_deg < agree_deg:
        log.info("consensus: the %d runs agree within %.1f deg; no more runs", len(results),
                 agree_deg)
        return True, None
    refined_deg = refined.disagreement_deg(results) if refined is not None else None
    if refined_deg is not None and refined_deg.max() < AGREEMENT_DEG:
        log.info("consensus: the %d runs, %.1f deg apart on the keypoint matches, agree within "
                 "%.2f deg refined on the dense image correspondences; no more runs",
                 len(results), apart_deg, refined_deg.max())
        return True, refined_deg
    return False, None


def _runs_agreement_deg(rig: RigCalibration, camera_names: Sequence[str],
                        config: PipelineConfig) -> float:
    """multistart.agreement_deg for the cameras as `rig` (a consensus run's) calibrated them."""
    from .method.multistart import agreement_deg

    return agreement_deg([rig.cameras[n].intrinsics if n in rig.cameras else None
                          for n in camera_names], config.sfm)


def _best_partners(cameras: Sequence[str], tracks: Optional[Tracks],
                   camera_names: Sequence[str]) -> Optional[dict]:
    """{camera: [the other camera it shares the most keypoint-match tracks with, how many]} for
    `cameras` (_shared_matches); None without keypoint-match tracks (a dense matcher)."""
    shared = _shared_matches(tracks, camera_names)
    if not shared:
        return None
    out = {}
    for name in cameras:
        counts = {(b if a == name else a): n for (a, b), n in shared.items() if name in (a, b)}
        partner = max(counts, key=counts.get)
        out[name] = [partner, counts[partner]]
    return out


def _suggests_asift(config: PipelineConfig, camera_names: Sequence[str]) -> bool:
    """Whether a warning about the rig suggests asift: perspective cameras on sift's matches
    that no second matcher is tried on (second_matcher.perspective_on_sift)."""
    from .robust.second_matcher import perspective_on_sift

    return perspective_on_sift(config, camera_names) and not config.second_matcher


def _shared_matches(tracks: Optional[Tracks], camera_names: Sequence[str]) -> dict:
    """{(a, b): keypoint-match tracks seen by both cameras}; {} without tracks."""
    if tracks is None or not tracks.num_tracks:
        return {}
    shared = pair_track_counts(tracks)
    return {(a, b): int(shared[i, j]) for i, a in enumerate(camera_names)
            for j, b in enumerate(camera_names) if i < j}


def _calibrate_once(match_sets: list, image_sizes: Sequence[tuple[int, int]],
                    camera_names: Sequence[str], config: PipelineConfig,
                    previous: Optional[RigCalibration], match_tracks: Optional[Tracks],
                    progress: Progress, only_starts: Optional[Sequence[str]] = None
                    ) -> CalibrationResult:
    try:
        sampled, given = _sampled_tracks(match_sets, image_sizes, camera_names, config, previous)
    except FocalInitError as exc:  # it knows the cameras by index only
        raise exc.named(camera_names) from exc
    stats = sampled.stats
    say_progress(progress, f"sampled {sampled.tracks.num_tracks} tracks (per order "
                           f"{stats['tracks_per_order']}) from {stats['closed_cycles']} closed "
                           "cycles")
    # Focals the user or EXIF gave (a previous calibration's are calibrated, not guessed).
    known = previous is None and given is not None
    return calibrate_from_tracks(sampled.tracks, image_sizes, camera_names, config,
                                 two_view=sampled.two_view, focal_px=sampled.focal_px,
                                 previous=previous, match_tracks=match_tracks,
                                 known_focals=known, only_starts=only_starts,
                                 progress=progress)


def _sampled_tracks(match_sets: list, image_sizes: Sequence[tuple[int, int]],
                    camera_names: Sequence[str], config: PipelineConfig,
                    previous: Optional[RigCalibration]):
    """(sample_tracks' result, the start focals given to it or None)."""
    from .method.sampling import sample_tracks

    given = None
    if previous is not None and config.pipeline == "global" and config.sfm.global_init == "previous":
        from .method.global_sfm import working_models
        from .method.previous_start import poses_from_previous

        intrinsics, poses = poses_from_previous(previous, camera_names, image_sizes,
                                                working_models(config.sfm, len(camera_names)))
        intrinsics = with_known_intrinsics(intrinsics, config, camera_names)
        sampled = sample_tracks(match_sets, config, cam_from_rig=poses, intrinsics=intrinsics)
    elif len(config.sfm.fixed_intrinsics_cameras) == len(camera_names):
        # Every camera's intrinsics given: the sampling's rays come from them (distortion
        # included) instead of a pinhole or equidistant guess.
        given = start_focals(config, previous, camera_names, image_sizes)
        sampled = sample_tracks(match_sets, config, focal_px=given, intrinsics=[
            config.cameras.known_intrinsics[n] for n in camera_names])
    else:
        given = start_focals(config, previous, camera_names, image_sizes)
        sampled = sample_tracks(match_sets, config, focal_px=given)
    return sampled, given


def run_calibration(frame_sets: Sequence[Sequence[np.ndarray]], camera_names: Sequence[str],
                    config: PipelineConfig, *, matcher=None,
                    previous: Optional[RigCalibration] = None,
                    progress: Progress = None) -> CalibrationResult:
    """Calibrate a rig from synchronised frame sets.

    frame_sets[t][c]: camera c's image at time t, (H, W, 3) uint8 RGB or (H, W) uint8 gray.
    matcher: an already loaded core.method.matching.Matcher to reuse (else config.matcher is created
    and loaded here). previous: a previous calibration of the same cameras; its focal lengths
    replace the initial-focal estimate (recalibration; see core.recalibration for starting from its
    poses). Raises CalibrationError subclasses."""
    start = time.perf_counter()
    camera_names = list(camera_names)
    image_sizes, strips, ignored, match_sets = checked_and_matched(frame_sets, camera_names,
                                                                   config, matcher, progress)
    result, config = _calibrated(frame_sets, camera_names, config, image_sizes, ignored,
                                 match_sets, previous, progress)
    with_point_colours(result, frame_sets)
    result.rig.quality.update(matcher=config.matcher, num_frame_sets=len(frame_sets),
                              runtime_s=time.perf_counter() - start)
    if config.cameras.lens:
        result.rig.quality.camera_lens = dict(config.cameras.lens)
    if config.cameras.masks:
        result.rig.quality.masked_cameras = sorted(config.cameras.masks)
    record_info_strips(result, strips)
    if config.cameras.exif_focal_px:
        result.rig.quality.exif_focal_px = {n: round(float(f), 1)
                                               for n, f in config.cameras.exif_focal_px.items()}
    return result


def _calibrated(frame_sets: Sequence[Sequence[np.ndarray]], camera_names: Sequence[str],
                config: PipelineConfig, image_sizes: Sequence[tuple[int, int]], ignored: list,
                match_sets: list, previous: Optional[RigCalibration], progress: Progress
                ) -> tuple[CalibrationResult, PipelineConfig]:
    """calibrate_from_matches on match_sets; where perspective cameras matched with sift come
    out undetermined (core.robust.second_matcher), also on config.second_matcher's
    matches, keeping the better-determined calibration. Returns it with the config that made
    it. Raises the first calibration's error where neither gives one."""
    from .robust.second_matcher import better_determined, rematch_applies, undetermined

    def calibrate(cfg: PipelineConfig, sets: list, warn_undetermined: bool = False,
                  stop_if_incomplete: bool = False) -> CalibrationResult:
        return calibrate_from_matches(sets, image_sizes, camera_names, cfg, previous=previous,
                                      frame_sets=frame_sets, ignored=ignored, progress=progress,
                                      warn_undetermined=warn_undetermined,
                                      stop_if_incomplete=stop_if_incomplete)
    if not rematch_applies(config, camera_names, fresh=previous is None):
        return calibrate(config, match_sets, warn_undetermined=True), config
    first, error = None, None
    try:
        # A camera the first run leaves out is the second matcher's case: its consensus runs are
        # completed only where the second matcher does no better (below).
        first = calibrate(config, match_sets, stop_if_incomplete=True)
    except InputError:
        raise  # the user's input, not sift's matches: another matcher would be refused too
    except CalibrationError as exc:
        error = exc
    cut_short = first is not None and bool(first.rig.failed_cameras) and \
        config.consensus_runs > 1
    why = undetermined(first.rig if first else None)
    if why is None:
        return first, config
    wide = replace(config, matcher=config.second_matcher)
    say_progress(progress, f"{config.matcher}: {why}; matching again with {wide.matcher}, which "
                           "keeps matches across wide viewpoint changes (several times slower)")
    second = None
    try:
        second = calibrate(wide, match_frame_sets(frame_sets, wide, progress=progress,
                                                  camera_names=camera_names, ignored=ignored))
    except CalibrationError as exc:
        log.info("the calibration on %s's matches failed too: %s", wide.matcher, exc)
    if cut_short and not better_determined(second.rig if second else None, first.rig):
        say_progress(progress, f"{wide.matcher}: no better determined; completing "
                               f"{config.matcher}'s consensus runs")
        try:
            first = calibrate(config, match_sets)  # its first run as before: the same seed
        except CalibrationError as exc:  # not expected (the same first run): keep the one run
            log.info("completing %s's consensus runs failed: %s", config.matcher, exc)
        why = undetermined(first.rig)
        if why is None:  # a later run registered the camera: no second matcher was needed
            return first, config
    if first is None and second is None:
        raise error
    second_came = undetermined(second.rig if second else None) or "determined"
    keep_second = better_determined(second.rig if second else None,
                                    first.rig if first else None)
    kept, kept_config = (second, wide) if keep_second else (first, config)
    kept.rig.quality.rematch = {
        "first": config.matcher, "first_result": why, "second": wide.matcher,
        "second_result": second_came, "kept": kept_config.matcher}
    say_progress(progress, f"{wide.matcher}: {second_came}; kept the calibration on "
                           f"{kept_config.matcher}'s matches")
    warning = unregistered_warning(kept.rig)
    if warning:
        warn_user(kept.rig, warning, progress)
    if not keep_second:
        # Above the weak bound the weak warning has given the hint already.
        hint = "" if weak_focal_warning(kept.rig) else one_camera_hint(kept.rig)
        warn_user(kept.rig, f"{wide.matcher}'s matches were tried as well and gave no better "
                            f"determined rig ({second_came}).{hint}", progress)
    else:
        warning = loose_focal_warning(kept.rig, f"{wide.matcher}'s matches (kept over "
                                                f"{config.matcher}'s)")
        if warning:
            warn_user(kept.rig, warning, progress)
    return kept, kept_config


def checked_and_matched(frame_sets: Sequence[Sequence[np.ndarray]], camera_names: Sequence[str],
                        config: PipelineConfig, matcher=None, progress: Progress = None,
                        each_on_its_own: bool = False) -> tuple[list, dict, list, list]:
    """The frame sets checked (check_frame_sets: the image sizes), their info strips and the
    regions no match may use, and their matches (match_frame_sets, each_on_its_own as there)."""
    image_sizes = check_frame_sets(frame_sets, camera_names)
    strips = info_strips(frame_sets, camera_names, config)
    ignored = ignored_regions(frame_sets, camera_names, config, strips)
    match_sets = match_frame_sets(frame_sets, config, matcher=matcher, progress=progress,
                                  camera_names=camera_names, ignored=ignored,
                                  each_on_its_own=each_on_its_own)
    return image_sizes, strips, ignored, match_sets


def record_info_strips(result: CalibrationResult, strips: dict) -> None:
    """Note the info strips that were ignored (info_strips) in rig.quality.info_strips
    (camera -> what)."""
    if strips:
        result.rig.quality.info_strips = {
            n: ", ".join(s.describe() for s in found) for n, found in strips.items()}


def with_point_colours(result: CalibrationResult,
                       frame_sets: Sequence[Sequence[np.ndarray]]) -> None:
    """Colour the result's reconstruction points from the images (reconstruction.colour_points)."""
    if result.reconstruction is None or result.state is None:
        return
    try:
        colour_points(result.reconstruction, result.state, frame_sets)
    except Exception as exc:  # colours are for viewing: they never cost a calibration
        log.warning("scene points left uncoloured: %r", exc)


def calibrate_rig(frame_sets: Sequence[Sequence[np.ndarray]], camera_names: Sequence[str],
                  config: PipelineConfig, *, matcher=None,
                  previous: Optional[RigCalibration] = None,
                  progress: Progress = None) -> RigCalibration:
    """run_calibration(...).rig: the calibrated rig only."""
    return run_calibration(frame_sets, camera_names, config, matcher=matcher, previous=previous,
                           progress=progress).rig
