"""Global self-calibrating SfM of a static rig with staged bundle adjustment (paper Sec. 3.4 and
implementation details), initialised without VGGT.

1. View graph: cameras are linked when they share >= MIN_PAIR_TRACKS sampled tracks; a graph that
   splits raises DisconnectedViewGraphError naming the camera groups.
2. Initial poses (`SfMConfig.global_init`):
   - "rotation_averaging": the GLOMAP core of pycolmap 4.x on OUR tracks: per camera pair an
     essential matrix (MAGSAC++) on the rays of the initial intrinsics (focal from the
     initial-focal step) gives a relative pose; `pycolmap.run_rotation_averaging` (L1 + IRLS) gives
     the rotations and `pycolmap.run_global_positioning` (point-to-camera constraints on the tracks)
     the camera centres.
   - "previous": a previous RigCalibration of the same cameras (recalibration: the cameras may
     have moved a little); its intrinsics are the starting intrinsics too.
   - "incremental": the result of the incremental pipeline (multistart.run_incremental).
   With "rotation_averaging" and `global_multistart`, both it and "incremental" are refined and
   the better fit is kept, judged like the incremental multi-start on matches neither was fitted
   to (a sample of all keypoint matches) where the pipeline passes them.
3. Points: every track is triangulated from all its views with pycolmap.estimate_triangulation
   (LO-RANSAC on reprojection error), and again from the refined cameras before every BA stage.
4. Gauge: the world frame becomes the frame of the camera with the highest summed track score
   over tracks from >= 3-cycles; its pose stays fixed in every BA stage, and COLMAP's gauge fixes
   the scale with one translation component of another camera.
5. Staged BA (Cauchy loss, reconstruction.bundle_adjust), each stage adding parameters to the
   previous ones, a stage with 0 iterations is skipped: extrinsics (+ points) -> + focal ->
   + distortion -> + principal point; then, with `refine_to_model` (fisheye), the cameras are
   re-expressed in the richer model and only its distortion (+ points) is refined ("model").
   There is no outlier removal by reprojection error (B_err) in the global pipeline (paper): all
   observations take part in every stage; observations above TRIANGULATION_MAX_ERROR_PX are
   left out of the result only after the last stage. The residuals after triangulation and after
   every stage are reported in `quality`.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace
from typing import Callable, Optional, Sequence

import numpy as np
import pycolmap

from ..config import B_ERR_PX, SfMConfig
from ..errors import (DisconnectedViewGraphError, FocalInitError, InputError, NotEnoughCamerasError,
                      NotEnoughOverlapError)
from ..progress import Progress
from ..types import CameraIntrinsics, RigCalibration, RigQuality, Tracks
from .incremental import ESSENTIAL_THRESHOLD_PX, MIN_PAIR_CORRESPONDENCES
from .multistart import cost_truncation_px, held_out_cost, run_incremental, truncated_cost
from .plausibility import bundle_adjust_plausibly, drop_implausible_cameras, implausible_cameras
from .previous_start import poses_from_previous
from .reconstruction import (TRIANGULATION_MAX_ERROR_PX, BAStage, SfMState, bundle_adjust,
                             convert_camera_models, matrix_from_rigid, reprojection_errors,
                             triangulate_tracks)
from .twoview import estimate_essential_from_rays
from .view_graph import check_connected, pair_track_counts
from .view_order import track_weights

log = logging.getLogger(__name__)

GLOBAL_INITS = ("rotation_averaging", "previous", "incremental")
MIN_PAIR_TRACKS = MIN_PAIR_CORRESPONDENCES  # shared tracks that make a view-graph edge
MAX_POSITIONING_TRACKS = 4000  # tracks given to global positioning (its cost grows with them)
CENTRE_GRID = 1e-5  # x the rig's size: global positioning's centres are rounded to it
MIN_CAMERA_OBSERVATIONS = 10  # a camera with fewer point observations after BA has failed
STAGES = ("extrinsics", "focal", "distortion", "principal_point")

@dataclass
class GlobalResult:
    """state: the refined reconstruction. view_order: cameras by gauge score, highest (the gauge
    camera) first. failed: cameras left without a pose. quality: init method, gauge camera, number
    of outlier observations left out of the result, residual_stats after triangulation and after
    each BA stage ("stage_residuals")."""

    state: SfMState
    view_order: list[int]
    failed: list[int]
    gauge_camera: int
    quality: RigQuality = field(default_factory=RigQuality)


def gauge_scores(tracks: Tracks) -> np.ndarray:
    """float (C,): per camera the summed score (1 per track when scoring is off) of the tracks it
    observes that come from cycles of order >= 3."""
    w = track_weights(tracks) * (tracks.cycle_order >= 3)
    return w @ tracks.observed().astype(np.float64)


def relative_poses(tracks: Tracks, intrinsics: Sequence[CameraIntrinsics], seed: int = 0
                   ) -> dict[tuple[int, int], tuple[np.ndarray, int]]:
    """{(i, j), i < j: (cam_j_from_cam_i 3x4 with unit translation, number of E inliers)} for every
    pair sharing >= MIN_PAIR_TRACKS tracks whose essential matrix (MAGSAC++ on the rays of
    `intrinsics`, threshold ESSENTIAL_THRESHOLD_PX) could be estimated."""
    obs = tracks.observed()
    cams = [cam.to_pycolmap() for cam in intrinsics]
    out = {}
    counts = pair_track_counts(tracks)
    for i in range(tracks.num_cameras):
        for j in range(i + 1, tracks.num_cameras):
            if counts[i, j] < MIN_PAIR_TRACKS:
                continue
            rows = np.flatnonzero(obs[:, i] & obs[:, j])
            focal = 0.5 * (intrinsics[i].params[0] + intrinsics[j].params[0])
            geom = estimate_essential_from_rays(
                cams[i].cam_ray_from_img(tracks.xy_px[rows, i]),
                cams[j].cam_ray_from_img(tracks.xy_px[rows, j]),
                ESSENTIAL_THRESHOLD_PX / focal, seed=seed)
            if geom.R_ji is not None and geom.num_inliers >= MIN_PAIR_TRACKS:
                out[(i, j)] = (np.c_[geom.R_ji, geom.t_ji], geom.num_inliers)
    return out


def _image_reconstruction(tracks: Tracks, intrinsics: Sequence[CameraIntrinsics]
                          ) -> pycolmap.Reconstruction:
    """One unposed image per camera (image_id = camera_id = c + 1), keypoints = its observations."""
    rec = pycolmap.Reconstruction()
    obs = tracks.observed()
    for c, cam in enumerate(intrinsics):
        rec.add_camera_with_trivial_rig(cam.to_pycolmap(camera_id=c + 1))
        rows = np.flatnonzero(obs[:, c])
        rec.add_image_with_trivial_frame(pycolmap.Image(
            name=str(c), keypoints=tracks.xy_px[rows, c], camera_id=c + 1, image_id=c + 1))
    return rec


def _positioning_tracks(tracks: Tracks, max_tracks: int) -> np.ndarray:
    """Rows of the tracks given to global positioning: all with >= 2 views, or the max_tracks of
    highest cycle order and score (ties in track order) when there are more."""
    rows = np.flatnonzero(tracks.observed().sum(axis=1) >= 2)
    if len(rows) > max_tracks:
        order = np.lexsort((rows, -tracks.score[rows], -tracks.cycle_order[rows]))
        rows = np.sort(rows[order[:max_tracks]])
    return rows


def rotation_averaging_poses(tracks: Tracks, intrinsics: Sequence[CameraIntrinsics],
                             camera_names: Sequence[str], seed: int = 0) -> list[np.ndarray]:
    """Initial cam_from_world (4x4 per camera) from pycolmap's rotation averaging and global
    positioning (the GLOMAP core) on our tracks (module docstring). Raises
    DisconnectedViewGraphError when the pairs with a relative pose (or the poses that rotation
    averaging accepts) do not connect all cameras."""
    from ..colmap_logging import quiet_colmap

    C = tracks.num_cameras
    pairs = relative_poses(tracks, intrinsics, seed)
    check_connected(C, list(pairs), camera_names, "consistent relative pose")
    rec = _image_reconstruction(tracks, intrinsics)
    pose_graph = pycolmap.PoseGraph()
    for (i, j), (cam_j_from_cam_i, num_inliers) in pairs.items():
        edge = pycolmap.PoseGraphEdge()
        edge.cam2_from_cam1 = pycolmap.Rigid3d(cam_j_from_cam_i)
        edge.num_matches = int(num_inliers)
        pose_graph.add_edge(i + 1, j + 1, edge)
    rotation_options = pycolmap.RotationEstimatorOptions()
    rotation_options.random_seed = int(seed)
    with quiet_colmap(2):
        ok = pycolmap.run_rotation_averaging(rotation_options, pose_graph, rec, [])
    posed = [c for c in range(C) if rec.image(c + 1).has_pose]
    if not ok or len(posed) < C:
        valid = [(i, j) for (i, j) in pairs if pose_graph.has_edge(i + 1, j + 1)
                 and pose_graph.get_edge(i + 1, j + 1).valid]
        check_connected(C, valid, camera_names, "relative rotation consistent with the others")
        missing = ", ".join(camera_names[c] for c in range(C) if c not in posed)
        raise DisconnectedViewGraphError(
            f"Rotation averaging gave no rotation for camera(s) {missing}: their relative poses "
            "disagree with the rest of the rig. Check their overlap with the other cameras.")
    # Global positioning: camera centres and points from the tracks' viewing rays.
    obs = tracks.observed()
    point2d_idx = np.cumsum(obs, axis=0) - 1
    for t in _positioning_tracks(tracks, MAX_POSITIONING_TRACKS):
        track = pycolmap.Track()
        track.add_elements([pycolmap.TrackElement(int(c) + 1, int(point2d_idx[t, c]))
                            for c in np.flatnonzero(obs[t])])
        rec.add_point3D(np.zeros(3), track)
    position_options = pycolmap.GlobalPositionerOptions()
    position_options.random_seed = int(seed)
    position_options.use_gpu = False
    position_options.min_num_view_per_track = 2
    with quiet_colmap(2):
        ok = pycolmap.run_global_positioning(position_options, pose_graph, rec)
    poses = [matrix_from_rigid(rec.image(c + 1).cam_from_world()) for c in range(C)]
    if not ok or not all(np.all(np.isfinite(T)) for T in poses):
        raise DisconnectedViewGraphError(
            "Global positioning could not place every camera from the shared tracks: the view "
            "graph is too weak. Add frame sets with common, textured content, or use the "
            "incremental pipeline.")
    return snapped_centres(poses)


def snapped_centres(cam_from_world: Sequence[np.ndarray]) -> list[np.ndarray]:
    """The poses with camera 0 moved to the origin and every camera centre rounded to a grid of
    about CENTRE_GRID x the rig's size (a power of two, so the grid itself does not wobble).

    pycolmap's global positioning runs Ceres on every core (the thread count is not exposed),
    and the order in which the threads add up terms varies, so the centres differ by a
    rounding-error amount from run to run, which the staged BA after it (outlier cuts, the
    choice between two starts) can turn into different rigs (docs/design-notes.md, Global
    positioning's run-to-run noise). Rounding makes the start identical unless a centre lies within
    that noise of a grid line (~1e-3 per coordinate); the BA refines the centres anyway."""
    centres = np.array([-T[:3, :3].T @ T[:3, 3] for T in cam_from_world])
    centres -= centres[0]
    size = np.median(np.linalg.norm(centres[1:], axis=1)) if len(centres) > 1 else 0.0
    if not (np.isfinite(size) and size > 0):
        return [np.array(T, dtype=np.float64) for T in cam_from_world]
    step = 2.0 ** np.round(np.log2(size * CENTRE_GRID))
    out = []
    for T, centre in zip(cam_from_world, np.round(centres / step) * step):
        snapped = np.array(T, dtype=np.float64)
        snapped[:3, 3] = -snapped[:3, :3] @ centre
        out.append(snapped)
    return out


def residual_stats(state: SfMState, max_error_px: float = TRIANGULATION_MAX_ERROR_PX) -> dict:
    """Reprojection residuals of the active observations of reconstruction points: median_px (all),
    rms_px (those <= max_error_px) and outlier_fraction (above it or behind the camera). Without
    outlier removal the plain RMS would only measure the few gross outliers."""
    err = reprojection_errors(state)
    err = err[~np.isnan(err)]
    inliers = err[err <= max_error_px]
    return dict(median_px=float(np.median(err)) if len(err) else float("nan"),
                rms_px=float(np.sqrt(np.mean(inliers ** 2))) if len(inliers) else float("nan"),
                outlier_fraction=float(1.0 - len(inliers) / len(err)) if len(err) else 0.0)


def _describe(stats: dict) -> str:
    return (f"median {stats['median_px']:.2f} px, RMS {stats['rms_px']:.2f} px of the residuals "
            f"<= {TRIANGULATION_MAX_ERROR_PX:.0f} px ({100 * stats['outlier_fraction']:.1f} % above)")


def to_gauge_frame(state: SfMState, gauge_camera: int) -> None:
    """Re-express poses and points in place in the gauge camera's frame, scaled so that the median
    distance of the other registered cameras from it is 1. COLMAP's scale gauge (one translation
    component of a second camera, bundle_adjust) only pins the scale when the fixed camera sits at
    the world origin: elsewhere the cameras can shrink towards it while that component stays put."""
    gauge_from_world = state.cam_from_world[gauge_camera].copy()
    world_from_gauge = np.linalg.inv(gauge_from_world)
    # The gauge camera is left out by index: its own distance comes out as 0 or as rounding noise
    # (1e-16) depending on the BLAS, and a test "d > 0" let that noise into the median.
    centres = [np.linalg.inv(T)[:3, 3] for c, T in enumerate(state.cam_from_world)
               if T is not None and c != gauge_camera]
    distances = [np.linalg.norm(gauge_from_world[:3, :3] @ c + gauge_from_world[:3, 3])
                 for c in centres]
    distances = [d for d in distances if d > 0]
    scale = 1.0 / float(np.median(distances)) if distances else 1.0
    for c, T in enumerate(state.cam_from_world):
        if T is not None:
            T = T @ world_from_gauge
            T[:3, 3] *= scale
            state.cam_from_world[c] = T
    state.points_xyz = scale * (state.points_xyz @ gauge_from_world[:3, :3].T
                                + gauge_from_world[:3, 3])


def staged_bundle_adjustment(state: SfMState, camera_names: Sequence[str], config: SfMConfig,
                             gauge_camera: int, progress: Progress = None, seed: int = 0
                             ) -> dict[str, dict]:
    """The staged BA of the module docstring, in place; before every stage but the first the
    tracks are re-triangulated from the current cameras (triangulate_tracks). Returns {stage:
    residual_stats after it} for the stages that ran."""
    say = Progress.of(progress).say
    iterations = dict(config.global_stage_iterations)
    stats: dict[str, dict] = {}
    # A rig mixing lenses refines the principal point of its fisheye cameras only
    # (incremental.final_adjustment): the pinhole cameras' intrinsics are held in that stage.
    held_in_pp_stage = config.mixed_rig_pinhole_cameras(state.num_cameras)
    for k, name in enumerate(STAGES):
        its = int(iterations.get(name, 0))
        if its <= 0:
            continue
        if stats:
            # Points triangulated from the previous stage's cameras are RANSAC consensus points:
            # a stage that starts from them is not pulled by observations fitted to a worse model.
            triangulate_tracks(state, seed=seed)
        stage = BAStage(its, refine_focal=k >= 1, refine_extra=k >= 2,
                        refine_principal_point=k >= 3, fixed_pose_cameras=(gauge_camera,),
                        fixed_intrinsics_cameras=held_in_pp_stage if k >= 3 else ())
        summary = bundle_adjust_plausibly(state, camera_names, stage, config.num_threads)
        stats[name] = residual_stats(state)
        say(f"global BA stage {name} ({its} it, {summary.termination_type.name}): "
            f"{_describe(stats[name])}")
    its = int(iterations.get("model", 0))
    if config.refine_to_model and its > 0:
        if stats:
            triangulate_tracks(state, seed=seed)
        convert_camera_models(state, config.refine_to_model)
        bundle_adjust(state, camera_names, BAStage(its, refine_focal=False, refine_extra=True,
                                                   refine_poses=False), config.num_threads)
        stats["model"] = residual_stats(state)
        say(f"global BA stage model ({config.refine_to_model}, {its} it): "
            f"{_describe(stats['model'])}")
    return stats


def run_global(tracks: Tracks, intrinsics: Sequence[CameraIntrinsics],
               camera_names: Sequence[str], config: SfMConfig, seed: int = 0,
               progress: Progress = None, previous: Optional[RigCalibration] = None,
               validation_tracks: Optional[Tracks] = None,
               extra_starts: Optional[dict] = None) -> GlobalResult:
    """Global SfM with staged BA (module docstring).

    tracks: (T, C, 2) COLMAP px observations; intrinsics: initial CameraIntrinsics per camera
    (model = config.camera_model, focal from the initial-focal step); previous: the calibration
    to start from when config.global_init == "previous"; validation_tracks: other tracks of the
    same cameras (e.g. a sample of all keypoint matches) on which the incremental start's
    multi-start and the choice between starts are judged (multistart.held_out_cost; None: on
    the tracks themselves); extra_starts: more named starting intrinsics for the incremental
    start's focal multi-start (run_incremental). Raises DisconnectedViewGraphError, InputError
    (unknown init, missing/unusable previous calibration), NotEnoughCamerasError.
    """
    say = Progress.of(progress).say
    C = tracks.num_cameras
    init = config.global_init
    if init not in GLOBAL_INITS:
        raise InputError(f"Unknown sfm.global_init {init!r}: choose one of "
                         f"{', '.join(GLOBAL_INITS)}.")
    counts = pair_track_counts(tracks)
    check_connected(C, [(i, j) for i in range(C) for j in range(i + 1, C)
                        if counts[i, j] >= MIN_PAIR_TRACKS], camera_names, "sampled tracks")
    if init == "previous":
        if previous is None:
            raise InputError("sfm.global_init is 'previous' but no previous calibration was "
                             "given: pass one, or use 'rotation_averaging'.")
        starts = [init]
    elif init == "rotation_averaging" and config.global_multistart:
        starts = ["rotation_averaging", "incremental"]
    else:
        starts = [init]
    candidates = []
    for name in starts:
        try:
            candidates.append((name, *_refine_from_start(name, tracks, intrinsics, camera_names,
                                                         config, seed, progress, previous,
                                                         validation_tracks, extra_starts)))
        except (NotEnoughOverlapError, NotEnoughCamerasError, DisconnectedViewGraphError,
                FocalInitError) as exc:
            if len(starts) == 1:
                raise
            say(f"global start {name} failed: {exc}")
    if not candidates:
        raise NotEnoughCamerasError(
            "Global SfM found no usable start (rotation averaging and incremental both failed): "
            "check that the cameras overlap and see textured scene content.")
    init, state, stats, gauge, order = _best_start(candidates, config, seed, validation_tracks,
                                                   say)
    outliers, failed = _without_outliers(state, camera_names, say)
    quality = RigQuality(global_init=init, gauge_camera=camera_names[gauge],
                   num_outlier_observations=int(outliers.sum()), stage_residuals=stats)
    return GlobalResult(state=state, view_order=order, failed=failed, gauge_camera=gauge,
                        quality=quality)


def _best_start(candidates: list, config: SfMConfig, seed: int,
                validation_tracks: Optional[Tracks], say: Callable[[str], None]) -> tuple:
    """The candidate (name, state, stage stats, gauge camera, view order) that fits best.

    Both starts are refined on the same observations; keep the better fit (no ground truth
    needed): most cameras posed with plausible intrinsics, then the lowest truncated
    reprojection cost, on the validation tracks where given (matches neither start was fitted
    to), else on the tracks."""
    trunc = cost_truncation_px(config, candidates[0][1].num_cameras)
    judge = validation_tracks is not None and validation_tracks.num_tracks > 0

    def cost(state: SfMState) -> float:
        return (held_out_cost(state, validation_tracks, trunc, seed) if judge
                else truncated_cost(state, trunc))
    costs = [(-(len(cand[1].registered()) - len(implausible_cameras(cand[1]))), cost(cand[1]))
             for cand in candidates]
    best = min(range(len(candidates)), key=lambda k: costs[k])
    if len(candidates) > 1:
        judged_on = (f"{validation_tracks.num_tracks} keypoint-match tracks" if judge
                     else "the sampled tracks")
        say(f"global starts (truncated reprojection cost on {judged_on}): " + ", ".join(
            f"{cand[0]} {c[1]:.3f} px" for cand, c in zip(candidates, costs))
            + f"; kept {candidates[best][0]}")
    return candidates[best]


def _without_outliers(state: SfMState, camera_names: Sequence[str],
                      say: Callable[[str], None]) -> tuple[np.ndarray, list[int]]:
    """(the observations taken out as outliers, the failed cameras), in place.

    Gross outliers took part in every stage under the robust loss; they are left out of the
    result (its statistics and COLMAP model) only now, so the estimate does not depend on it.
    A camera with (almost) no observations of reconstruction points has no trustworthy pose."""
    C = state.num_cameras
    err = reprojection_errors(state)
    outliers = np.nan_to_num(err, nan=0.0) > TRIANGULATION_MAX_ERROR_PX
    state.active[outliers] = False
    err[outliers] = np.nan
    failed = [c for c in range(C) if state.cam_from_world[c] is None
              or np.isfinite(err[:, c]).sum() < MIN_CAMERA_OBSERVATIONS]
    for c in failed:
        state.cam_from_world[c] = None
    drop_implausible_cameras(state, failed, camera_names, say)
    if C - len(failed) < 2:
        raise NotEnoughCamerasError(
            "Fewer than two cameras keep enough observations after global SfM: check that the "
            "cameras overlap and see textured scene content.")
    return outliers, failed


def _refine_from_start(init: str, tracks: Tracks, intrinsics: Sequence[CameraIntrinsics],
                       camera_names: Sequence[str], config: SfMConfig, seed: int,
                       progress: Progress, previous: Optional[RigCalibration],
                       validation_tracks: Optional[Tracks] = None,
                       extra_starts: Optional[dict] = None):
    """Initial poses from `init`, multi-view triangulation, gauge, staged BA.
    Returns (state, residual stats per stage, gauge camera, cameras by gauge score)."""
    say = Progress.of(progress).say
    C = tracks.num_cameras
    if init == "previous":
        start, poses = poses_from_previous(previous, camera_names,
                                           [(c.width, c.height) for c in intrinsics],
                                           working_models(config, C))
        for c in config.fixed_intrinsics_cameras:  # given intrinsics win over the previous ones
            start[c] = intrinsics[c]
        state = SfMState.create(tracks, start, config.share_intrinsics,
                                config.fixed_intrinsics_cameras,
                                config.shared_intrinsics_groups)
    elif init == "incremental":
        # The incremental pipeline needs its outlier threshold (B_err) to stay on track even
        # when the global preset has none.
        inc_config = config
        if config.b_err_px is None:
            inc_config = replace(config, b_err_px=B_ERR_PX[
                "fisheye" if "FISHEYE" in config.camera_model else "regular"])
            if config.mixed_rig_pinhole_cameras(C):
                inc_config = replace(inc_config, pinhole_b_err_px=B_ERR_PX["regular"])
        state = run_incremental(tracks, intrinsics, camera_names, inc_config, seed=seed,
                                progress=progress, validation_tracks=validation_tracks,
                                extra_starts=extra_starts).state
        poses = state.cam_from_world
        state.active = tracks.observed().copy()  # global: every observation, no B_err removal
    else:
        state = SfMState.create(tracks, intrinsics, config.share_intrinsics,
                                config.fixed_intrinsics_cameras,
                                config.shared_intrinsics_groups)
        poses = rotation_averaging_poses(tracks, [state.camera(c) for c in range(C)],
                                         camera_names, seed)
    # Only the incremental initialisation can leave cameras without a pose (not registrable).
    state.cam_from_world = [None if T is None else np.asarray(T, dtype=np.float64).copy()
                            for T in poses]
    num_points = triangulate_tracks(state, seed=seed)
    stats = {"triangulation": residual_stats(state)}
    say(f"global init {init}: {num_points} of {tracks.num_tracks} tracks triangulated, "
        f"{_describe(stats['triangulation'])}")
    scores = np.where([T is not None for T in state.cam_from_world], gauge_scores(tracks), -1.0)
    order = [int(c) for c in np.argsort(-scores, kind="stable")]
    gauge = order[0]
    to_gauge_frame(state, gauge)
    stats.update(staged_bundle_adjustment(state, camera_names, config, gauge, progress, seed))
    return state, stats, gauge, order


def working_models(config: SfMConfig, num_cameras: int) -> list[tuple[str, ...]]:
    """Per camera, the models the pipeline works in: its initial model, then the refinement
    model where it is of the same lens family (convert_camera_models)."""
    out = []
    for model in config.models(num_cameras):
        refine = config.refine_to_model
        same = refine and ("FISHEYE" in refine) == ("FISHEYE" in model)
        out.append((model,) + ((refine,) if same else ()))
    return out
