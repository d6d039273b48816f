"""The incremental SfM run from several starts (run_incremental), and the costs that pick one.

Focal-from-F (eq. 2) is degenerate when the cameras' optical axes nearly meet (a common rig
layout) and then tends to be off by a common factor, from which incremental SfM
(core.method.incremental) converges to a wrong reconstruction. So it is run from several starting
intrinsics (focal_starts; first pairs where every camera's intrinsics are given), each a trial on
a subsample of the tracks, side by side in worker processes (core.parallel), and the trial with the
lowest truncated reprojection cost, judged on matches it was not built from where given
(held_out_cost), is finished on all tracks.
"""
from __future__ import annotations

import itertools
import logging
from dataclasses import replace
from typing import Callable, Optional, Sequence

import numpy as np
import pycolmap

from ..config import SfMConfig
from ..errors import NotEnoughOverlapError
from ..metrics import mean_focal_px, relative_pose_errors
from ..parallel import map_jobs
from ..progress import Progress, StageClock
from ..types import CameraIntrinsics, Tracks
from .incremental import (MIN_PAIR_CORRESPONDENCES, TRUNCATION_FALLBACK_PX, IncrementalResult,
                          finish_on, incremental_sfm)
from .plausibility import drop_implausible_cameras, implausible_cameras
from .reconstruction import SfMState, reprojection_errors, triangulate_tracks
from .view_graph import pair_track_counts

log = logging.getLogger(__name__)


FOCAL_SCALE_STARTS = (1.0, 1.3, 0.8)  # multi-start factors on the initial focals (run_incremental)


# One more step of 1.3 upwards where the initial focals come from eq. 2 (not fisheye models, whose
# start is a lens-model assumption): eq. 2 errs low on converging rigs (docs/design-notes.md,
# Focal starts and multi-start costs).
EQ2_EXTRA_FOCAL_SCALE_STARTS = (1.69,)


# Generic focal priors (x max(width, height)), starts that do not depend on the F's, for perspective
# models: COLMAP's prior for unknown focals, 1.2 (45 deg across the long side), two wider lenses
# 1/sqrt(2) apart, 0.85 and 0.6 (62 and 81 deg: wide-angle trap and arena cameras), and two longer
# ones, 1.7 and 2.4 (33 and 24 deg: telephoto surveillance and lab cameras, where eq. 2 is most
# often degenerate: optical axes that nearly meet). Where eq. 2 degenerates it can miss by more
# than the scale starts span; the starts sit closer together than the ~1.4x a start may be off
# and still converge.
PRIOR_FOCAL_IMAGE_RATIOS = (1.2, 0.85, 0.6, 1.7, 2.4)


# Tracks each multi-start trial is built from, per camera of the rig (a seeded subsample of at
# most this many times the cameras). A trial only has to land in the right rig: the winner is
# judged on matches no trial was built from and finished on every track, and a trial's time
# grows with its tracks. What a trial has to determine grows with the cameras (a pose, a focal
# length and distortion each), so the sample does too: at 2-4 views a track, 100 tracks a camera
# give each camera about 250 observations, some 25 for each of its parameters.
TRIAL_TRACKS_PER_CAMERA = 100
# Keypoint-match tracks the starts are judged on (a seeded sample; focal hops judge on it too): the
# judging is cheap next to the trials, so it keeps more of the matches the trials never saw.
MULTISTART_MAX_TRACKS = 3000


# With every camera's intrinsics given there is no focal to explore; the run's other lottery is
# its first pair (eq. 3 picks among the first three views, on few points). So the multi-start runs
# from first pairs instead (the most shared tracks first), as many as the focal multi-start of the
# same lenses would have run (7 perspective, 3 fisheye: no slower than self-calibrating), at most
# this many (docs/design-notes.md, Focal starts and multi-start costs).
MAX_FIRST_PAIR_STARTS = 8




