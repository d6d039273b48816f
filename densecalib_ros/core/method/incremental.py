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
   its relative poses instead, trying several focal candidates (`register_from_pairs`).
4. A final global BA (principal point refined per preset), every track re-triangulated from the
   final cameras, B_err, the final BA again and, for fisheye, a distortion-only refinement into
   the richer model (RADIAL_FISHEYE -> OPENCV_FISHEYE).
Every BA uses a Cauchy loss (COLMAP default scale) and `config.ba_iterations` iterations; those
that refine intrinsics are guarded against physically implausible lenses (plausibility.py), and
cameras that still end implausible are reported as failed.
"""
from __future__ import annotations

import itertools
import logging
from dataclasses import dataclass
from typing import Callable, Optional, Sequence

import cv2
import numpy as np
import pycolmap

from ..config import SfMConfig
from ..errors import NotEnoughOverlapError
from ..metrics import rotation_angle_deg
from ..types import CameraIntrinsics, Tracks
from .plausibility import bundle_adjust_plausibly
from .reconstruction import (TRIANGULATION_MAX_ERROR_PX, BAStage, SfMState, bundle_adjust,
                             camera_reprojection_errors, convert_camera_models,
                             midpoint_triangulation, remove_outlier_observations, triangulate,
                             triangulate_tracks)
from .twoview import relative_pose_from_rays
from .view_order import view_order

log = logging.getLogger(__name__)

MIN_PAIR_CORRESPONDENCES = 15  # fewer common tracks give no usable essential matrix
# An essential matrix is fixed by five correspondences: one that fits fewer fits nothing.
MIN_ESSENTIAL_INLIERS = 5
MIN_REGISTRATION_POINTS = 12  # 2D-3D correspondences needed to register a camera
MIN_REGISTRATION_INLIERS = 10
ESSENTIAL_THRESHOLD_PX = 2.0  # MAGSAC++ threshold of the first pair's essential matrix
ABSOLUTE_POSE_MAX_ERROR_PX = 12.0  # COLMAP's default RANSAC threshold for absolute pose
TRUNCATION_FALLBACK_PX = 20.0  # truncation of the costs when B_err is off
MIN_RAY_Z = 0.05  # rays closer to the image plane than this do not fit a perspective E model
# Focal candidates (x the current focal) for a camera registered from 2-view tracks only: eq. 2
# errs by up to a third there (docs/design-notes.md, Focal starts and multi-start costs); the
# span is kept about symmetric in log.
PAIR_REGISTRATION_FOCAL_SCALES = (0.6, 0.75, 0.9, 1.0, 1.15, 1.35, 1.6)
PAIR_REGISTRATION_BA_ITERATIONS = 30
# A camera placed from 2-view tracks takes its orientation from one partner's relative pose, and
# a partner whose matches are wrong (cameras facing each other across a ring, repeated texture)
# gives an orientation far from the others'. Orientations for the camera that differ by less
# than this are one hypothesis (the pose adjustment that follows converges from either); each
# farther one is tried on its own and the camera's reprojection cost decides, as between focals.
PAIR_ORIENTATION_AGREEMENT_DEG = 30.0


@dataclass
class IncrementalResult:
    state: SfMState
    view_order: list[int]  # the order cameras were tried in
    first_pair: tuple[int, int]
    failed: list[int]  # cameras that could not be registered
    # The cameras after registration and the first final BA, before `_finish` (re-triangulation
    # of every track, B_err, final BA, model refinement): what a multi-start trial hands on.
    registration: Optional[SfMState] = None
    # Set by the multi-start (multistart.settled_starts): the starts a later run on another
    # sample of the same matches needs, where this run's starts all ended in one rig; else None.
    settled_starts: Optional[list[str]] = None


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
    if inl.sum() < MIN_ESSENTIAL_INLIERS:  # none: recoverPose would raise
        return None, rows
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


def register_from_pairs(state: SfMState, c: int, camera_names: Sequence[str], seed: int,
                         max_error_px: float, num_threads: int) -> bool:
    """Fallback registration of a camera that shares no 3D points with the reconstruction (only
    2-cycle tracks; common when baselines are wide and few 3-cycles close).

    Camera c's focal is still its initial estimate, which nothing has refined yet, and a relative
    pose from an essential matrix on wrongly scaled rays is biased (wrong translation directions
    at a focal error eq. 2 can make: docs/design-notes.md, Incremental SfM). So the pose is
    computed for several focal candidates (`_pair_registration_focals`) and, for each, from
    every distinct orientation the partners give (`_partner_poses`,
    PAIR_ORIENTATION_AGREEMENT_DEG); the one whose 2-view points reproject best after a BA of c's
    pose and focal (everything else fixed) is kept: for 2-view tracks the reprojection error
    measures how well the E's agree across c's partners, which the wrong focal or a wrong
    partner breaks."""
    best = (np.inf, None)
    for focal in _pair_registration_focals(state, c):
        base = state.copy()
        set_focal(base, c, focal)
        partners = _partner_poses(base, c, seed)
        for anchor in _distinct_orientations(partners):
            trial = base.copy()
            _place_from_pairs(trial, c, partners, anchor)
            rows = np.flatnonzero(trial.active[:, c] & ~trial.triangulated()
                                  & (trial.registered_active().sum(axis=1) >= 2))
            triangulate(trial, rows, max_error_px)
            # Only c moves, so the points c does not see cannot change its pose, focal or cost:
            # they stay out of the adjustment (and only c's pose and intrinsics are kept).
            trial.points_xyz[~trial.active[:, c]] = np.nan
            others = tuple(r for r in trial.registered() if r != c)
            bundle_adjust(trial, camera_names,
                          BAStage(PAIR_REGISTRATION_BA_ITERATIONS, refine_focal=True,
                                  refine_extra=False, fixed_pose_cameras=others,
                                  fixed_intrinsics_cameras=others), num_threads)
            cost = _camera_truncated_cost(trial, c, max_error_px)
            log.debug("pair registration of camera %d with focal %.1f px, orientation from "
                      "camera %d: cost %.3f px", c, focal, partners[anchor].camera, cost)
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


def set_focal(state: SfMState, c: int, focal_px: float) -> None:
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
    err = camera_reprojection_errors(state, c)[rows]
    truncation_px = min(truncation_px, TRUNCATION_FALLBACK_PX)
    return float(np.where(np.isfinite(err), np.minimum(err, truncation_px), truncation_px).mean())


@dataclass
class _PartnerPose:
    """What one registered partner's relative pose says about camera c."""
    camera: int
    c_from_world: np.ndarray  # (3, 3) c's orientation
    centre: np.ndarray  # the partner's centre (world)
    direction: np.ndarray  # unit direction from the partner's centre to c's (world)
    num_tracks: int


