"""Incremental self-calibrating SfM of a static rig (paper Sec. 3.3 and implementation details).

1. View order by 3-cycle scores (view_order.py); the first pair among the first three views is
   chosen by brute force with the cost of eq. 3 (mean reprojection distance / number of points in
   front of both cameras, i.e. sum(d) / N^2).
2. The first pair's relative pose from an essential matrix on camera rays, triangulation, BA of
   the poses (two views do not constrain two focal lengths well, so intrinsics wait for the 3rd).
3. Each next camera: absolute pose (pycolmap.estimate_and_refine_absolute_pose, focal and
   distortion refined) from points seen by >= 2 registered cameras, BA, triangulation of the
   tracks that now have two registered views (the 2-cycle points), BA, removal of observations
   above B_err. A camera that shares only 2-cycle tracks with the registered ones is placed from
   its relative poses instead, trying several focal candidates (`_register_from_pairs`).
4. A final global BA (principal point refined per preset), every track re-triangulated from the
   final cameras, B_err, the final BA again and, for fisheye, a distortion-only refinement into
   the richer model (RADIAL_FISHEYE -> OPENCV_FISHEYE).
Every BA uses a Cauchy loss (COLMAP default scale) and `config.ba_iterations` iterations; those
that refine intrinsics are guarded against physically implausible lenses (plausibility.py), and
cameras that still end implausible are reported as failed.
"""
from __future__ import annotations

import functools
import itertools
import logging
from dataclasses import dataclass, replace
from typing import Callable, Optional, Sequence

import cv2
import numpy as np
import pycolmap

from ..config import SfMConfig
from ..errors import NotEnoughOverlapError
from ..parallel import map_jobs
from ..progress import say_progress
from ..types import CameraIntrinsics, Tracks
from .plausibility import bundle_adjust_plausibly, drop_implausible_cameras, implausible_cameras
from .reconstruction import (TRIANGULATION_MAX_ERROR_PX, BAStage, SfMState, bundle_adjust,
                             convert_camera_models, midpoint_triangulation,
                             remove_outlier_observations, reprojection_errors, triangulate,
                             triangulate_tracks)
from .twoview import relative_pose_from_rays
from .view_order import view_order

log = logging.getLogger(__name__)

MIN_PAIR_CORRESPONDENCES = 15  # fewer common tracks give no usable essential matrix
MIN_REGISTRATION_POINTS = 12  # 2D-3D correspondences needed to register a camera
MIN_REGISTRATION_INLIERS = 10
ESSENTIAL_THRESHOLD_PX = 2.0  # MAGSAC++ threshold of the first pair's essential matrix
ABSOLUTE_POSE_MAX_ERROR_PX = 12.0  # COLMAP's default RANSAC threshold for absolute pose
MIN_RAY_Z = 0.05  # rays closer to the image plane than this do not fit a perspective E model
FOCAL_SCALE_STARTS = (1.0, 1.3, 0.8)  # multi-start factors on the initial focals (run_incremental)
# One more step of 1.3 upwards where the initial focals come from eq. 2 (not fisheye models, whose
# start is a lens-model assumption): eq. 2 errs low on converging rigs (docs/design-notes.md).
EQ2_EXTRA_FOCAL_SCALE_STARTS = (1.69,)
# Generic focal priors (x max(width, height)), starts that do not depend on the F's, for perspective
# models: COLMAP's prior for unknown focals, 1.2 (45 deg across the long side), two wider lenses
# 1/sqrt(2) apart, 0.85 and 0.6 (62 and 81 deg: wide-angle trap and arena cameras), and two longer
# ones, 1.7 and 2.4 (33 and 24 deg: telephoto surveillance and lab cameras, where eq. 2 is most
# often degenerate: optical axes that nearly meet). Where eq. 2 degenerates it can miss by more
# than the scale starts span; the starts sit closer together than the ~1.4x a start may be off
# and still converge.
PRIOR_FOCAL_IMAGE_RATIOS = (1.2, 0.85, 0.6, 1.7, 2.4)
MULTISTART_MAX_TRACKS = 3000  # tracks the multi-start runs on (a seeded subsample)
# With every camera's intrinsics given there is no focal to explore; the run's other lottery is
# its first pair (eq. 3 picks among the first three views, on few points). So the multi-start runs
# from first pairs instead (the most shared tracks first), as many as the focal multi-start of the
# same lenses would have run (7 perspective, 3 fisheye: no slower than self-calibrating), at most
# this many (measured: docs/design-notes.md).
MAX_FIRST_PAIR_STARTS = 8
TRUNCATION_FALLBACK_PX = 20.0  # truncation of the multi-start cost when B_err is off
# Truncation (and triangulation gate) of the cost on raw keypoint matches (held_out_cost): COLMAP's
# two-view inlier threshold, the scale of a right match's error on a right rig. Raw matches are not
# cycle-verified (repetitive texture: many are wrong), and a loose gate lets a degenerate rig
# absorb wrong matches (measured on the fox: docs/design-notes.md).
HELD_OUT_TRUNCATION_PX = 4.0
# Focal candidates (x the current focal) for a camera registered from 2-view tracks only: eq. 2
# errs by up to a third there (docs/design-notes.md); the span is kept about symmetric in log.
PAIR_REGISTRATION_FOCAL_SCALES = (0.6, 0.75, 0.9, 1.0, 1.15, 1.35, 1.6)
PAIR_REGISTRATION_BA_ITERATIONS = 30