# Truncation (and triangulation gate) of the cost on raw keypoint matches (held_out_cost): COLMAP's
# two-view inlier threshold, the scale of a right match's error on a right rig. Raw matches are not
# cycle-verified (repetitive texture: many are wrong), and a loose gate lets a degenerate rig
# absorb wrong matches (docs/design-notes.md, Focal starts and multi-start costs).
HELD_OUT_TRUNCATION_PX = 4.0
# Two reconstructions that agree within this (mean over camera pairs of the larger of the relative
# rotation and translation-direction differences, deg) are one answer: a third of AUC@3's strictest
# threshold, so a choice between them could not change which poses count as accurate.
AGREEMENT_DEG = 1.0
# Real lenses put the principal point up to this fraction of the long image side off-centre
# (docs/design-notes.md, Real cameras' principal points). Where the SfM holds it at the centre, a
# camera inherits a turn of about this fraction x side / f (rad) that no choice between two
# reconstructions of it can remove: see agreement_deg.
HELD_PRINCIPAL_POINT_OFFSET_FRACTION = 0.02
# agreement_deg never exceeds AUC@3's strictest threshold: reconstructions this far apart place
# cameras differently by the measure of accuracy itself.
MAX_AGREEMENT_DEG = 3.0
# A reconstruction whose truncated reprojection cost exceeds the best one's by this factor is a
# wrong one, not an equally good alternative: the factor sits between what right or near-ambiguous
# alternatives (converging cameras, free focals) cost and what wrong reconstructions cost
# (docs/design-notes.md, Consensus: best fit vs vote).
WORSE_FIT_RATIO = 1.3
# Where the multi-start settled (settled_starts), a later consensus run tries this many of its
# best starts: two, so that a start that misses on another sample has a second, and both cores
# are busy for the time of one trial.
SETTLED_STARTS = 2
# While the trials run, a line this often tells a person the work goes on and how long it has
# left, without a line per trial in the log.
TRIALS_PROGRESS_EVERY_S = 15.0


def run_incremental(tracks: Tracks, intrinsics: Sequence[CameraIntrinsics],
                    camera_names: Sequence[str], config: SfMConfig, seed: int = 0,
                    progress=None,
                    validation_tracks: Optional[Tracks] = None,
                    extra_starts: Optional[dict[str, list[CameraIntrinsics]]] = None,
                    only_starts: Optional[Sequence[str]] = None) -> IncrementalResult:
    """Register the rig's cameras one by one and refine them (core.method.incremental), from the
    best of several starts (module docstring).

    tracks: (T, C, 2) COLMAP px observations; intrinsics: initial CameraIntrinsics per camera
    (model = config.camera_model, focal from the initial-focal step). Raises NotEnoughOverlapError
    when no camera pair among the first three of the view order can be initialised.

    Multi-start on the focal scale: focal-from-F (eq. 2) is degenerate when the cameras' optical
    axes nearly meet (a common rig layout) and then tends to be off by a common factor, low
    (docs/design-notes.md, Focal starts and multi-start costs), from which incremental SfM converges
    to a wrong reconstruction. So the SfM is run from the initial focals scaled by each of
    FOCAL_SCALE_STARTS (and, for perspective models, EQ2_EXTRA_FOCAL_SCALE_STARTS and the generic
    priors PRIOR_FOCAL_IMAGE_RATIOS), on a seeded subsample of trial_max_tracks tracks,
    and the start with the lowest truncated reprojection cost gives the result: that trial itself
    when it ran on all tracks, else its cameras finished on all tracks (`_on_all_tracks`). The cost
    is taken on validation_tracks (other tracks of the same cameras, e.g. all keypoint matches,
    triangulated from the trial's cameras: `held_out_cost`) when given, else on the trial's own
    tracks (`truncated_cost`). A trial can fit the tracks it was built from better than the right
    rig does and still fit the matches it never saw worse (same section), so the left-out matches
    judge more fairly.
    extra_starts: more named starting intrinsics for the multi-start (the eq. 2 estimate where
    `intrinsics` hold known focals: stages.runs.sfm_run). Where every camera's
    intrinsics are given (config.fixed_intrinsics_cameras) there is one focal start, and the
    multi-start runs from first pairs instead (first_pair_starts, MAX_FIRST_PAIR_STARTS).
    only_starts: run only the starts of these names (those present; all where none is): what
    an earlier run's settled multi-start (the result's settled_starts) leaves to try.
    """
    progress = Progress.of(progress)
    say = progress.say
    sub = tracks.sample(trial_max_tracks(tracks.num_cameras), seed)
    starts = _named_starts(intrinsics, camera_names, config, sub, extra_starts)
    restricted = only_starts is not None and any(n in starts for n in only_starts)
    if restricted:
        starts = {n: starts[n] for n in starts if n in only_starts}
    trials, costs = _judged_trials(sub, starts, camera_names, config, seed, validation_tracks,
                                   progress)
    best = min(costs, key=costs.get) if costs else next(iter(starts))
    if costs:
        judged_on = (f"{validation_tracks.num_tracks} keypoint-match tracks"
                     if validation_tracks is not None and validation_tracks.num_tracks
                     else "its own tracks")
        say(f"focal multi-start: {best} fits best (truncated reprojection cost on {judged_on} "
            f"{costs[best][1]:.2f} px; " + ", ".join(f"{n}: {c[1]:.2f}" for n, c in costs.items())
            + ")")
    if best in trials:
        result, messages = trials[best]
        for msg in messages:
            say(msg)
        if sub is not tracks:
            result = _on_all_tracks(tracks, result, *starts[best], camera_names, config, seed,
                                    say)
    else:
        start, pair = starts[best]
        result = incremental_sfm(tracks, start, camera_names, config, seed, say, pair)
    drop_implausible_cameras(result.state, result.failed, camera_names, say)
    if not restricted:
        states = {n: t[0].state for n, t in trials.items()}
        agree = (agreement_deg([states[best].camera(c) for c in range(tracks.num_cameras)],
                               config) if best in states else AGREEMENT_DEG)
        result.settled_starts = settled_starts(costs, states, agree)
    return result