def _partner_poses(state: SfMState, c: int, seed: int) -> list[_PartnerPose]:
    """Camera c's orientation and direction from each registered partner's relative pose (an E on
    their shared tracks: `_relative_pose`), in registration order."""
    out = []
    for r in state.registered():
        pose_cr, rows = _relative_pose(state, r, c, seed)
        if pose_cr is None:
            continue
        R_r, t_r = state.cam_from_world[r][:3, :3], state.cam_from_world[r][:3, 3]
        direction = R_r.T @ (-pose_cr[:3, :3].T @ pose_cr[:3, 3])
        out.append(_PartnerPose(r, pose_cr[:3, :3] @ R_r, -R_r.T @ t_r,
                                direction / np.linalg.norm(direction), len(rows)))
    return out


def _distinct_orientations(partners: list[_PartnerPose]) -> list[int]:
    """Indices of the partners, the most shared tracks first, whose orientations for c differ
    from every earlier kept one's by PAIR_ORIENTATION_AGREEMENT_DEG or more: each hypothesis is
    represented by its best-supported partner (with one hypothesis: the partner sharing the
    most tracks, as a single orientation always was)."""
    kept: list[int] = []
    for k in sorted(range(len(partners)), key=lambda k: -partners[k].num_tracks):
        if all(rotation_angle_deg(partners[k].c_from_world @ partners[a].c_from_world.T)
               >= PAIR_ORIENTATION_AGREEMENT_DEG for a in kept):
            kept.append(k)
    return kept


def _place_from_pairs(state: SfMState, c: int, partners: list[_PartnerPose], anchor: int
                      ) -> None:
    """Pose of camera c: orientation from partners[anchor]; position from the baseline
    directions of the partners whose orientations agree with it (least-squares intersection of
    the lines), or, with one such partner, at the median distance between registered cameras
    (later 3-cycles and BA fix that scale)."""
    rotation = partners[anchor].c_from_world
    lines = [(p.centre, p.direction) for p in partners
             if rotation_angle_deg(p.c_from_world @ rotation.T) < PAIR_ORIENTATION_AGREEMENT_DEG]
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


def incremental_sfm(tracks: Tracks, intrinsics: Sequence[CameraIntrinsics],
                    camera_names: Sequence[str], config: SfMConfig, seed: int,
                    say: Callable[[str], None],
                    first_pair: Optional[tuple[int, int]] = None) -> IncrementalResult:
    """One incremental run from `intrinsics` (module docstring; core.method.multistart runs it
    from several starts); first_pair: start from this camera pair instead of choosing among the
    first three views by eq. 3."""
    C = tracks.num_cameras
    state = SfMState.create(tracks, intrinsics, config.share_intrinsics,
                            config.fixed_intrinsics_cameras,
                            config.shared_intrinsics_groups)
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
            if not register_from_pairs(state, c, camera_names, seed, b_err, config.num_threads):
                break
            how = "two-view geometry (2-cycle tracks only)"
        pending.remove(c)
        # Poses first, then intrinsics (as the global pipeline's stages): refining the focals
        # against a new camera's still-rough pose can drift them towards an affine solution on
        # near-planar scenes (docs/design-notes.md, Incremental SfM).
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
    held: refining every camera's lets every focal drift short (docs/design-notes.md,
    Incremental SfM)."""
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
    # triangulated then count again; B_err, then the final BA once more. It matters most on rigs
    # with few tracks (docs/design-notes.md, Incremental SfM).
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


def finish_on(tracks: Tracks, trial: IncrementalResult, camera_names: Sequence[str],
               config: SfMConfig, seed: int) -> IncrementalResult:
    """The trial's registered cameras (poses and intrinsics before its finishing step), finished
    on `tracks` (a superset of the trial's)."""
    state = trial.registration.on_tracks(tracks)
    _finish(state, camera_names, config, seed)
    return IncrementalResult(state=state, view_order=trial.view_order,
                             first_pair=trial.first_pair, failed=list(trial.failed),
                             registration=trial.registration)
