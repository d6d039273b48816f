"""The SfM state of a static rig and its pycolmap glue: building a pycolmap Reconstruction from
tracks + intrinsics + poses, triangulation, bundle adjustment with per-stage refine flags, and
reprojection statistics.

Model: the rig's cameras are static, so each camera is one pycolmap image (with its own trivial
rig and frame) whose points2D are all of its track observations over all time steps. Point2D k of
camera c's image is track `SfMState.obs_track[c][k]`; track t's 3D point is `points_xyz[t]`.
All image coordinates are COLMAP pixels; poses are 4x4 `cam_from_world`.
"""
from __future__ import annotations

import dataclasses

import logging
from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np
import pycolmap

from ..types import CameraIntrinsics, CameraQuality, Tracks
from .colmap_points import add_points, camera_bits

log = logging.getLogger(__name__)

# Two-view points closer to parallel than this have ill-conditioned depth; COLMAP's default is 1.5.
MIN_TRIANGULATION_ANGLE_DEG = 1.0
TRIANGULATION_MAX_ERROR_PX = 16.0  # RANSAC triangulation inlier threshold (triangulate_tracks)
COVERAGE_GRID = 10  # coverage = fraction of a 10x10 grid of image cells holding an observation
# Ceres stops when an iteration lowers the cost by less than this fraction (Ceres' own default;
# COLMAP sets 0, which spends most iterations on changes far below the pixel noise).
FUNCTION_TOLERANCE = 1e-6