def _named_starts(intrinsics: Sequence[CameraIntrinsics], camera_names: Sequence[str],
                  config: SfMConfig, trial_tracks: Tracks,
                  extra_starts: Optional[dict[str, list[CameraIntrinsics]]]
                  ) -> dict[str, tuple[list[CameraIntrinsics], Optional[tuple[int, int]]]]:
    """The multi-start's starts by name (run_incremental): start name -> (starting intrinsics,
    first pair or None where the view order picks it). The focal starts and extra_starts; where
    every camera's intrinsics are given, also first pairs of trial_tracks, as many as
    self-calibrating would have run focal starts."""
    starts = {name: (start, None) for name, start in
              {**focal_starts(intrinsics, config.fixed_intrinsics_cameras),
               **(extra_starts or {})}.items()}
    if len(config.fixed_intrinsics_cameras) == trial_tracks.num_cameras and \
            config.brute_force_first_pair:
        budget = len(focal_starts(intrinsics))  # what self-calibrating would have run
        starts.update({f"given, first pair {camera_names[i]}/{camera_names[j]}":
                       (list(intrinsics), (i, j))
                       for i, j in first_pair_starts(trial_tracks, budget)})
    return starts


def _judged_trials(trial_tracks: Tracks, starts: dict, camera_names: Sequence[str],
                   config: SfMConfig, seed: int, validation_tracks: Optional[Tracks],
                   progress: Progress) -> tuple[dict, dict]:
    """Every start's trial on trial_tracks (_trial), side by side: (start name -> (trial,
    its progress messages) for the trials that started; start name -> (-registered cameras,
    truncated cost) for those with plausible intrinsics), in the order of `starts`. The trials
    are the progress's substeps, and its stop ends them."""
    # Trials are independent: they run side by side (core.parallel), each BA on one core, so
    # the outcome does not depend on how many ran at once.
    trial_config = replace(config, num_threads=1)
    clock = StageClock(len(starts))

    def trials_done(k: int) -> None:
        progress.substep(k / len(starts))
        if clock.due(TRIALS_PROGRESS_EVERY_S) and k < len(starts):
            progress.say(f"focal multi-start: {k} of {len(starts)} trials done{clock.left(k)}")
    outcomes = map_jobs(_trial, [(trial_tracks, start, camera_names, trial_config, seed, pair,
                                  validation_tracks) for start, pair in starts.values()],
                        config.num_threads, on_done=trials_done, check=progress.check)
    trials, costs = {}, {}
    for name, (trial, messages, cost) in zip(starts, outcomes):
        if trial is None:
            continue
        trials[name] = (trial, messages)
        if cost is None:
            log.debug("focal start %s: implausible intrinsics %s", name,
                      implausible_cameras(trial.state))
            continue
        costs[name] = (-len(trial.state.registered()), cost)
        log.debug("focal start %s: %d registered, truncated cost %.3f px", name,
                  -costs[name][0], costs[name][1])
    return trials, costs


