"""One calibration run on a matcher's matches: tracks sampled from the cycle-consistent matches
(core.method.sampling), the epipolar filter, the initial focal lengths, the SfM (incremental from
several starts, or global), and the rig refined on every keypoint match after the cameras they
contradict are moved (core.robust.placement). The consensus policy (core.robust.consensus_runs)
repeats it with other sampling seeds."""
from __future__ import annotations

import time
from typing import Optional, Sequence

import numpy as np

from ..calibration_result import CalibrationResult, SfMRecord, rig_from_state, saved_model
from ..config import PipelineConfig
from ..errors import FocalInitError, InputError, NotEnoughOverlapError, TooFewCamerasGivenError
from ..method.all_matches import refine_on_tracks
from ..method.focal_start import eq2_start, initial_focals, start_focals, with_known_intrinsics
from ..method.identity_tracks import beside_sampled, with_match_tracks
from ..method.incremental import MIN_REGISTRATION_INLIERS, initial_intrinsics
from ..method.known_intrinsics import given_intrinsics_fit
from ..method.multistart import MULTISTART_MAX_TRACKS, run_incremental
from ..method.reconstruction import SfMState
from ..method.twoview import epipolar_filter, fundamental_matrices
from ..method.view_graph import connected_components, disconnected_error, named_pair_counts
from ..progress import Progress
from ..robust.placement import repair_placements
from ..types import RigCalibration, RigQuality, Tracks
from .matching import Matched


def calibrate_once(matched: Matched, image_sizes: Sequence[tuple[int, int]],
                   camera_names: Sequence[str], config: PipelineConfig, progress: Progress,
                   previous: Optional[RigCalibration] = None,
                   only_starts: Optional[Sequence[str]] = None) -> CalibrationResult:
    """Tracks sampled from the matches (with config.sampling.seed), then sfm_run.
    previous: a previous calibration of these cameras, whose poses and intrinsics start the
    global pipeline where config.sfm.global_init is "previous" (and score the samples' angles),
    else whose focals start the SfM; only_starts: as sfm_run's. The matches' identity tracks
    (pose keypoints), where there are any, join the sampled tracks and the keypoint matches
    (core.method.identity_tracks), and carry the run alone where the images gave no tracks."""
    identity = matched.identity_tracks
    try:
        sampled, given = _sampled_tracks(matched.match_sets, image_sizes, camera_names, config,
                                         previous)
        if identity is None and not sampled.tracks.num_tracks:
            raise NotEnoughOverlapError(_NO_TRACKS)
    except (FocalInitError, NotEnoughOverlapError) as exc:
        if identity is None and isinstance(exc, FocalInitError):  # it knows cameras by index
            raise exc.named(camera_names) from exc
        if identity is None:
            raise NotEnoughOverlapError(str(exc) + _pairs_matched(matched, camera_names)) \
                from exc
        progress.say(f"the image matches give no tracks to start from ({exc}); the keypoints "
                     "carry the run")
        sampled, given = None, start_focals(config, previous, camera_names, image_sizes)
    if sampled is not None:
        stats = sampled.stats
        progress.say(f"sampled {sampled.tracks.num_tracks} tracks (per order "
                     f"{stats['tracks_per_order']}) from {stats['closed_cycles']} closed cycles")
    tracks, two_view, focal_px = (sampled.tracks, sampled.two_view, sampled.focal_px) \
        if identity is None else beside_sampled(sampled, identity, given)
    return sfm_run(tracks, image_sizes, camera_names, config,
                   two_view=two_view, focal_px=focal_px, previous=previous,
                   match_tracks=with_match_tracks(matched.keypoint_tracks, identity),
                   known_focals=previous is None and given is not None, only_starts=only_starts,
                   progress=progress)


def calibrate_from_tracks(tracks: Tracks, image_sizes: Sequence[tuple[int, int]],
                          camera_names: Sequence[str], config: PipelineConfig, *,
                          progress=None, **options) -> CalibrationResult:
    """A calibration from correspondences already made (tracks: (T, C, 2) COLMAP px, NaN where a
    camera does not see a track; image_sizes: (width, height) per camera): sfm_run (`options`
    as there), with its quality record and standard deviations (stages.record.assemble)."""
    from .record import assemble

    config = config.for_cameras(camera_names)
    result = sfm_run(tracks, image_sizes, camera_names, config, progress=progress, **options)
    assemble(result, config, camera_names, options.get("match_tracks"), None, (), None)
    return result