@dataclass
class IncrementalResult:
    state: SfMState
    view_order: list[int]  # the order cameras were tried in
    first_pair: tuple[int, int]
    failed: list[int]  # cameras that could not be registered
    # The cameras after registration and the first final BA, before `_finish` (re-triangulation
    # of every track, B_err, final BA, model refinement): what a multi-start trial hands on.
    registration: Optional[SfMState] = None


def initial_intrinsics(image_sizes: Sequence[tuple[int, int]], focal_px: np.ndarray,
                       model: str | Sequence[str]) -> list[CameraIntrinsics]:
    """Per camera `model` (one for all, or one per camera) with focal_px[c], the principal point
    at the image centre and zero distortion. image_sizes: (width, height) per camera."""
    models = [model] * len(image_sizes) if isinstance(model, str) else list(model)
    out = []
    for (w, h), f, model in zip(image_sizes, focal_px, models):
        cam = pycolmap.Camera.create_from_model_name(0, model, float(f), int(w), int(h))
        out.append(CameraIntrinsics.from_pycolmap(cam))
    return out


def _pair_rows(tracks: Tracks, i: int, j: int) -> np.ndarray:
    obs = tracks.observed()
    return np.flatnonzero(obs[:, i] & obs[:, j])


def _relative_pose(state: SfMState, i: int, j: int, seed: int
                   ) -> tuple[Optional[np.ndarray], np.ndarray]:
    """cam_j_from_cam_i (4x4, unit baseline) from an essential matrix (MAGSAC++) on the camera
    rays of the tracks both observe, and those tracks' rows. (None, rows) on failure."""
    rows = _pair_rows(state.tracks, i, j)
    if len(rows) < MIN_PAIR_CORRESPONDENCES:
        return None, rows
    rays_i = state.camera(i).to_pycolmap().cam_ray_from_img(state.tracks.xy_px[rows, i])
    rays_j = state.camera(j).to_pycolmap().cam_ray_from_img(state.tracks.xy_px[rows, j])
    usable = (rays_i[:, 2] > MIN_RAY_Z) & (rays_j[:, 2] > MIN_RAY_Z)
    if usable.sum() < MIN_PAIR_CORRESPONDENCES:
        return None, rows
    n_i = np.ascontiguousarray(rays_i[usable, :2] / rays_i[usable, 2:])
    n_j = np.ascontiguousarray(rays_j[usable, :2] / rays_j[usable, 2:])
    focal = 0.5 * (state.camera(i).params[0] + state.camera(j).params[0])
    cv2.setRNGSeed(int(seed))
    E, mask = cv2.findEssentialMat(n_i, n_j, np.eye(3), cv2.USAC_MAGSAC, 0.9999,
                                   ESSENTIAL_THRESHOLD_PX / focal)
    if E is None or E.shape != (3, 3):
        return None, rows
    inl = mask.ravel() > 0
    R, t, _ = relative_pose_from_rays(E, rays_i[usable][inl], rays_j[usable][inl])
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = R, t
    return pose, rows