def trial_max_tracks(num_cameras: int) -> int:
    """The most tracks a multi-start trial of a rig of num_cameras cameras is built from
    (TRIAL_TRACKS_PER_CAMERA)."""
    return TRIAL_TRACKS_PER_CAMERA * num_cameras


def agreement_deg(intrinsics: Sequence[Optional[CameraIntrinsics]], config: SfMConfig) -> float:
    """How far apart (deg, as states_disagreement_deg and consensus.rig_disagreement_deg measure)
    two reconstructions of these cameras may be and still count as one answer.

    AGREEMENT_DEG, or where the SfM held the principal point at the image centre (the regular
    preset: SfMConfig.principal_point_cameras) the turn a real lens's offset leaves in every
    reconstruction alike (HELD_PRINCIPAL_POINT_OFFSET_FRACTION x side / focal, the median over
    those cameras; None: a camera not registered), if larger, at most MAX_AGREEMENT_DEG.
    Reconstructions that differ by less than that bias are one answer: a choice between them
    cannot make the rig more accurate than the held principal point lets it be, which the image
    refinement then frees (docs/design-notes.md, Consensus: best fit vs vote). It exceeds
    AGREEMENT_DEG for lenses wider than about 47 deg across the long side (focal under 1.15x it)."""
    refined = set(config.principal_point_cameras(len(intrinsics)))
    turns = [np.degrees(HELD_PRINCIPAL_POINT_OFFSET_FRACTION * max(cam.width, cam.height)
                        / mean_focal_px(cam))
             for c, cam in enumerate(intrinsics) if cam is not None and c not in refined]
    if not turns:
        return AGREEMENT_DEG
    return float(np.clip(np.median(turns), AGREEMENT_DEG, MAX_AGREEMENT_DEG))


def settled_starts(costs: dict, states: dict, agree_deg: float = AGREEMENT_DEG
                   ) -> Optional[list[str]]:
    """The SETTLED_STARTS best starts' names where the multi-start settled, else None.

    costs: start name -> (-registered cameras, truncated cost) of the plausible trials; states:
    start name -> the trial's SfMState. Settled: the trials that register as many cameras as the
    best and fit within WORSE_FIT_RATIO of it are at least two, and all of them agree with the
    best within agree_deg (agreement_deg). Then the focal lengths are not in doubt: every start
    that fits about as well ends in the same rig, so a later run on another track sample needs no
    more than its best starts (core.pipeline's consensus)."""
    if not costs:
        return None
    best = min(costs, key=costs.get)
    registered, best_cost = costs[best]
    contenders = sorted((n for n, (r, c) in costs.items()
                         if r == registered and c <= WORSE_FIT_RATIO * best_cost),
                        key=costs.get)
    if len(contenders) < 2 or any(states_disagreement_deg(states[best], states[n])
                                  >= agree_deg for n in contenders[1:]):
        return None
    return contenders[:SETTLED_STARTS]


def states_disagreement_deg(a: SfMState, b: SfMState) -> float:
    """Mean over the pairs of cameras registered in `a` of the larger of the relative-rotation and
    translation-direction differences between the two reconstructions (deg; a pair with a
    camera that `b` did not register counts 180)."""
    poses = [{c: state.cam_from_world[c] for c in state.registered()} for state in (a, b)]
    pairs = relative_pose_errors(poses[1], poses[0])
    return float(np.mean([min(p.max_err_deg, 180.0) for p in pairs])) if pairs else 0.0


