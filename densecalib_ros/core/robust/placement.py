"""Check every camera's placement against all the matches; move the cameras they contradict.

Cycle sampling verifies tracks by closing cycles, which wrong matches can also do where a scene
repeats itself: on a wall covered in patterned wallpaper (the instant-ngp fox capture) a pair's
matches can be almost all wrong and still agree with one fundamental matrix (the pattern shifted
by a period), and cycles through two such pairs close. Incremental SfM can then register a camera
(or two nearly identical frames together) from those tracks into a wrong place that the rest of
the rig cannot pull it out of (docs/design-notes.md, Placement repair).

Such a placement shows in the raw matches (keypoint-match tracks): few of the camera's matches
with the other cameras fit it, while the other cameras' points, triangulated without it, place it
where many more fit. So, for groups of cameras (each registered camera alone, and with the camera
it shares the most matches with, which can hold it in a wrong place):
- support = the number of raw matches between the group and the other registered cameras whose
  two-view point reprojects within SUPPORT_MAX_ERROR_PX in both views, in front of both (matches
  within the group say nothing about where the group sits);
- the alternative: each member's absolute pose (RANSAC, then pose, focal and distortion refined;
  the pose only where intrinsics are shared) from the tracks it observes that at least two
  registered cameras outside the group triangulate;
- the group moves when the alternative has at least REPLACE_SUPPORT_RATIO x the support and
  MIN_SUPPORT_GAIN more matches. One group at a time, the largest ratio first; then every group is
  judged again (a moved camera changes the others' points).
- Focal tie-break, when no group moves so: a camera facing a flat scene nearly square on can sit
  at a wrong focal and distance that fit the matches as well as the right ones (the focal-distance
  ambiguity of a fronto-parallel plane). A camera whose focal is FOCAL_TIE_BREAK_RATIO x or more
  off the median focal of the other registered cameras of its image size (its peers) is moved to
  the alternative closest to their focal, among those at least as well supported; its pose alone
  at the peers' intrinsics is one of the alternatives (refined, the focal wanders along the
  ambiguity). A camera whose own focal the matches do pin down is left alone: no alternative at
  another focal fits as many of them.

What it cannot repair: a reconstruction wrong everywhere, or a wrong group of three or more
cameras. The all-match refinement (all_matches.py) runs after it. Measured on the fox and
generated rigs: docs/design-notes.md (Placement repair).
"""
from __future__ import annotations

import itertools
import logging
from typing import Callable, Optional, Sequence

import numpy as np

from ..method.incremental import MIN_REGISTRATION_POINTS, absolute_pose
from ..method.plausibility import intrinsics_problem
from ..method.reconstruction import (MIN_TRIANGULATION_ANGLE_DEG, SfMState, midpoint_triangulation)
from ..metrics import mean_focal_px, rotation_angle_deg
from ..parallel import map_threads
from ..types import CameraIntrinsics

log = logging.getLogger(__name__)

# A raw match supports a placement when its two-view point reprojects within this in both views:
# COLMAP's two-view geometry threshold (4 px). The cameras are final here, so right matches
# reproject to about a pixel.
SUPPORT_MAX_ERROR_PX = 4.0
# The alternative must explain half as many matches again: right placements come close to their
# alternative, wrong ones fall far behind it (docs/design-notes.md, Placement repair) ...
REPLACE_SUPPORT_RATIO = 1.5
MIN_SUPPORT_GAIN = 20  # ... and this many more (counts of a few matches are noise)
# A hypothesis within this of the current placement is that placement (wrong placements are tens
# of degrees off: docs/design-notes.md, Placement repair; smaller errors are the bundle
# adjustment's job).
SAME_PLACEMENT_DEG = 2.0
SAME_PLACEMENT_CENTRE = 0.05  # x the median distance between registered cameras
# Points for the alternative pose: reprojection gate in the views outside the group (the regular
# B_err; the absolute pose's RANSAC sorts out the rest).
LOO_POINT_MAX_ERROR_PX = 20.0
MAX_POSE_POINTS = 1000
# Focal tie-break: when an alternative placement fits at least as many matches, and its focal is
# this many times closer (as a ratio) to the focal of the other cameras of the same image size,
# it is taken. Matches cannot tell focal from distance for a camera facing a flat scene nearly
# square on (a wrong focal and pose can fit as many: docs/design-notes.md, Placement repair);
# the rig's other cameras can.
FOCAL_TIE_BREAK_RATIO = 1.5


