"""Incremental self-calibrating SfM of a static rig (paper Sec. 3.3 and implementation details).

1. View order by 3-cycle scores (view_order.py); the first pair among the first three views is
   chosen by brute force with the cost of eq. 3 (mean reprojection distance / number of points in
   front of both cameras, i.e. sum(d) / N^2).
2. The first pair's relative pose from an essential matrix on camera rays, triangulation, BA of
   the poses (two views do not constrain two focal lengths well, so intrinsics wait for the 3rd).
3. Each next camera: absolute pose (pycolmap.estimate_and_refine_absolute_pose, focal and
   distortion refined) from points seen by >= 2 registered cameras, BA, triangulation of the
   tracks that now have two registered views (the 2-cycle points), BA, removal of observations
   above B_err.
4. A final global BA (principal point refined per preset) and, for fisheye, a distortion-only
   refinement into the richer model (RADIAL_FISHEYE -> OPENCV_FISHEYE).
Every BA uses a Cauchy loss (COLMAP default scale) and `config.ba_iterations` iterations.
"""
from __future__ import annotations

import itertools
import logging
from dataclasses import dataclass
from typing import Callable, Optional, Sequence

import cv2
import numpy as np
import pycolmap

from .config import SfMConfig
from .errors import NotEnoughCamerasError, NotEnoughOverlapError
from .reconstruction import (BAStage, SfMState, bundle_adjust, convert_camera_models,
                             midpoint_triangulation, remove_outlier_observations, triangulate)
from .twoview import relative_pose_from_rays
from .types import CameraIntrinsics, Tracks
from .view_order import view_order

log = logging.getLogger(__name__)

MIN_PAIR_CORRESPONDENCES = 15  # fewer common tracks give no usable essential matrix
MIN_REGISTRATION_POINTS = 12  # 2D-3D correspondences needed to register a camera
MIN_REGISTRATION_INLIERS = 10
ESSENTIAL_THRESHOLD_PX = 2.0  # MAGSAC++ threshold of the first pair's essential matrix
ABSOLUTE_POSE_MAX_ERROR_PX = 12.0  # COLMAP's default RANSAC threshold for absolute pose
MIN_RAY_Z = 0.05  # rays closer to the image plane than this do not fit a perspective E model


@dataclass
class IncrementalResult:
    state: SfMState
    view_order: list[int]  # the order cameras were tried in
    first_pair: tuple[int, int]
    failed: list[int]  # cameras that could not be registered


def initial_intrinsics(image_sizes: Sequence[tuple[int, int]], focal_px: np.ndarray,
                       model: str) -> list[CameraIntrinsics]:
    """Per camera `model` with focal_px[c], the principal point at the image centre and zero
    distortion. image_sizes: (width, height) per camera."""
    out = []
    for (w, h), f in zip(image_sizes, focal_px):
        cam = pycolmap.Camera.create_from_model_name(0, model, float(f), int(w), int(h))
        out.append(CameraIntrinsics.from_pycolmap(cam))
    return out


def _pair_rows(tracks: Tracks, i: int, j: int) -> np.ndarray:
    obs = tracks.observed()
    return np.flatnonzero(obs[:, i] & obs[:, j])


def _first_pair_candidate(state: SfMState, i: int, j: int, max_error_px: float, seed: int
                          ) -> tuple[float, Optional[np.ndarray]]:
    """Relative pose of camera j w.r.t. camera i (cam_j_from_cam_i, 4x4) from an essential matrix
    on camera rays, and its eq. 3 cost sum(d) / N^2 (d: mean reprojection distance over the two
    views of each point in front of both cameras, N their number). (inf, None) on failure."""
    rows = _pair_rows(state.tracks, i, j)
    if len(rows) < MIN_PAIR_CORRESPONDENCES:
        return np.inf, None
    rays_i = state.camera(i).to_pycolmap().cam_ray_from_img(state.tracks.xy_px[rows, i])
    rays_j = state.camera(j).to_pycolmap().cam_ray_from_img(state.tracks.xy_px[rows, j])
    usable = (rays_i[:, 2] > MIN_RAY_Z) & (rays_j[:, 2] > MIN_RAY_Z)
    if usable.sum() < MIN_PAIR_CORRESPONDENCES:
        return np.inf, None
    n_i = np.ascontiguousarray(rays_i[usable, :2] / rays_i[usable, 2:])
    n_j = np.ascontiguousarray(rays_j[usable, :2] / rays_j[usable, 2:])
    focal = 0.5 * (state.camera(i).params[0] + state.camera(j).params[0])
    cv2.setRNGSeed(int(seed))
    E, mask = cv2.findEssentialMat(n_i, n_j, np.eye(3), cv2.USAC_MAGSAC, 0.9999,
                                   ESSENTIAL_THRESHOLD_PX / focal)
    if E is None or E.shape != (3, 3):
        return np.inf, None
    R, t, _ = relative_pose_from_rays(E, rays_i[usable][mask.ravel() > 0],
                                      rays_j[usable][mask.ravel() > 0])
    pose_j = np.eye(4)
    pose_j[:3, :3], pose_j[:3, 3] = R, t
    scratch = SfMState(state.tracks, state.intrinsics, state.camera_block,
                       [None] * state.num_cameras, state.points_xyz, state.active)
    scratch.cam_from_world[i], scratch.cam_from_world[j] = np.eye(4), pose_j
    X, _, err = midpoint_triangulation(scratch, rows)
    d = np.nanmean(err[:, [i, j]], axis=1)
    front = np.isfinite(d) & (d <= max_error_px)
    n = int(front.sum())
    if n < MIN_PAIR_CORRESPONDENCES:
        return np.inf, None
    return float(d[front].sum() / n ** 2), pose_j