@dataclass
class SfMState:
    """Mutable reconstruction state over C static cameras and T tracks.

    tracks: the observations (T, C, 2) px, NaN = unobserved.
    intrinsics: one CameraIntrinsics per intrinsics block; `camera_block[c]` is camera c's block
        (identity unless intrinsics are shared between identical cameras).
    cam_from_world: per camera a 4x4 pose, or None while the camera is not registered.
    points_xyz: float64 (T, 3) world points, NaN where the track is not triangulated.
    active: bool (T, C) observations that take part in the reconstruction (observed, not
        removed as outliers).
    fixed_blocks: intrinsics blocks the user gave (SfMConfig.fixed_intrinsics_cameras): no
        bundle adjustment, registration or model change alters them.
    """

    tracks: Tracks
    intrinsics: list[CameraIntrinsics]
    camera_block: np.ndarray
    cam_from_world: list[Optional[np.ndarray]]
    points_xyz: np.ndarray
    active: np.ndarray
    fixed_blocks: frozenset = frozenset()

    @classmethod
    def create(cls, tracks: Tracks, intrinsics: Sequence[CameraIntrinsics],
               share_intrinsics: bool = False, fixed_cameras: Sequence[int] = (),
               shared_groups: Sequence[Sequence[int]] = ()) -> "SfMState":
        """intrinsics: one initial CameraIntrinsics per camera. With share_intrinsics, cameras of
        the same model and image size share one block (the first such camera's values);
        shared_groups: groups of cameras that share one (identical units).
        fixed_cameras: cameras whose intrinsics are given and held; each keeps a block of its
        own (sharing would let another camera's estimate overwrite them)."""
        blocks: list[CameraIntrinsics] = []
        camera_block = np.zeros(len(intrinsics), dtype=np.int64)
        keys: dict[tuple, int] = {}
        fixed = set(int(c) for c in fixed_cameras)
        group_of = {int(c): g for g, members in enumerate(shared_groups) for c in members}
        for c, cam in enumerate(intrinsics):
            key = (cam.model, cam.width, cam.height) if share_intrinsics and c not in fixed \
                else ("group", group_of[c]) if c in group_of and c not in fixed \
                else ("camera", c)
            if key not in keys:
                keys[key] = len(blocks)
                params = np.array(cam.params, dtype=np.float64)
                if key[0] == "group":  # identical units: the middle of their starts
                    params = np.median([np.asarray(intrinsics[m].params, dtype=np.float64)
                                        for m in shared_groups[key[1]]], axis=0)
                blocks.append(CameraIntrinsics(cam.model, cam.width, cam.height, params))
            camera_block[c] = keys[key]
        T = tracks.num_tracks
        return cls(tracks=tracks, intrinsics=blocks, camera_block=camera_block,
                   cam_from_world=[None] * tracks.num_cameras,
                   points_xyz=np.full((T, 3), np.nan), active=tracks.observed().copy(),
                   fixed_blocks=frozenset(int(camera_block[c]) for c in fixed))

    @property
    def num_cameras(self) -> int:
        return self.tracks.num_cameras

    def copy(self) -> "SfMState":
        """A scratch copy for trial steps (tracks are shared; they are never modified)."""
        return SfMState(self.tracks,
                        [CameraIntrinsics(c.model, c.width, c.height, c.params.copy())
                         for c in self.intrinsics],
                        self.camera_block.copy(),
                        [None if T is None else T.copy() for T in self.cam_from_world],
                        self.points_xyz.copy(), self.active.copy(), self.fixed_blocks)

    def on_tracks(self, tracks: Tracks) -> "SfMState":
        """A copy of the cameras (poses, intrinsics) over other tracks of the same cameras: no
        points yet, every observation active."""
        return dataclasses.replace(self.copy(), tracks=tracks,
                                   points_xyz=np.full((tracks.num_tracks, 3), np.nan),
                                   active=tracks.observed().copy())

    def with_own_blocks(self, cameras: Sequence[int]) -> "SfMState":
        """A copy in which each of `cameras` has a block of its own, starting from the values of
        the block it shared (identical units estimated as one by the SfM, each estimated on its
        own from here)."""
        out = self.copy()
        for c in cameras:
            shared = int(out.camera_block[c])
            if int(np.sum(out.camera_block == shared)) < 2:
                continue
            cam = out.intrinsics[shared]
            out.intrinsics.append(CameraIntrinsics(cam.model, cam.width, cam.height,
                                                   cam.params.copy()))
            out.camera_block[c] = len(out.intrinsics) - 1
        return out

    def camera(self, c: int) -> CameraIntrinsics:
        return self.intrinsics[int(self.camera_block[c])]

    def intrinsics_fixed(self, c: int) -> bool:
        """Whether camera c's intrinsics are given and held (fixed_blocks)."""
        return int(self.camera_block[c]) in self.fixed_blocks

    def registered(self) -> list[int]:
        return [c for c, pose in enumerate(self.cam_from_world) if pose is not None]

    def shares_intrinsics(self, c: int) -> bool:
        """Whether camera c's intrinsics block is used by another registered camera (it is then
        refined by that camera's registration and BA, not re-estimated for c)."""
        return any(self.camera_block[r] == self.camera_block[c]
                   for r in self.registered() if r != c)

    def triangulated(self) -> np.ndarray:
        """bool (T,): tracks with a 3D point."""
        return np.isfinite(self.points_xyz[:, 0])

    def registered_active(self) -> np.ndarray:
        """bool (T, C): active observations in registered cameras."""
        reg = np.zeros(self.num_cameras, dtype=bool)
        reg[self.registered()] = True
        return self.active & reg[None, :]

    def point_mask(self) -> np.ndarray:
        """bool (T,): tracks that are points of the reconstruction (3D point + >= 2 views)."""
        return self.triangulated() & (self.registered_active().sum(axis=1) >= 2)

    def drop_weak_points(self) -> None:
        """Forget the 3D point of tracks left with fewer than two active registered views."""
        self.points_xyz[~self.point_mask()] = np.nan


def rigid_from_matrix(T: np.ndarray) -> pycolmap.Rigid3d:
    return pycolmap.Rigid3d(np.asarray(T, dtype=np.float64)[:3, :4])


def matrix_from_rigid(rigid: pycolmap.Rigid3d) -> np.ndarray:
    T = np.eye(4)
    T[:3, :4] = rigid.matrix()
    return T


def build_reconstruction(state: SfMState, camera_names: Sequence[str]
                         ) -> tuple[pycolmap.Reconstruction, dict[int, int]]:
    """The registered cameras and the reconstruction's points as a pycolmap Reconstruction.

    Returns (reconstruction, track_of_point3D_id). Camera c has image_id = c + 1; block b has
    camera_id = rig_id = b + 1 (trivial rig per intrinsics block, one frame per image)."""
    rec = pycolmap.Reconstruction()
    registered = state.registered()
    for b in sorted({int(state.camera_block[c]) for c in registered}):
        rec.add_camera_with_trivial_rig(state.intrinsics[b].to_pycolmap(camera_id=b + 1))
    points = state.point_mask()
    obs = state.registered_active() & points[:, None]
    for c in registered:
        rows = np.flatnonzero(state.tracks.observed()[:, c])
        image = pycolmap.Image(name=str(camera_names[c]), keypoints=state.tracks.xy_px[rows, c],
                               camera_id=int(state.camera_block[c]) + 1, image_id=c + 1)
        rec.add_image_with_trivial_frame(image, rigid_from_matrix(state.cam_from_world[c]))
    rows = np.flatnonzero(points)
    ids = add_points(rec, state.tracks, rows, obs[rows], state.points_xyz)
    track_of_point = dict(zip(ids, rows.tolist()))
    return rec, track_of_point