def _first_pair_candidate(state: SfMState, i: int, j: int, max_error_px: float, seed: int
                          ) -> tuple[float, Optional[np.ndarray]]:
    """Relative pose cam_j_from_cam_i (4x4) and its eq. 3 cost sum(d) / N^2 (d: mean
    reprojection distance over the two views of each point in front of both cameras and within
    max_error_px, N their number). (inf, None) on failure."""
    pose_j, rows = _relative_pose(state, i, j, seed)
    if pose_j is None:
        return np.inf, None
    scratch = SfMState(state.tracks, state.intrinsics, state.camera_block,
                       [None] * state.num_cameras, state.points_xyz, state.active,
                       state.fixed_blocks)
    scratch.cam_from_world[i], scratch.cam_from_world[j] = np.eye(4), pose_j
    _, _, err = midpoint_triangulation(scratch, rows)
    pair_err = err[:, [i, j]]  # nan where behind a camera: the mean of the finite ones
    seen = np.isfinite(pair_err).sum(axis=1)
    d = np.where(seen > 0, np.nansum(pair_err, axis=1) / np.maximum(seen, 1), np.nan)
    front = np.isfinite(d) & (d <= max_error_px)
    n = int(front.sum())
    if n < MIN_PAIR_CORRESPONDENCES:
        return np.inf, None
    return float(d[front].sum() / n ** 2), pose_j


def _register_from_pairs(state: SfMState, c: int, camera_names: Sequence[str], seed: int,
                         max_error_px: float, num_threads: int) -> bool:
    """Fallback registration of a camera that shares no 3D points with the reconstruction (only
    2-cycle tracks; common when baselines are wide and few 3-cycles close).

    Camera c's focal is still its initial estimate, which nothing has refined yet, and a relative
    pose from an essential matrix on wrongly scaled rays is biased (measured: wrong translation
    directions at 30 % focal error). So the pose is computed for several focal candidates
    (`_pair_registration_focals`) and the one whose 2-view points reproject best after a BA of
    c's pose and focal (everything else fixed) is kept: for 2-view tracks the reprojection error
    measures how well the E's agree across c's partners, which the wrong focal breaks."""
    best = (np.inf, None)
    for focal in _pair_registration_focals(state, c):
        trial = state.copy()
        _set_focal(trial, c, focal)
        if not _place_from_pairs(trial, c, seed):
            continue
        rows = np.flatnonzero(trial.active[:, c] & ~trial.triangulated()
                              & (trial.registered_active().sum(axis=1) >= 2))
        triangulate(trial, rows, max_error_px)
        others = tuple(r for r in trial.registered() if r != c)
        bundle_adjust(trial, camera_names,
                      BAStage(PAIR_REGISTRATION_BA_ITERATIONS, refine_focal=True,
                              refine_extra=False, fixed_pose_cameras=others,
                              fixed_intrinsics_cameras=others), num_threads)
        cost = _camera_truncated_cost(trial, c, max_error_px)
        log.debug("pair registration of camera %d with focal %.1f px: cost %.3f px", c, focal, cost)
        if cost < best[0]:
            best = (cost, trial)
    if best[1] is None:
        return False
    state.cam_from_world[c] = best[1].cam_from_world[c]
    state.intrinsics[int(state.camera_block[c])] = best[1].camera(c)
    return True