def _scratch(state: SfMState, cam_from_world: Sequence[Optional[np.ndarray]]) -> SfMState:
    """A scratch state over the same tracks and intrinsics with the given poses and every
    observation active (tracks and intrinsics shared, not modified)."""
    return SfMState(state.tracks, state.intrinsics, state.camera_block, list(cam_from_world),
                    np.full((state.tracks.num_tracks, 3), np.nan), state.tracks.observed(),
                    state.fixed_blocks)


def pair_support(state: SfMState, a: int, b: int) -> int:
    """Number of raw matches between registered cameras a and b (keypoint-match tracks both
    observe) that fit their poses and intrinsics (module docstring)."""
    rows = np.flatnonzero(state.tracks.observed()[:, a] & state.tracks.observed()[:, b])
    if not len(rows):
        return 0
    poses: list[Optional[np.ndarray]] = [None] * state.num_cameras
    poses[a], poses[b] = state.cam_from_world[a], state.cam_from_world[b]
    X, _, err = midpoint_triangulation(_scratch(state, poses), rows)
    worst = np.nan_to_num(err[:, [a, b]], nan=np.inf).max(axis=1)
    return int(np.sum(np.isfinite(X[:, 0]) & (worst <= SUPPORT_MAX_ERROR_PX)))


def group_support(state: SfMState, group: Sequence[int]) -> int:
    """Raw matches between the cameras of `group` and the other registered cameras that fit.
    Matches within the group are not counted: they say nothing about where the group sits."""
    return sum(pair_support(state, a, b) for a in group for b in state.registered()
               if b not in group)


def pose_hypotheses(state: SfMState, c: int, left_out: Sequence[int]
                    ) -> list[tuple[np.ndarray, CameraIntrinsics]]:
    """Alternative (cam_from_world, intrinsics) of camera c from the points that the registered
    cameras outside `left_out` (which holds c) triangulate: one absolute pose per start in
    `_start_intrinsics`; none when too few points or inliers."""
    poses = [None if r in left_out else T for r, T in enumerate(state.cam_from_world)]
    others = _scratch(state, poses)
    rows = np.flatnonzero(state.tracks.observed()[:, c]
                          & (others.registered_active().sum(axis=1) >= 2))
    if len(rows) < MIN_REGISTRATION_POINTS:
        return []
    X, angle, err = midpoint_triangulation(others, rows)
    ok = (np.isfinite(X[:, 0]) & (angle >= MIN_TRIANGULATION_ANGLE_DEG)
          & (np.nan_to_num(err, nan=0.0).max(axis=1) <= LOO_POINT_MAX_ERROR_PX))
    if ok.sum() < MIN_REGISTRATION_POINTS:
        return []
    use = np.flatnonzero(ok)
    if len(use) > MAX_POSE_POINTS:  # a seeded subsample bounds the RANSAC's time
        use = np.sort(np.random.default_rng(c).choice(use, MAX_POSE_POINTS, replace=False))
    shared = state.shares_intrinsics(c) or state.intrinsics_fixed(c)  # held: one start
    starts = [(start, not shared) for start in _start_intrinsics(state, c, shared)]
    if len(starts) == 2 and len(left_out) == 1 and _focal_off_peers(
            state, c, peer_focal_px(state, c)) >= np.log(FOCAL_TIE_BREAK_RATIO):
        # The pose alone at the peers' intrinsics: the placement the focal tie-break prefers
        # where the matches cannot fix the focal (refined, it wanders along the ambiguity).
        # Only where the tie-break can apply: it costs another absolute pose.
        starts.append((starts[1][0], False))
    out = []
    for start, refine in starts:
        camera = start.to_pycolmap()
        T = absolute_pose(state.tracks.xy_px[rows[use], c], X[use], camera,
                          refine_intrinsics=refine)
        intrinsics = CameraIntrinsics.from_pycolmap(camera)
        if T is not None and intrinsics_problem(intrinsics) is None:
            out.append((T, intrinsics))
    return out