def _register_next(state: SfMState, c: int, config: SfMConfig) -> bool:
    """Absolute pose of camera c from 2D-3D correspondences to points seen by >= 2 registered
    cameras; focal and distortion are refined unless c shares an already registered camera's
    intrinsics. Sets state.cam_from_world[c] and c's intrinsics on success."""
    rows = np.flatnonzero(state.point_mask() & state.active[:, c])
    if len(rows) < MIN_REGISTRATION_POINTS:
        return False
    camera = state.camera(c).to_pycolmap()
    block_in_use = any(state.camera_block[r] == state.camera_block[c]
                       for r in state.registered())
    est = pycolmap.AbsolutePoseEstimationOptions()
    est.ransac.max_error = ABSOLUTE_POSE_MAX_ERROR_PX
    est.ransac.random_seed = 0
    ref = pycolmap.AbsolutePoseRefinementOptions()
    ref.refine_focal_length = not block_in_use
    ref.refine_extra_params = not block_in_use
    ref.max_num_iterations = config.absolute_pose_refine_iterations
    result = pycolmap.estimate_and_refine_absolute_pose(
        state.tracks.xy_px[rows, c], state.points_xyz[rows], camera, est, ref)
    if result is None or result["num_inliers"] < MIN_REGISTRATION_INLIERS:
        return False
    T = np.eye(4)
    T[:3, :4] = result["cam_from_world"].matrix()
    state.cam_from_world[c] = T
    if not block_in_use:
        state.intrinsics[int(state.camera_block[c])] = CameraIntrinsics.from_pycolmap(camera)
    return True


def _triangulate_new(state: SfMState, max_error_px: float) -> int:
    """Triangulate every track without a point that has >= 2 active registered views."""
    rows = np.flatnonzero(~state.triangulated() & (state.registered_active().sum(axis=1) >= 2))
    return int(triangulate(state, rows, max_error_px).sum())


def run_incremental(tracks: Tracks, intrinsics: Sequence[CameraIntrinsics],
                    camera_names: Sequence[str], config: SfMConfig, seed: int = 0,
                    progress: Optional[Callable[[str], None]] = None) -> IncrementalResult:
    """Register the rig's cameras one by one and refine them (module docstring).

    tracks: (T, C, 2) COLMAP px observations; intrinsics: initial CameraIntrinsics per camera
    (model = config.camera_model, focal from the initial-focal step). Raises NotEnoughOverlapError
    when no camera pair can be initialised and NotEnoughCamerasError when < 2 cameras register.
    """
    say = progress or (lambda msg: None)
    C = tracks.num_cameras
    state = SfMState.create(tracks, intrinsics, config.share_intrinsics)
    b_err = config.b_err_px if config.b_err_px is not None else np.inf
    order = view_order(tracks)
    if len(order) < 2:
        raise NotEnoughOverlapError(
            "No two cameras share sampled correspondences: check that the cameras' fields of view "
            "overlap and the scene is textured, or add more frame sets.")
    head = order[:3]
    candidates = list(itertools.combinations(head, 2)) if config.brute_force_first_pair \
        else [tuple(head[:2])]
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
    queue = [c for c in order if c not in (i, j)]
    failed: list[int] = []
    stage = BAStage(config.ba_iterations, refine_focal=True, refine_extra=True,
                    refine_principal_point=False)
    deferred: list[int] = []
    while queue:
        c = queue.pop(0)
        if not _register_next(state, c, config):
            # A camera can become registrable once later cameras add points: retry once at the end.
            if c not in deferred:
                deferred.append(c)
                queue.append(c)
            else:
                failed.append(c)
            continue
        bundle_adjust(state, camera_names, stage, config.num_threads)
        _triangulate_new(state, b_err)
        bundle_adjust(state, camera_names, stage, config.num_threads)
        removed = remove_outlier_observations(state, config.b_err_px)
        say(f"registered {camera_names[c]} ({len(state.registered())}/{C}): "
            f"{int(state.point_mask().sum())} points, {removed} observations above B_err removed")
    final = BAStage(config.ba_iterations, refine_focal=True, refine_extra=True,
                    refine_principal_point=config.refine_principal_point)
    bundle_adjust(state, camera_names, final, config.num_threads)
    if config.refine_to_model:
        convert_camera_models(state, config.refine_to_model)
        bundle_adjust(state, camera_names, BAStage(config.ba_iterations, refine_focal=False,
                                                   refine_extra=True, refine_poses=False),
                      config.num_threads)
    failed += [c for c in range(C) if c not in order]
    registered = state.registered()
    if len(registered) < 2:
        raise NotEnoughCamerasError("Fewer than two cameras could be registered.")
    return IncrementalResult(state=state, view_order=order, first_pair=(i, j),
                             failed=sorted(failed))