def _trial(tracks: Tracks, start: list[CameraIntrinsics], camera_names: Sequence[str],
           config: SfMConfig, seed: int, first_pair: Optional[tuple[int, int]],
           validation_tracks: Optional[Tracks]
           ) -> tuple[Optional[IncrementalResult], list[str], Optional[float]]:
    """One multi-start trial (run_incremental): (its result, None where no pair could start it;
    its progress messages; its truncated cost, None where its intrinsics are implausible)."""
    messages: list[str] = []
    try:
        trial = incremental_sfm(tracks, start, camera_names, config, seed, messages.append,
                             first_pair)
    except NotEnoughOverlapError:
        return None, messages, None
    if implausible_cameras(trial.state):
        return trial, messages, None
    truncation = cost_truncation_px(config, tracks.num_cameras)
    if validation_tracks is not None and validation_tracks.num_tracks:
        return trial, messages, held_out_cost(trial.state, validation_tracks, truncation, seed)
    return trial, messages, truncated_cost(trial.state, truncation)


def first_pair_starts(tracks: Tracks, max_pairs: int = MAX_FIRST_PAIR_STARTS
                      ) -> list[tuple[int, int]]:
    """The camera pairs (i < j) sharing at least MIN_PAIR_CORRESPONDENCES tracks, the most
    shared first, at most min(max_pairs, MAX_FIRST_PAIR_STARTS)."""
    shared = pair_track_counts(tracks)
    pairs = [(i, j) for i, j in itertools.combinations(range(tracks.num_cameras), 2)
             if shared[i, j] >= MIN_PAIR_CORRESPONDENCES]
    return sorted(pairs, key=lambda p: -shared[p])[:min(max_pairs, MAX_FIRST_PAIR_STARTS)]


def focal_starts(intrinsics: Sequence[CameraIntrinsics], fixed: Sequence[int] = ()
                 ) -> dict[str, list[CameraIntrinsics]]:
    """The multi-start's starting intrinsics by name: the initial focals scaled ("x1.30"), and for
    perspective models the generic priors ("prior 0.85"). The cameras in `fixed` (given
    intrinsics) keep theirs in every start; when that is every camera there is one start,
    "given".

    A prior is run even where it is within ~1.15x of a scaled start for every camera: it gives
    every camera the same focal where the scaled start keeps eq. 2's ratios between cameras, and
    the two can end in different rigs: skipping such priors saved some SfM time but turned runs
    wrong that a prior had got right (docs/design-notes.md, Focal starts and multi-start
    costs)."""
    # A fisheye model's initial focal is already a lens-model prior, not an eq. 2 estimate: the
    # eq. 2 step and the generic priors move only the perspective cameras (a rig mixing lenses).
    free = [c not in fixed for c in range(len(intrinsics))]
    if not any(free):
        return {"given": list(intrinsics)}
    perspective = ["FISHEYE" not in cam.model and f for cam, f in zip(intrinsics, free)]
    starts = {f"x{f:.2f}": _scaled_focals(intrinsics, f, free) for f in FOCAL_SCALE_STARTS}
    if any(perspective):
        starts.update({f"x{f:.2f}": _scaled_focals(intrinsics, f, perspective)
                       for f in EQ2_EXTRA_FOCAL_SCALE_STARTS})
        starts.update({f"prior {ratio:g}": _prior_focals(intrinsics, ratio, perspective)
                       for ratio in PRIOR_FOCAL_IMAGE_RATIOS})
    return starts


def _on_all_tracks(tracks: Tracks, trial: IncrementalResult, start: list[CameraIntrinsics],
                   first_pair: Optional[tuple[int, int]], camera_names: Sequence[str],
                   config: SfMConfig, seed: int, say: Callable[[str], None]
                   ) -> IncrementalResult:
    """The winning subsample trial carried to all tracks: its cameras finished on every track.

    Not a fresh incremental run from the trial's start: on all tracks that run takes another,
    chaotic path through registration and can end in a wrong reconstruction although its start
    won on the subsample (docs/design-notes.md, Focal starts and multi-start costs).
    Only when the trial left a camera unregistered is a full run made as well (it may register
    the camera from the extra tracks), and the better of the two kept."""
    finished = finish_on(tracks, trial, camera_names, config, seed)
    say(f"multi-start trial finished on all {tracks.num_tracks} tracks: "
        f"{int(finished.state.point_mask().sum())} points")
    if not finished.failed:
        return finished
    full = incremental_sfm(tracks, start, camera_names, config, seed, say, first_pair)
    truncation = cost_truncation_px(config, tracks.num_cameras)

    def rank(r: IncrementalResult) -> tuple[int, float]:
        return -len(r.state.registered()), truncated_cost(r.state, truncation)
    return finished if rank(finished) <= rank(full) else full