def _pair_registration_focals(state: SfMState, c: int) -> list[float]:
    """Focal candidates for camera c: its current focal scaled by PAIR_REGISTRATION_FOCAL_SCALES,
    and the refined focal of every registered camera with the same image size (rigs often use
    identical cameras). Only the current focal when c's intrinsics are shared with a registered
    camera (they are refined already) or given (held)."""
    cam = state.camera(c)
    f_c = float(cam.to_pycolmap().mean_focal_length())
    if state.shares_intrinsics(c) or state.intrinsics_fixed(c):
        return [f_c]
    out = [f_c * s for s in PAIR_REGISTRATION_FOCAL_SCALES]
    for r in state.registered():
        other = state.camera(r)
        if (other.width, other.height) == (cam.width, cam.height):
            out.append(float(other.to_pycolmap().mean_focal_length()))
    return out


def _set_focal(state: SfMState, c: int, focal_px: float) -> None:
    cam = state.camera(c).to_pycolmap()
    params = np.array(cam.params, dtype=np.float64)
    params[list(cam.focal_length_idxs())] = focal_px
    state.intrinsics[int(state.camera_block[c])] = CameraIntrinsics(
        cam.model.name, int(cam.width), int(cam.height), params)


def _camera_truncated_cost(state: SfMState, c: int, truncation_px: float) -> float:
    """Mean of min(reprojection error, truncation_px) over camera c's active observations of tracks
    seen by >= 2 registered cameras; missing points count truncation_px. Unlike `truncated_cost`
    (which compares whole runs) it judges one camera's trial placement on the current state."""
    rows = state.active[:, c] & (state.registered_active().sum(axis=1) >= 2)
    if not rows.any():
        return np.inf
    err = reprojection_errors(state)[rows, c]
    truncation_px = min(truncation_px, TRUNCATION_FALLBACK_PX)
    return float(np.where(np.isfinite(err), np.minimum(err, truncation_px), truncation_px).mean())


def _place_from_pairs(state: SfMState, c: int, seed: int) -> bool:
    """Pose of camera c from its relative poses to registered cameras: orientation from the
    partner it shares the most tracks with; position from the baseline directions to all partners
    (least-squares intersection of the lines), or, with one partner, at the median distance
    between registered cameras (later 3-cycles and BA fix that scale)."""
    lines = []  # (partner centre, unit direction to c's centre in world, number of tracks)
    rotation, best = None, 0
    for r in state.registered():
        pose_cr, rows = _relative_pose(state, r, c, seed)
        if pose_cr is None:
            continue
        R_r, t_r = state.cam_from_world[r][:3, :3], state.cam_from_world[r][:3, 3]
        centre_r = -R_r.T @ t_r
        direction = R_r.T @ (-pose_cr[:3, :3].T @ pose_cr[:3, 3])
        lines.append((centre_r, direction / np.linalg.norm(direction)))
        if len(rows) > best:
            rotation, best = pose_cr[:3, :3] @ R_r, len(rows)
    if rotation is None:
        return False
    centres = [-T[:3, :3].T @ T[:3, 3] for T in (state.cam_from_world[r]
                                                 for r in state.registered())]
    spread = np.median([np.linalg.norm(a - b) for k, a in enumerate(centres)
                        for b in centres[k + 1:]])
    centre = lines[0][0] + spread * lines[0][1]
    if len(lines) >= 2:
        A = sum(np.eye(3) - np.outer(d, d) for _, d in lines)
        b = sum((np.eye(3) - np.outer(d, d)) @ o for o, d in lines)
        if np.linalg.cond(A) < 1e6:
            candidate = np.linalg.solve(A, b)
            if all(np.dot(candidate - o, d) > 0 for o, d in lines):
                centre = candidate
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = rotation, -rotation @ centre
    state.cam_from_world[c] = T
    return True