def point_colours(tracks: Tracks, frame_sets: Sequence[Sequence[np.ndarray]]) -> np.ndarray:
    """uint8 (T, 3) RGB per track: the mean of the pixels it was observed at, each in its camera's
    image of the track's frame set (grey images give grey). Tracks hold COLMAP pixel coordinates
    (pixel i spans [i, i + 1))."""
    total = np.zeros((tracks.num_tracks, 3))
    count = np.zeros(tracks.num_tracks)
    observed = tracks.observed()
    for time in np.unique(tracks.time_index):
        in_set = tracks.time_index == time
        for c in range(tracks.num_cameras):
            rows = np.flatnonzero(in_set & observed[:, c])
            if not len(rows):
                continue
            image = np.asarray(frame_sets[int(time)][c])
            h, w = image.shape[:2]
            x = np.clip(np.floor(tracks.xy_px[rows, c, 0]).astype(np.int64), 0, w - 1)
            y = np.clip(np.floor(tracks.xy_px[rows, c, 1]).astype(np.int64), 0, h - 1)
            pixels = image[y, x].reshape(len(rows), -1)[:, :3].astype(np.float64)
            total[rows] += pixels if pixels.shape[1] == 3 else np.repeat(pixels[:, :1], 3, 1)
            count[rows] += 1
    return np.round(total / np.maximum(count, 1)[:, None]).astype(np.uint8)


def colour_points(rec: pycolmap.Reconstruction, state: SfMState,
                  frame_sets: Sequence[Sequence[np.ndarray]]) -> None:
    """Give the points of `rec` (build_reconstruction of `state`) the colour of the images
    (point_colours): the saved model then shows the scene in a viewer (export --format ply)."""
    colours = point_colours(state.tracks, frame_sets)
    observed = state.tracks.observed()
    rows_of_camera = {c: np.flatnonzero(observed[:, c]) for c in state.registered()}
    for point in rec.points3D.values():
        element = point.track.elements[0]  # image_id = camera + 1, point2D_idx = its rank
        point.color = colours[rows_of_camera[element.image_id - 1][element.point2D_idx]]


def read_reconstruction(state: SfMState, rec: pycolmap.Reconstruction,
                        track_of_point: dict[int, int]) -> None:
    """Copy intrinsics, poses and points of `rec` (built by build_reconstruction) into state."""
    for b in range(len(state.intrinsics)):
        if rec.exists_camera(b + 1):
            state.intrinsics[b] = CameraIntrinsics.from_pycolmap(rec.camera(b + 1))
    for c in state.registered():
        state.cam_from_world[c] = matrix_from_rigid(rec.image(c + 1).cam_from_world())
    for point_id, t in track_of_point.items():
        if rec.exists_point3D(point_id):
            state.points_xyz[t] = rec.point3D(point_id).xyz
        else:
            state.points_xyz[t] = np.nan


@dataclass
class BAStage:
    """Which parameters one bundle adjustment refines, and for how many iterations."""

    iterations: int = 100
    refine_focal: bool = True
    refine_extra: bool = True
    refine_principal_point: bool = False
    refine_poses: bool = True
    refine_points: bool = True
    fixed_pose_cameras: tuple[int, ...] = ()  # cameras whose pose stays constant
    fixed_intrinsics_cameras: tuple[int, ...] = ()  # cameras whose intrinsics block stays constant