def _focal_idxs(cam: CameraIntrinsics) -> list[int]:
    """Indices of the focal length(s) in cam.params (COLMAP's order for cam.model)."""
    return list(pycolmap.Camera(model=cam.model, width=cam.width, height=cam.height,
                                params=np.asarray(cam.params, dtype=np.float64)
                                ).focal_length_idxs())


def _prior_focals(intrinsics: Sequence[CameraIntrinsics], ratio: float,
                  which: Optional[Sequence[bool]] = None) -> list[CameraIntrinsics]:
    """The cameras (those `which` marks; default all) with focal = ratio x max(width, height) px."""
    out = []
    for c, cam in enumerate(intrinsics):
        params = np.array(cam.params, dtype=np.float64)
        if which is None or which[c]:
            params[_focal_idxs(cam)] = ratio * max(cam.width, cam.height)
        out.append(CameraIntrinsics(cam.model, cam.width, cam.height, params))
    return out


def _scaled_focals(intrinsics: Sequence[CameraIntrinsics], factor: float,
                   which: Optional[Sequence[bool]] = None) -> list[CameraIntrinsics]:
    """The cameras (those `which` marks; default all) with their focal lengths times factor."""
    out = []
    for c, cam in enumerate(intrinsics):
        params = np.array(cam.params, dtype=np.float64)
        if which is None or which[c]:
            params[_focal_idxs(cam)] *= factor
        out.append(CameraIntrinsics(cam.model, cam.width, cam.height, params))
    return out


def held_out_cost(state: SfMState, tracks: Tracks, truncation_px, seed: int = 0) -> float:
    """truncated_cost of other tracks of the same cameras, triangulated from state's cameras;
    truncated at most at HELD_OUT_TRUNCATION_PX."""
    truncation_px = np.minimum(truncation_px, HELD_OUT_TRUNCATION_PX)
    scratch = state.on_tracks(tracks)
    triangulate_tracks(scratch, max_error_px=float(np.max(truncation_px)), seed=seed)
    return truncated_cost(scratch, truncation_px)


def cost_truncation_px(config: SfMConfig, num_cameras: int):
    """Where the truncated cost stops counting an error: B_err, per camera (C,) where a rig mixing
    lenses judges its pinhole cameras by the regular preset's (SfMConfig.outlier_thresholds_px);
    TRUNCATION_FALLBACK_PX where B_err is off."""
    thresholds = config.outlier_thresholds_px(num_cameras)
    return thresholds if thresholds is not None else TRUNCATION_FALLBACK_PX


def truncated_cost(state: SfMState, truncation_px) -> float:
    """Mean over every observation, in registered cameras, of the tracks seen by >= 2 registered
    cameras of min(reprojection error, truncation_px); observations without a point (removed
    or not triangulated) count truncation_px. truncation_px: one value or one per camera (C,).
    Comparable between runs that register the same cameras, since it is computed over the same
    observations."""
    truncation_px = np.broadcast_to(np.asarray(truncation_px, float),
                                    (state.num_cameras,))[None, :]
    reg = np.zeros(state.num_cameras, dtype=bool)
    reg[state.registered()] = True
    obs = state.tracks.observed() & reg[None, :]
    obs &= (obs.sum(axis=1) >= 2)[:, None]
    err = reprojection_errors(state)
    err = np.where(np.isfinite(err), np.minimum(err, truncation_px), truncation_px)
    return float(err[obs].mean()) if obs.any() else float("inf")