def _start_intrinsics(state: SfMState, c: int, shared: bool) -> list[CameraIntrinsics]:
    """Camera c's intrinsics, and, unless they are shared with a registered camera, the median
    intrinsics of the other registered cameras of its model and image size: a camera registered
    wrongly often has a wrong focal too (docs/design-notes.md, Placement repair), from which the
    absolute pose's RANSAC does not find the right pose (rigs often use identical cameras)."""
    own = state.camera(c)
    peers = _peers(state, c)
    if shared or not peers:
        return [own]
    return [own, CameraIntrinsics(own.model, own.width, own.height,
                                  np.median(np.array([state.camera(r).params for r in peers]),
                                            axis=0))]


def _peers(state: SfMState, c: int) -> list[int]:
    """The other registered cameras of camera c's model and image size."""
    own = state.camera(c)
    return [r for r in state.registered()
            if r != c and (state.camera(r).model, state.camera(r).width, state.camera(r).height)
            == (own.model, own.width, own.height)]


def _alternatives(state: SfMState, group: Sequence[int]) -> list[tuple[SfMState, int]]:
    """Trial states with every camera of `group` at a pose hypothesis (all combinations of the
    members' hypotheses), each with its support; combinations that leave the group where it is
    (`_same_placement`) are not scored. Empty when a member has no hypothesis."""
    options = [pose_hypotheses(state, c, group) for c in group]
    if not all(options):
        return []
    out = []
    for combination in itertools.product(*options):
        if all(_same_placement(state, c, T) for c, (T, _) in zip(group, combination)):
            continue
        trial = state.copy()
        for c, (T, K) in zip(group, combination):
            trial.cam_from_world[c] = T
            if not state.shares_intrinsics(c):
                trial.intrinsics[int(trial.camera_block[c])] = K
        out.append((trial, group_support(trial, group)))
    return out


def peer_focal_px(state: SfMState, c: int) -> Optional[float]:
    """Median focal of the other registered cameras of camera c's model and image size (None
    when there is none, or when c shares its intrinsics: then there is no focal of its own)."""
    peers = _peers(state, c)
    if not peers or state.shares_intrinsics(c):
        return None
    return float(np.median([mean_focal_px(state.camera(r)) for r in peers]))


def _focal_off_peers(state: SfMState, c: int, f_peer: float) -> float:
    """|log(f_c / f_peer)|: how far camera c's focal in `state` is from its peers' focal."""
    return abs(float(np.log(mean_focal_px(state.camera(c)) / f_peer)))


def _focal_tie_break(state: SfMState, c: int, alternatives: list[tuple[SfMState, int]],
                     now: int) -> Optional[tuple[SfMState, int]]:
    """Among camera c's alternatives that the matches support at least as well as its current
    placement, the one whose focal is closest to its peers' (`peer_focal_px`), when that is
    FOCAL_TIE_BREAK_RATIO times closer (in ratio) than the current focal; else None."""
    f_peer = peer_focal_px(state, c)
    tied = [(trial, n) for trial, n in alternatives if n >= now]
    if f_peer is None or not tied:
        return None
    trial, n = min(tied, key=lambda a: _focal_off_peers(a[0], c, f_peer))
    if _focal_off_peers(trial, c, f_peer) + np.log(FOCAL_TIE_BREAK_RATIO) \
            <= _focal_off_peers(state, c, f_peer):
        return trial, n
    return None