def bundle_adjust(state: SfMState, camera_names: Sequence[str], stage: BAStage,
                  num_threads: int = -1) -> pycolmap.BundleAdjustmentSummary:
    """Refine `state` in place with COLMAP's Ceres BA (Cauchy loss, scale 1 px, COLMAP default).

    The gauge: if no pose is held fixed, the first registered camera's pose and the scale (via
    COLMAP's TWO_CAMS_FROM_WORLD gauge) are fixed; if one is, COLMAP's gauge takes that camera as
    its first and fixes the scale with one translation component of another camera (without it
    the scale drifts freely and can collapse)."""
    rec, track_of_point = build_reconstruction(state, camera_names)
    options = pycolmap.BundleAdjustmentOptions()
    options.refine_focal_length = stage.refine_focal
    options.refine_extra_params = stage.refine_extra
    options.refine_principal_point = stage.refine_principal_point
    options.refine_rig_from_world = stage.refine_poses
    options.refine_sensor_from_rig = False  # trivial rigs
    options.refine_points3D = stage.refine_points
    options.print_summary = False
    options.ceres.loss_function_type = pycolmap.LossFunctionType.CAUCHY
    options.ceres.loss_function_scale = 1.0
    options.ceres.solver_options.max_num_iterations = int(stage.iterations)
    options.ceres.solver_options.num_threads = int(num_threads)
    options.ceres.solver_options.function_tolerance = FUNCTION_TOLERANCE
    config = pycolmap.BundleAdjustmentConfig()
    for c in state.registered():
        config.add_image(c + 1)
    held = set(stage.fixed_intrinsics_cameras) | {c for c in state.registered()
                                                  if state.intrinsics_fixed(c)}
    for c in sorted(held):
        config.set_constant_cam_intrinsics(int(state.camera_block[c]) + 1)
    for c in stage.fixed_pose_cameras:
        config.set_constant_rig_from_world_pose(c + 1)  # frame_id = image_id (trivial frames)
    if stage.refine_poses and len(stage.fixed_pose_cameras) < 2:
        config.fix_gauge(pycolmap.BundleAdjustmentGauge.TWO_CAMS_FROM_WORLD)
    adjuster = pycolmap.create_default_bundle_adjuster(options, config, rec)
    summary = adjuster.solve()
    read_reconstruction(state, rec, track_of_point)
    return summary


def project(state: SfMState, c: int, X_world: np.ndarray) -> np.ndarray:
    """Pixels (N, 2) of world points (N, 3) in camera c; NaN behind the camera."""
    T = state.cam_from_world[c]
    X_cam = X_world @ T[:3, :3].T + T[:3, 3]
    xy = np.full((len(X_world), 2), np.nan)
    front = X_cam[:, 2] > 1e-9
    if front.any():
        xy[front] = state.camera(c).to_pycolmap().img_from_cam(X_cam[front])
    return xy


def reprojection_errors(state: SfMState) -> np.ndarray:
    """float64 (T, C): pixel reprojection error of every active observation of a reconstruction
    point in a registered camera; NaN elsewhere; inf where the point is behind the camera."""
    err = np.full(state.active.shape, np.nan)
    obs = state.registered_active() & state.point_mask()[:, None]
    for c in state.registered():
        _camera_errors_into(state, c, np.flatnonzero(obs[:, c]), err[:, c])
    return err


def camera_reprojection_errors(state: SfMState, c: int) -> np.ndarray:
    """float64 (T,): reprojection_errors(state)[:, c], without the other cameras' projections."""
    err = np.full(len(state.active), np.nan)
    obs = state.registered_active()[:, c] & state.point_mask()
    _camera_errors_into(state, c, np.flatnonzero(obs), err)
    return err


def _camera_errors_into(state: SfMState, c: int, rows: np.ndarray, err_c: np.ndarray) -> None:
    """Camera c's reprojection errors of tracks `rows` written into err_c (T,) (inf behind it)."""
    if len(rows):
        xy = project(state, c, state.points_xyz[rows])
        e = np.linalg.norm(xy - state.tracks.xy_px[rows, c], axis=1)
        err_c[rows] = np.where(np.isnan(e), np.inf, e)


def remove_outlier_observations(state: SfMState, max_error_px) -> int:
    """Deactivate observations with reprojection error above max_error_px (None = off; a float, or
    (C,) per camera); drop points left with < 2 views. Returns the number of observations
    removed."""
    if max_error_px is None:
        return 0
    err = reprojection_errors(state)
    bad = np.nan_to_num(err, nan=0.0, posinf=np.inf) > max_error_px
    state.active[bad] = False
    state.drop_weak_points()
    return int(bad.sum())