def sfm_run(tracks: Tracks, image_sizes: Sequence[tuple[int, int]],
            camera_names: Sequence[str], config: PipelineConfig, *,
            two_view: Optional[dict] = None, focal_px: Optional[np.ndarray] = None,
            previous: Optional[RigCalibration] = None, match_tracks: Optional[Tracks] = None,
            known_focals: bool = False, only_starts: Optional[Sequence[str]] = None,
            progress=None) -> CalibrationResult:
    """One run's SfM on tracks (config resolved for these cameras: for_cameras): what it did in
    the result's `sfm` (SfMRecord), its rig's quality the fit only.

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
    progress = Progress.of(progress)
    start = time.perf_counter()
    C = len(camera_names)
    _check_tracks(tracks, image_sizes, C)
    seed = config.sampling.seed
    filtered, two_view = _epipolar_filtered(tracks, two_view, config, camera_names, progress)
    if focal_px is None:
        focal_px = initial_focals(filtered, two_view, image_sizes)
    focal_px = np.asarray(focal_px, dtype=np.float64)
    progress.say("initial focals [px]: " + ", ".join(
        f"{n}={f:.0f}" for n, f in zip(camera_names, focal_px)))
    init = with_known_intrinsics(initial_intrinsics(image_sizes, focal_px, config.sfm.models(C)),
                                 config, camera_names)
    extra_starts = eq2_start(filtered, two_view, image_sizes, config, camera_names, progress) \
        if known_focals else None
    keypoints = match_tracks if match_tracks is not None and match_tracks.num_tracks else None
    validation = keypoints.sample(MULTISTART_MAX_TRACKS, seed) if keypoints is not None else None
    global_sfm, settled = {}, None  # the global pipeline's choice of start is not a multi-start
    if config.pipeline == "global":
        from ..method.global_sfm import run_global
        sfm = run_global(filtered, init, camera_names, config.sfm, seed=seed, progress=progress,
                         previous=previous, validation_tracks=validation,
                         extra_starts=extra_starts)
        global_sfm = sfm.quality.to_dict()  # init, gauge camera, BA stage residuals
    else:
        sfm = run_incremental(filtered, init, camera_names, config.sfm, seed=seed,
                              progress=progress, validation_tracks=validation,
                              extra_starts=extra_starts, only_starts=only_starts)
        settled = sfm.settled_starts
    state, moved = sfm.state, []
    if keypoints is not None:
        state, moved = _refined_on_matches(state, keypoints, camera_names, config, progress)
    failed = sorted(set(sfm.failed) | set(unsupported_cameras(state, camera_names, progress)))
    runtime = time.perf_counter() - start
    rig = rig_from_state(state, camera_names, failed, RigQuality())
    record = SfMRecord(config.pipeline, config.preset, runtime,
                       [camera_names[c] for c in sfm.view_order],
                       0 if match_tracks is None else match_tracks.num_tracks, moved, global_sfm,
                       given_intrinsics_fit(state, camera_names, config.sfm.num_threads) or None)
    progress.say(f"registered {len(rig.cameras)}/{C} cameras, reprojection RMS "
                 f"{rig.quality.reprojection_rms_px:.2f} px, {rig.quality.num_points} points "
                 f"({runtime:.1f} s)")
    return CalibrationResult(rig=rig, reconstruction=saved_model(state, camera_names, rig),
                             tracks=filtered, focal_init_px=focal_px, sfm=record, state=state,
                             settled_starts=settled)


def unsupported_cameras(state: SfMState, camera_names: Sequence[str],
                        progress: Optional[Progress] = None) -> list[int]:
    """Registered cameras that fewer than MIN_REGISTRATION_INLIERS points of the final
    reconstruction still observe, unregistered in `state`: the refinement's outlier gates took
    the observations that placed them, so their pose and intrinsics are whatever the last step
    left, with nothing in the fit behind them."""
    observed = (state.registered_active() & state.point_mask()[:, None]).sum(axis=0)
    out = [c for c in state.registered() if observed[c] < MIN_REGISTRATION_INLIERS]
    for c in out:
        Progress.of(progress).say(f"{camera_names[c]} left out: {int(observed[c])} points of "
                                  "the final fit observe it")
        state.cam_from_world[c] = None
    return out


_NO_TRACKS = ("No correspondences survived cycle sampling: the cameras' views do not overlap "
              "enough or the scene lacks texture. Point the cameras at a shared, textured scene "
              "or add frame sets.")


def _pairs_matched(matched: Matched, camera_names: Sequence[str]) -> str:
    """The sentence naming each camera pair's keypoint matches, fewest first, for a refusal
    that found no correspondences to calibrate from; "" without keypoint-match tracks (a dense
    matcher)."""
    tracks = matched.keypoint_tracks
    if tracks is None or tracks.num_cameras != len(camera_names):
        return ""
    counts = named_pair_counts(tracks, camera_names)  # {} where no track was matched at all
    pairs = sorted((counts.get((a, b), 0), a, b) for i, a in enumerate(camera_names)
                   for b in camera_names[i + 1:])
    if not pairs:
        return ""
    fewest = pairs[0]
    return (f" Keypoint matches per camera pair ({matched.matcher}, fewest first): "
            + ", ".join(f"{a}/{b} {n}" for n, a, b in pairs)
            + f"; {fewest[1]} and {fewest[2]} need frame sets in which both see the same "
            "textured things (a person crossing between them), or keypoints of what moves "
            "(--keypoints).")


def _check_tracks(tracks: Tracks, image_sizes: Sequence[tuple[int, int]], C: int) -> None:
    if tracks.num_cameras != C or len(image_sizes) != C:
        raise InputError(f"{C} camera names but tracks for {tracks.num_cameras} cameras and "
                         f"{len(image_sizes)} image sizes.")
    if C < 2:
        raise TooFewCamerasGivenError(f"A rig needs at least two cameras, got {C}.")
    if tracks.num_tracks == 0:
        raise NotEnoughOverlapError(_NO_TRACKS)


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
    progress.say(f"{filtered.num_tracks} of {tracks.num_tracks} tracks pass the epipolar filter "
                 f"(F_err {f_err})")
    return filtered, two_view


def _check_one_group(two_view: dict, camera_names: Sequence[str]) -> None:
    """DisconnectedViewGraphError when the cameras form two or more groups of at least two that
    share no two-view geometry: SfM would calibrate one group (which one, by chance) and call the
    others failed. A lone camera without geometry is left to fail on its own (named failed)."""
    edges = [k for k, g in two_view.items() if g.F_ji is not None]
    groups = connected_components(len(camera_names), edges)
    if sum(len(g) >= 2 for g in groups) > 1:
        raise disconnected_error(groups, camera_names, "two-view geometry")


def _refined_on_matches(state: SfMState, match_tracks: Tracks, camera_names: Sequence[str],
                        config: PipelineConfig, progress: Progress) -> tuple[SfMState, list[str]]:
    """The SfM's cameras on every keypoint match: cameras the matches contradict moved
    (core.robust.placement), then refined (core.method.all_matches); and the cameras moved."""
    state = state.on_tracks(match_tracks)
    moved = repair_placements(state, camera_names, progress.say)
    state = refine_on_tracks(state, match_tracks, camera_names, config.sfm, config.sampling.seed)
    progress.say(f"refined on all {match_tracks.num_tracks} keypoint-match tracks: "
                 f"{int(state.point_mask().sum())} points")
    return state, moved


def _sampled_tracks(match_sets: list, image_sizes: Sequence[tuple[int, int]],
                    camera_names: Sequence[str], config: PipelineConfig,
                    previous: Optional[RigCalibration]):
    """(sample_tracks' result, the start focals given to it or None)."""
    from ..method.sampling import sample_tracks

    given = None
    if previous is not None and config.pipeline == "global" and config.sfm.global_init == "previous":
        from ..method.global_sfm import working_models
        from ..method.previous_start import poses_from_previous

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