def _same_placement(state: SfMState, c: int, cam_from_world: np.ndarray) -> bool:
    """Whether a pose hypothesis of camera c is its current placement: within SAME_PLACEMENT_DEG
    and SAME_PLACEMENT_CENTRE x the median distance between registered cameras."""
    T = state.cam_from_world[c]
    turn = rotation_angle_deg(T[:3, :3] @ cam_from_world[:3, :3].T)
    centres = np.array([-P[:3, :3].T @ P[:3, 3] for P in
                        (state.cam_from_world[r] for r in state.registered())])
    spread = np.median(np.linalg.norm(centres[:, None] - centres[None], axis=2)[
        np.triu_indices(len(centres), 1)])
    shift = np.linalg.norm(-T[:3, :3].T @ T[:3, 3]
                           + cam_from_world[:3, :3].T @ cam_from_world[:3, 3])
    return turn <= SAME_PLACEMENT_DEG and shift <= SAME_PLACEMENT_CENTRE * spread


def _groups(state: SfMState) -> list[tuple[int, ...]]:
    """Every registered camera alone, and with the registered camera it shares the most raw
    matches with."""
    registered = state.registered()
    observed = state.tracks.observed()
    common = observed.T.astype(np.int64) @ observed.astype(np.int64)
    out: list[tuple[int, ...]] = [(c,) for c in registered]
    if len(registered) < 4:  # two cameras must remain to triangulate without a pair
        return out
    for c in registered:
        partner = max((r for r in registered if r != c), key=lambda r: common[c, r])
        pair = tuple(sorted((c, partner)))
        if pair not in out:
            out.append(pair)
    return out


def repair_placements(state: SfMState, camera_names: Sequence[str],
                      say: Optional[Callable[[str], None]] = None) -> list[str]:
    """Move, in place, the cameras whose placement the raw matches contradict to where the other
    cameras' points place them (module docstring). `state` holds the found cameras over
    keypoint-match tracks (its points are not used). Returns the names of the moved cameras."""
    say = say or (lambda msg: None)
    moved: list[str] = []
    for _ in range(state.num_cameras):
        best = None  # (support ratio, group, trial, support now, support after)
        tie = None  # (group, trial, support now, support after): the focal tie-break
        groups = _groups(state)
        # Each group's hypotheses are found on `state` alone (absolute poses, seeded, outside
        # the GIL): side by side.
        for group, alternatives in zip(groups, map_threads(
                lambda g: _alternatives(state, g), groups)):
            if not alternatives:
                continue
            trial, after = max(alternatives, key=lambda a: a[1])
            now = group_support(state, group)
            log.debug("placement of %s: support %d, moved %d",
                      "+".join(camera_names[c] for c in group), now, after)
            if after >= REPLACE_SUPPORT_RATIO * now and after - now >= MIN_SUPPORT_GAIN:
                ratio = after / max(now, 1)
                if best is None or ratio > best[0]:
                    best = (ratio, group, trial, now, after)
            elif tie is None and len(group) == 1:
                found = _focal_tie_break(state, group[0], alternatives, now)
                if found is not None:
                    tie = (group, found[0], now, found[1])
        if best is not None:
            _, group, trial, now, after = best
            why = None
        elif tie is not None:
            group, trial, now, after = tie
            c = group[0]
            why = (f"its focal {mean_focal_px(state.camera(c)):.0f} px is far "
                   f"from the other cameras of its size (median {peer_focal_px(state, c):.0f} px), "
                   f"and the matches fit as well ({now} -> {after}) with focal "
                   f"{mean_focal_px(trial.camera(c)):.0f} px where the other "
                   "cameras' points place it")
        else:
            break
        for c in group:
            state.cam_from_world[c] = trial.cam_from_world[c]
            state.intrinsics[int(state.camera_block[c])] = trial.camera(c)
        names = [camera_names[c] for c in group]
        moved += names
        if why is not None:
            say(f"camera {names[0]}: {why}; moved there")
            continue
        which, it, they = ((f"camera {names[0]}", "it", "it was") if len(names) == 1 else
                           (f"cameras {' and '.join(names)}", "them", "they were"))
        say(f"{which}: only {now} of the matches with the other cameras fit where {they} "
            f"registered; moved to where the other cameras' points place {it} ({after} fit)")
    return list(dict.fromkeys(moved))  # a camera can move twice; name it once