def _register_next(state: SfMState, c: int, config: SfMConfig) -> bool:
    """Absolute pose of camera c from 2D-3D correspondences to points seen by >= 2 registered
    cameras; focal and distortion are refined unless c shares an already registered camera's
    intrinsics or they are given. Sets state.cam_from_world[c] and c's intrinsics on success."""
    rows = np.flatnonzero(state.point_mask() & state.active[:, c])
    if len(rows) < MIN_REGISTRATION_POINTS:
        return False
    camera = state.camera(c).to_pycolmap()
    block_in_use = state.shares_intrinsics(c) or state.intrinsics_fixed(c)
    T = absolute_pose(state.tracks.xy_px[rows, c], state.points_xyz[rows], camera,
                      refine_intrinsics=not block_in_use,
                      refine_iterations=config.absolute_pose_refine_iterations)
    if T is None:
        return False
    state.cam_from_world[c] = T
    if not block_in_use:
        state.intrinsics[int(state.camera_block[c])] = CameraIntrinsics.from_pycolmap(camera)
    return True


def absolute_pose(xy_px: np.ndarray, points_xyz: np.ndarray, camera: pycolmap.Camera,
                  refine_intrinsics: bool, refine_iterations: int = 100) -> Optional[np.ndarray]:
    """cam_from_world (4x4) from 2D-3D correspondences (COLMAP px, world points): RANSAC
    (ABSOLUTE_POSE_MAX_ERROR_PX) then refinement of the pose and, with refine_intrinsics, of the
    focal and distortion, which `camera` then holds. None with fewer than
    MIN_REGISTRATION_INLIERS inliers."""
    estimation = pycolmap.AbsolutePoseEstimationOptions()
    estimation.ransac.max_error = ABSOLUTE_POSE_MAX_ERROR_PX
    estimation.ransac.random_seed = 0
    refinement = pycolmap.AbsolutePoseRefinementOptions()
    refinement.refine_focal_length = refine_intrinsics
    refinement.refine_extra_params = refine_intrinsics
    refinement.max_num_iterations = refine_iterations
    result = pycolmap.estimate_and_refine_absolute_pose(xy_px, points_xyz, camera, estimation,
                                                        refinement)
    if result is None or result["num_inliers"] < MIN_REGISTRATION_INLIERS:
        return None
    T = np.eye(4)
    T[:3, :4] = result["cam_from_world"].matrix()
    return T


def _triangulate_new(state: SfMState, max_error_px: float) -> int:
    """Triangulate every track without a point that has >= 2 active registered views."""
    rows = np.flatnonzero(~state.triangulated() & (state.registered_active().sum(axis=1) >= 2))
    return int(triangulate(state, rows, max_error_px).sum())


