"""Focal hops: a local search over one camera's focal length at a time, from a finished rig.

Where the consensus runs disagree, the rig is weakly determined and the refined cost on all
keypoint matches has several minima that differ mainly in one camera's focal length and pose
(an end camera held by few 3-view tracks). No run need find the right one: the best of the runs
can keep an end camera's focal short while the true rig fits the same matches better
(docs/design-notes.md, Focal hops). A scaled start of the whole rig does not leave such a minimum
(the multi-start already ran those); a kick to one camera does.

So, from the kept rig: for each free camera, its focal is scaled by each of HOP_FACTORS, its
pose re-estimated for that focal from the points the other cameras triangulate, and the whole
rig refined on the keypoint matches again (all_matches.refine_on_tracks, every focal free), and
the trial is judged by the same truncated cost on the matches as the runs (incremental.
held_out_cost). The best trial replaces the rig when it lowers that cost by more than
MIN_RELATIVE_GAIN; rounds repeat until none does, at most MAX_ROUNDS. The kick only chooses the
basin: the refinement frees the focal again, so the result does not depend on the factor's exact
value.
"""
from __future__ import annotations

import logging
from dataclasses import replace
from typing import Callable, Optional, Sequence

import numpy as np

from ..config import SfMConfig
from ..method.all_matches import refine_on_tracks
from ..method.incremental import absolute_pose, set_focal
from ..method.multistart import (HELD_OUT_TRUNCATION_PX, MULTISTART_MAX_TRACKS, cost_truncation_px,
                                 held_out_cost)
from ..method.plausibility import implausible_cameras
from ..method.reconstruction import SfMState, triangulate_tracks
from ..parallel import map_jobs
from ..types import Tracks

log = logging.getLogger(__name__)

# Focal kicks (x the current focal): within the ~1.3x a start may be off and still converge
# (multistart.PRIOR_FOCAL_IMAGE_RATIOS), both sides, and far enough to reach the wrong minima seen
# (docs/design-notes.md, Focal hops).
HOP_FACTORS = (0.8, 0.9, 1.1, 1.25)
MIN_RELATIVE_GAIN = 0.01  # a hop must lower the cost by more than this fraction to be kept
MAX_ROUNDS = 3
MIN_POSE_POINTS = 12  # points of the other cameras needed to re-pose the kicked camera


def hop_focals(state: SfMState, match_tracks: Tracks, camera_names: Sequence[str],
               config: SfMConfig, seed: int = 0,
               say: Optional[Callable[[str], None]] = None) -> tuple[SfMState, list[str]]:
    """The rig of `state` (registered cameras, on match_tracks) after focal hops (module doc),
    judged and searched on a seeded sample of at most MULTISTART_MAX_TRACKS of match_tracks and,
    when a hop was kept, refined on all of them. Returns the state (the input one when no hop
    helped) and one line per kept hop."""
    say = say or (lambda msg: None)
    sample = match_tracks.sample(MULTISTART_MAX_TRACKS, seed)
    truncation = np.minimum(cost_truncation_px(config, state.num_cameras), HELD_OUT_TRUNCATION_PX)
    current = refine_on_tracks(state, sample, camera_names, config, seed)
    cost = held_out_cost(current, sample, truncation, seed)
    # The trials of a round are independent: they run side by side (core.parallel), each BA on
    # one core, so the outcome does not depend on how many ran at once (as the multi-start's).
    trial_config = replace(config, num_threads=1)
    hops: list[str] = []
    for _ in range(MAX_ROUNDS):
        best = (cost * (1.0 - MIN_RELATIVE_GAIN), None, "")
        tasks, labels = [], []
        for c in hop_cameras(current):
            focal = float(current.camera(c).to_pycolmap().mean_focal_length())
            points = points_without(current, c, seed)
            for factor in HOP_FACTORS:
                tasks.append((current, c, focal * factor, points, sample, camera_names,
                              trial_config, seed, truncation))
                labels.append(f"{camera_names[c]} x{factor:g}")
        for label, outcome in zip(labels, map_jobs(_hop_trial, tasks, config.num_threads)):
            if outcome is None:
                continue
            trial_cost, trial = outcome
            log.debug("focal hop %s: %.4f px (now %.4f)", label, trial_cost, cost)
            if trial_cost < best[0]:
                best = (trial_cost, trial, label)
        if best[1] is None:
            break
        hops.append(f"focal hop {best[2]}: truncated cost on {sample.num_tracks} keypoint-match "
                    f"tracks {cost:.3f} -> {best[0]:.3f} px")
        say(hops[-1])
        cost, current = best[0], best[1]
    if not hops:
        return state, hops
    return refine_on_tracks(current, match_tracks, camera_names, config, seed), hops


def _hop_trial(state: SfMState, c: int, focal_px: float, others: SfMState, sample: Tracks,
               camera_names: Sequence[str], config: SfMConfig, seed: int,
               truncation) -> Optional[tuple[float, SfMState]]:
    """One hop (a worker's task): camera c kicked to focal_px (kicked_state), the rig refined on
    `sample`, and its truncated cost; None where it could not be posed or ended implausible."""
    trial = kicked_state(state, c, focal_px, others)
    if trial is None:
        return None
    trial = refine_on_tracks(trial, sample, camera_names, config, seed)
    if implausible_cameras(trial):
        return None
    return held_out_cost(trial, sample, truncation, seed), trial


def hop_cameras(state: SfMState) -> list[int]:
    """Registered cameras whose focal may be kicked: not given, and for intrinsics shared between
    cameras only the first of the block (a kick moves the whole block)."""
    out, blocks = [], set()
    for c in state.registered():
        block = int(state.camera_block[c])
        if state.intrinsics_fixed(c) or block in blocks:
            continue
        blocks.add(block)
        out.append(c)
    return out


def points_without(state: SfMState, c: int, seed: int) -> SfMState:
    """A copy of `state` with every track triangulated from the registered cameras other than c
    (c's focal plays no part, so one copy serves every kick of c)."""
    others = state.copy()
    others.active[:, c] = False
    triangulate_tracks(others, max_error_px=HELD_OUT_TRUNCATION_PX, seed=seed)
    return others


def kicked_state(state: SfMState, c: int, focal_px: float, others: SfMState) -> Optional[SfMState]:
    """A copy of `state` with camera c's focal set to focal_px and its pose re-estimated for it
    from the points of `others` (points_without(state, c)); None when too few."""
    trial = state.copy()
    set_focal(trial, c, focal_px)
    rows = np.flatnonzero(others.point_mask() & trial.tracks.observed()[:, c])
    if len(rows) < MIN_POSE_POINTS:
        return None
    pose = absolute_pose(trial.tracks.xy_px[rows, c], others.points_xyz[rows],
                         trial.camera(c).to_pycolmap(), refine_intrinsics=False)
    if pose is None:
        return None
    trial.cam_from_world[c] = pose
    return trial