def camera_rays_world(state: SfMState, c: int, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit viewing rays (N, 3) in world frame of camera c's observations of tracks `rows`, and
    the camera centre (3,)."""
    T = state.cam_from_world[c]
    R, t = T[:3, :3], T[:3, 3]
    rays = state.camera(c).to_pycolmap().cam_ray_from_img(state.tracks.xy_px[rows, c])
    rays_world = rays @ R  # R^T applied to each row
    rays_world /= np.linalg.norm(rays_world, axis=1, keepdims=True)
    return rays_world, -R.T @ t


def midpoint_triangulation(state: SfMState, rows: np.ndarray
                           ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Triangulate tracks `rows` (N,) from their active observations in registered cameras: the
    least-squares midpoint of all viewing rays, vectorised over tracks.

    Returns X (N, 3) world points (NaN with < 2 views or parallel rays), angle_deg (N,) an upper
    estimate of the widest triangulation angle (twice the largest ray deviation from the mean
    ray), and err_px (N, C) reprojection errors (inf behind the camera, NaN where unobserved)."""
    rows = np.asarray(rows, dtype=np.int64)
    n = len(rows)
    obs = state.registered_active()[rows]
    A = np.zeros((n, 3, 3))
    b = np.zeros((n, 3))
    ray_sum = np.zeros((n, 3))
    rays = {}
    for c in state.registered():
        sel = np.flatnonzero(obs[:, c])
        if len(sel):
            d, centre = camera_rays_world(state, c, rows[sel])
            finite = np.isfinite(d).all(axis=1)  # no ray where the lens model does not invert
            obs[sel[~finite], c] = False
            sel, d = sel[finite], d[finite]
            P = np.eye(3)[None] - d[:, :, None] * d[:, None, :]
            A[sel] += P
            b[sel] += P @ centre
            ray_sum[sel] += d
            rays[c] = (sel, d)
    X = np.full((n, 3), np.nan)
    solvable = (obs.sum(axis=1) >= 2) & (np.abs(np.linalg.det(A)) > 1e-12)
    X[solvable] = np.linalg.solve(A[solvable], b[solvable][..., None])[..., 0]
    mean_dir = ray_sum / np.maximum(np.linalg.norm(ray_sum, axis=1, keepdims=True), 1e-12)
    angle = np.zeros(n)
    err = np.full((n, state.num_cameras), np.nan)
    for c, (sel, d) in rays.items():
        cos = np.clip(np.sum(d * mean_dir[sel], axis=1), -1.0, 1.0)
        angle[sel] = np.maximum(angle[sel], 2.0 * np.degrees(np.arccos(cos)))
        e = np.linalg.norm(project(state, c, np.nan_to_num(X[sel]))
                           - state.tracks.xy_px[rows[sel], c], axis=1)
        err[sel, c] = np.where(np.isfinite(e) & solvable[sel], e, np.inf)
    return X, angle, err


def triangulate(state: SfMState, rows: np.ndarray, max_error_px: float,
                min_angle_deg: float = MIN_TRIANGULATION_ANGLE_DEG) -> np.ndarray:
    """Triangulate tracks `rows` (midpoint_triangulation) and store the points that are in front
    of every view, reproject within max_error_px in every view and have a triangulation angle of
    at least min_angle_deg. Returns bool (len(rows),): which were stored."""
    rows = np.asarray(rows, dtype=np.int64)
    if len(rows) == 0:
        return np.zeros(0, dtype=bool)
    X, angle, err = midpoint_triangulation(state, rows)
    ok = np.isfinite(X[:, 0]) & (angle >= min_angle_deg)
    ok &= np.all(np.nan_to_num(err, nan=0.0) <= max_error_px, axis=1)
    state.points_xyz[rows[ok]] = X[ok]
    return ok


def camera_quality(state: SfMState, c: int, errors: Optional[np.ndarray] = None) -> CameraQuality:
    """Reprojection RMS, number of observations (and of those whose point >= 3 cameras see) and
    image coverage of camera c's observations of reconstruction points."""
    errors = reprojection_errors(state) if errors is None else errors
    e = errors[:, c]
    rows = np.flatnonzero(np.isfinite(e))
    cam = state.camera(c)
    if len(rows) == 0:
        return CameraQuality(reprojection_rms_px=float("nan"), num_observations=0, coverage=0.0,
                             num_multiview_observations=0)
    xy = state.tracks.xy_px[rows, c]
    gx = np.clip((xy[:, 0] / cam.width * COVERAGE_GRID).astype(int), 0, COVERAGE_GRID - 1)
    gy = np.clip((xy[:, 1] / cam.height * COVERAGE_GRID).astype(int), 0, COVERAGE_GRID - 1)
    coverage = len(np.unique(gy * COVERAGE_GRID + gx)) / COVERAGE_GRID ** 2
    views = np.isfinite(errors[rows]).sum(axis=1)
    return CameraQuality(reprojection_rms_px=float(np.sqrt(np.mean(e[rows] ** 2))),
                         num_observations=int(len(rows)), coverage=float(coverage),
                         num_multiview_observations=int(np.sum(views >= 3)))


def convert_camera_models(state: SfMState, model: str) -> None:
    """Re-express every intrinsics block of `model`'s lens family (fisheye or not) in `model`,
    keeping the projection identical where the source model is a special case of it
    (RADIAL_FISHEYE -> OPENCV_FISHEYE, RADIAL -> OPENCV ...). Blocks of the other family (the
    pinhole cameras of a rig mixing lenses) and given intrinsics (fixed_blocks) are left as
    they are."""
    for b, cam in enumerate(state.intrinsics):
        if b in state.fixed_blocks or cam.model == model or ("FISHEYE" in cam.model) != ("FISHEYE" in model):
            continue
        state.intrinsics[b] = CameraIntrinsics(model, cam.width, cam.height,
                                               _convert_params(cam.model, model, cam.params))


def _convert_params(src: str, dst: str, p: np.ndarray) -> np.ndarray:
    p = [float(v) for v in p]
    if src in ("RADIAL_FISHEYE", "SIMPLE_RADIAL_FISHEYE") and dst == "OPENCV_FISHEYE":
        k = p[3:] + [0.0] * (4 - len(p[3:]))
        return np.array([p[0], p[0], p[1], p[2], *k])
    if src in ("RADIAL", "SIMPLE_RADIAL") and dst == "OPENCV":
        k = p[3:] + [0.0] * (2 - len(p[3:]))
        return np.array([p[0], p[0], p[1], p[2], k[0], k[1], 0.0, 0.0])
    raise ValueError(f"No parameter conversion from {src} to {dst}.")


def triangulate_tracks(state: SfMState, max_error_px: float = TRIANGULATION_MAX_ERROR_PX,
                       min_angle_deg: float = MIN_TRIANGULATION_ANGLE_DEG, seed: int = 0) -> int:
    """Triangulate every track with >= 2 active registered views with
    pycolmap.estimate_triangulation (LO-RANSAC over all its views, reprojection error <=
    max_error_px, triangulation angle >= min_angle_deg). Sets state.points_xyz (NaN where it
    fails). Observations RANSAC rejects stay active: with initial poses a degree off (a bumped
    camera) whole cameras can look like outliers; BA's robust loss decides instead. Returns the
    number of triangulated tracks."""
    options = pycolmap.EstimateTriangulationOptions()
    options.residual_type = pycolmap.TriangulationResidualType.REPROJECTION_ERROR
    options.ransac.max_error = float(max_error_px)
    options.ransac.random_seed = int(seed)
    options.min_tri_angle = float(np.radians(min_angle_deg))
    cameras = [state.camera(c).to_pycolmap() for c in range(state.num_cameras)]
    poses = [rigid_from_matrix(T) if T is not None else None for T in state.cam_from_world]
    obs = state.registered_active()
    state.points_xyz[:] = np.nan
    rows = np.flatnonzero(obs.sum(axis=1) >= 2)
    bits = camera_bits(obs[rows])
    # Per set of cameras its poses and cameras, listed once: the loop is the calls alone.
    views = {}
    for b in np.unique(bits).tolist():
        cams = np.flatnonzero((b >> np.arange(state.num_cameras)) & 1)
        views[b] = (cams, [poses[c] for c in cams], [cameras[c] for c in cams])
    xy_px, estimate = state.tracks.xy_px, pycolmap.estimate_triangulation
    for t, b in zip(rows.tolist(), bits.tolist()):
        cams, cams_poses, cams_cameras = views[b]
        result = estimate(xy_px[t, cams], cams_poses, cams_cameras, options)
        if result is not None:
            state.points_xyz[t] = result["xyz"]
    return int(state.point_mask().sum())