def run_incremental(tracks: Tracks, intrinsics: Sequence[CameraIntrinsics],
                    camera_names: Sequence[str], config: SfMConfig, seed: int = 0,
                    progress: Optional[Callable[[str], None]] = None,
                    validation_tracks: Optional[Tracks] = None,
                    extra_starts: Optional[dict[str, list[CameraIntrinsics]]] = None
                    ) -> IncrementalResult:
    """Register the rig's cameras one by one and refine them (module docstring).

    tracks: (T, C, 2) COLMAP px observations; intrinsics: initial CameraIntrinsics per camera
    (model = config.camera_model, focal from the initial-focal step). Raises NotEnoughOverlapError
    when no camera pair among the first three of the view order can be initialised.

    Multi-start on the focal scale: focal-from-F (eq. 2) is degenerate when the cameras' optical
    axes nearly meet (a common rig layout) and then tends to be off by a common factor (measured
    20-47 % low), from which incremental SfM converges to a wrong reconstruction. So the SfM is
    run from the initial focals scaled by each of FOCAL_SCALE_STARTS (and, for perspective
    models, EQ2_EXTRA_FOCAL_SCALE_STARTS and the generic priors PRIOR_FOCAL_IMAGE_RATIOS), on
    a seeded subsample of at most MULTISTART_MAX_TRACKS tracks, and the start with the lowest
    truncated reprojection cost gives the result: that trial itself when it ran on all tracks,
    else its cameras finished on all tracks (`_on_all_tracks`). The cost is taken on
    validation_tracks (other tracks of the same cameras, e.g. all keypoint matches, triangulated
    from the trial's cameras: `held_out_cost`) when given, else on the trial's own tracks
    (`truncated_cost`). A trial can fit the tracks it was built from better than the right rig
    does and still fit the matches it never saw worse (a 3-camera rig: 0.33 vs 0.41 px on its
    samples, 2.17 vs 2.02 px on the other matches), so the left-out matches judge more fairly.
    extra_starts: more named starting intrinsics for the multi-start (the eq. 2 estimate where
    `intrinsics` hold known focals: pipeline.calibrate_from_tracks). Where every camera's
    intrinsics are given (config.fixed_intrinsics_cameras) there is one focal start, and the
    multi-start runs from first pairs instead (first_pair_starts, MAX_FIRST_PAIR_STARTS).
    """
    say = functools.partial(say_progress, progress)
    starts = {name: (start, None) for name, start in
              {**focal_starts(intrinsics, config.fixed_intrinsics_cameras),
               **(extra_starts or {})}.items()}
    sub = tracks.sample(MULTISTART_MAX_TRACKS, seed)
    if len(config.fixed_intrinsics_cameras) == tracks.num_cameras and \
            config.brute_force_first_pair:
        budget = len(focal_starts(intrinsics))  # what self-calibrating would have run
        starts.update({f"given, first pair {camera_names[i]}/{camera_names[j]}":
                       (list(intrinsics), (i, j)) for i, j in first_pair_starts(sub, budget)})
    # Trials are independent: they run side by side (core.parallel), each BA on one core, so
    # the outcome does not depend on how many ran at once.
    trial_config = replace(config, num_threads=1)
    outcomes = map_jobs(_trial, [(sub, start, camera_names, trial_config, seed, pair,
                                  validation_tracks) for start, pair in starts.values()],
                        config.num_threads)
    costs, trials = {}, {}
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
        result = _incremental(tracks, start, camera_names, config, seed, say, pair)
    drop_implausible_cameras(result.state, result.failed, camera_names, say)
    return result


def _trial(tracks: Tracks, start: list[CameraIntrinsics], camera_names: Sequence[str],
           config: SfMConfig, seed: int, first_pair: Optional[tuple[int, int]],
           validation_tracks: Optional[Tracks]
           ) -> tuple[Optional[IncrementalResult], list[str], Optional[float]]:
    """One multi-start trial (run_incremental): (its result, None where no pair could start it;
    its progress messages; its truncated cost, None where its intrinsics are implausible)."""
    messages: list[str] = []
    try:
        trial = _incremental(tracks, start, camera_names, config, seed, messages.append,
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
    obs = tracks.observed().astype(np.int64)
    shared = obs.T @ obs
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
    the two can end in different rigs. Skipping such priors saved ~13 % of the SfM time but
    turned one of five consensus runs of a 4-camera rig wrong (from x1.30 and x1.69, where priors
    0.6 and 0.85 had been right), AUC@3 94.4 -> 88.9."""
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

    Not a fresh incremental run from the trial's start: on 7000 tracks that run takes another,
    chaotic path through registration and ended in a wrong reconstruction although its start won
    on the subsample (10-cam s102, sampling seed 1: three starts fit the subsample at 0.18 px,
    the re-run from the best fit all tracks at 10.5 px, AUC@3 0; finished from the trial: 0.17 px).
    Only when the trial left a camera unregistered is a full run made as well (it may register
    the camera from the extra tracks), and the better of the two kept."""
    finished = _finish_on(tracks, trial, camera_names, config, seed)
    say(f"multi-start trial finished on all {tracks.num_tracks} tracks: "
        f"{int(finished.state.point_mask().sum())} points")
    if not finished.failed:
        return finished
    full = _incremental(tracks, start, camera_names, config, seed, say, first_pair)
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


def _incremental(tracks: Tracks, intrinsics: Sequence[CameraIntrinsics],
                 camera_names: Sequence[str], config: SfMConfig, seed: int,
                 say: Callable[[str], None],
                 first_pair: Optional[tuple[int, int]] = None) -> IncrementalResult:
    """One incremental run; first_pair: start from this camera pair instead of choosing among the
    first three views by eq. 3."""
    C = tracks.num_cameras
    state = SfMState.create(tracks, intrinsics, config.share_intrinsics,
                            config.fixed_intrinsics_cameras)
    b_err = config.b_err_px if config.b_err_px is not None else np.inf
    order = view_order(tracks)
    if len(order) < 2:
        raise NotEnoughOverlapError(
            "No two cameras share sampled correspondences: check that the cameras' fields of view "
            "overlap and the scene is textured, or add more frame sets.")
    head = order[:3]
    candidates = list(itertools.combinations(head, 2)) if config.brute_force_first_pair \
        else [tuple(head[:2])]
    if first_pair is not None:
        candidates = [first_pair]
    best = (np.inf, None, None)
    for i, j in candidates:
        cost, pose = _first_pair_candidate(state, i, j, b_err, seed)
        log.debug("first pair (%s, %s): eq.3 cost %.3g", camera_names[i], camera_names[j], cost)
        if cost < best[0]:
            best = (cost, (i, j), pose)
    if best[1] is None:
        names = ", ".join(camera_names[c] for c in head)
        raise NotEnoughOverlapError(
            f"Could not initialise from any pair of cameras {names}: their shared correspondences "
            "give no consistent relative pose. Check the overlap, or use more frame sets.")
    (i, j), pose_j = best[1], best[2]
    state.cam_from_world[i], state.cam_from_world[j] = np.eye(4), pose_j
    _triangulate_new(state, b_err)
    bundle_adjust(state, camera_names, BAStage(config.ba_iterations, refine_focal=False,
                                               refine_extra=False), config.num_threads)
    say(f"initial pair {camera_names[i]} / {camera_names[j]}: "
        f"{int(state.point_mask().sum())} points")
    pending = [c for c in order if c not in (i, j)]
    stage = BAStage(config.ba_iterations, refine_focal=True, refine_extra=True,
                    refine_principal_point=False)
    extrinsics_only = BAStage(config.ba_iterations, refine_focal=False, refine_extra=False)
    while pending:
        # The next camera in view order that registers from 3D points; a camera can become
        # registrable once later cameras add points, so every pending camera is tried.
        c = next((c for c in pending if _register_next(state, c, config)), None)
        how = "3D points"
        if c is None:
            seen_by_registered = state.registered_active().any(axis=1)
            shared = [int(np.sum(state.active[:, c] & seen_by_registered)) for c in pending]
            c = pending[int(np.argmax(shared))]
            if not _register_from_pairs(state, c, camera_names, seed, b_err, config.num_threads):
                break
            how = "two-view geometry (2-cycle tracks only)"
        pending.remove(c)
        # Poses first, then intrinsics (as the global pipeline's stages): refining the focals
        # against a new camera's still-rough pose can drift them towards an affine solution on
        # near-planar scenes (measured on Strecha entry-P10: focals ran to 15x image size).
        bundle_adjust(state, camera_names, extrinsics_only, config.num_threads)
        bundle_adjust_plausibly(state, camera_names, stage, config.num_threads)
        _triangulate_new(state, b_err)
        bundle_adjust_plausibly(state, camera_names, stage, config.num_threads)
        removed = remove_outlier_observations(state, config.outlier_thresholds_px(C))
        say(f"registered {camera_names[c]} from {how} ({len(state.registered())}/{C}): "
            f"{int(state.point_mask().sum())} points, {removed} observations above B_err removed")
    failed = list(pending)
    final_adjustment(state, camera_names, config)
    registration = state.copy()
    _finish(state, camera_names, config, seed)
    failed += [c for c in range(C) if c not in order]
    return IncrementalResult(state=state, view_order=order, first_pair=(i, j),
                             failed=sorted(failed), registration=registration)


def final_stage(config: SfMConfig) -> BAStage:
    """The final global BA: everything but the principal point, which the preset decides."""
    return BAStage(config.ba_iterations, refine_focal=True, refine_extra=True,
                   refine_principal_point=config.refine_principal_point)


def final_adjustment(state: SfMState, camera_names: Sequence[str], config: SfMConfig) -> None:
    """The final global BA, in place. In a rig mixing lenses the principal point is refined for
    its fisheye cameras only (as the fisheye preset does; the regular preset keeps it fixed, the
    paper's ablation: refining it costs pinhole cameras AUC@3): pycolmap refines every camera's
    principal point or none, so a second pass refines it with the pinhole cameras' intrinsics
    held. Measured on generated rigs of 3-4 cameras with one fisheye: refining every camera's
    let every focal drift 4-8 % short (AUC@3 22-56); held for the pinhole cameras, 78-100."""
    pinhole = config.mixed_rig_pinhole_cameras(state.num_cameras)
    if not (config.refine_principal_point and pinhole):
        bundle_adjust_plausibly(state, camera_names, final_stage(config), config.num_threads)
        return
    held = BAStage(config.ba_iterations, refine_principal_point=False)
    bundle_adjust_plausibly(state, camera_names, held, config.num_threads)
    fisheye_pp = BAStage(config.ba_iterations, refine_principal_point=True,
                         fixed_intrinsics_cameras=pinhole)
    bundle_adjust_plausibly(state, camera_names, fisheye_pp, config.num_threads)


def _finish(state: SfMState, camera_names: Sequence[str], config: SfMConfig, seed: int) -> None:
    """Every track re-triangulated from the registered cameras, B_err, the final BA and the
    fisheye model refinement (module docstring, step 4); in place."""
    # As COLMAP's mapper ends: every track re-triangulated (LO-RANSAC) from the final cameras, so
    # observations dropped against earlier, rougher cameras and tracks that could not be
    # triangulated then count again; B_err, then the final BA once more. Measured: 3-camera rigs
    # with ~100 tracks went from 4 % to 0.3 % focal error (AUC@3 44 -> 100).
    retriangulate_and_adjust(state, camera_names, config, seed,
                             config.outlier_thresholds_px(state.num_cameras))
    if config.refine_to_model:
        convert_camera_models(state, config.refine_to_model)
        bundle_adjust(state, camera_names, BAStage(config.ba_iterations, refine_focal=False,
                                                   refine_extra=True, refine_poses=False),
                      config.num_threads)


def retriangulate_and_adjust(state: SfMState, camera_names: Sequence[str], config: SfMConfig,
                             seed: int, outlier_px: Optional[float]) -> None:
    """In place: every observation active again, every track triangulated from the registered
    cameras (RANSAC gate B_err, else TRIANGULATION_MAX_ERROR_PX), observations above outlier_px
    dropped (None: none), then the final BA."""
    state.active = state.tracks.observed().copy()
    gate_px = config.b_err_px if config.b_err_px is not None else TRIANGULATION_MAX_ERROR_PX
    triangulate_tracks(state, max_error_px=gate_px, seed=seed)
    remove_outlier_observations(state, outlier_px)
    final_adjustment(state, camera_names, config)


def _finish_on(tracks: Tracks, trial: IncrementalResult, camera_names: Sequence[str],
               config: SfMConfig, seed: int) -> IncrementalResult:
    """The trial's registered cameras (poses and intrinsics before its finishing step), finished
    on `tracks` (a superset of the trial's)."""
    state = trial.registration.on_tracks(tracks)
    _finish(state, camera_names, config, seed)
    return IncrementalResult(state=state, view_order=trial.view_order,
                             first_pair=trial.first_pair, failed=list(trial.failed),
                             registration=trial.registration)
