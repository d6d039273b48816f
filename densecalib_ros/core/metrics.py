"""Evaluation metrics: relative pose AUC (paper Sec. 4 / VGGT / PoseDiffusion), focal error and the
pixel distance between true and estimated projection maps. All angles are in degrees.

Pose metrics compare, for every unordered pair (i, j) of ground-truth cameras, the relative pose
cam_j_from_cam_i = cam_j_from_world @ inv(cam_i_from_world). It does not depend on the world (or rig)
frame nor on the reconstruction's scale, so cam_from_world and cam_from_rig inputs both work.

Differences from VGGT's `calculate_auc_np` worth knowing when comparing numbers:
- The translation-direction error is the plain angle between the two directions (a flipped direction
  is 180 deg). VGGT/PoseDiffusion fold it to min(e, 180 - e); pass `fold_translation_sign=True` to
  `relative_pose_errors` to reproduce that.
- A threshold counts errors strictly below it (VGGT's histogram also counts an error of exactly T
  at the last threshold T).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping

import numpy as np

from .types import CameraIntrinsics, RigCalibration

# A relative translation shorter than this (in reconstruction units) has no direction.
_MIN_TRANSLATION_NORM = 1e-12


@dataclass
class PairError:
    """Errors of one unordered camera pair (i, j), i before j in the ground truth's order."""

    i: str
    j: str
    rot_err_deg: float
    trans_dir_err_deg: float

    @property
    def max_err_deg(self) -> float:
        return max(self.rot_err_deg, self.trans_dir_err_deg)


def rotation_angle_deg(rotation: np.ndarray) -> float:
    """Angle of a 3x3 rotation matrix in degrees, in [0, 180]."""
    cos = (np.trace(rotation) - 1.0) / 2.0
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))


def _angle_between_deg(a: np.ndarray, b: np.ndarray) -> float:
    cos = float(np.dot(a, b) / (np.linalg.norm(a) * np.linalg.norm(b)))
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))


def _relative(cam_from_world: Mapping[str, np.ndarray], i: str, j: str) -> np.ndarray:
    """4x4 cam_j_from_cam_i."""
    return np.asarray(cam_from_world[j], float) @ np.linalg.inv(np.asarray(cam_from_world[i], float))


def relative_pose_errors(est_cam_from_world: Mapping[str, np.ndarray],
                         gt_cam_from_world: Mapping[str, np.ndarray],
                         fold_translation_sign: bool = False) -> list[PairError]:
    """Rotation and translation-direction errors of every unordered pair of ground-truth cameras.

    est_cam_from_world / gt_cam_from_world: camera name -> 4x4 cam_from_world (or cam_from_rig; any
    common frame per dict). Pairs are (gt_names[a], gt_names[b]) for a < b in the ground truth's
    order. A pair with a camera missing from `est` gets inf errors (it counts as a failure).
    Rotation error: angle of R_est^T R_gt of the relative rotations. Translation-direction error:
    angle between the unit relative translations. Where the true relative translation has no
    direction (coincident centres) only the rotation is scored (translation error 0); where only
    the estimate has none, the translation error is 180.
    """
    names = list(gt_cam_from_world)
    out: list[PairError] = []
    for a in range(len(names)):
        for b in range(a + 1, len(names)):
            i, j = names[a], names[b]
            if i not in est_cam_from_world or j not in est_cam_from_world:
                out.append(PairError(i, j, float("inf"), float("inf")))
                continue
            rel_gt = _relative(gt_cam_from_world, i, j)
            rel_est = _relative(est_cam_from_world, i, j)
            rot = rotation_angle_deg(rel_est[:3, :3].T @ rel_gt[:3, :3])
            t_gt, t_est = rel_gt[:3, 3], rel_est[:3, 3]
            if np.linalg.norm(t_gt) < _MIN_TRANSLATION_NORM:
                trans = 0.0
            elif np.linalg.norm(t_est) < _MIN_TRANSLATION_NORM:
                trans = 180.0
            else:
                trans = _angle_between_deg(t_est, t_gt)
                if fold_translation_sign:
                    trans = min(trans, 180.0 - trans)
            out.append(PairError(i, j, rot, trans))
    return out


def auc(pair_errors: list[PairError], threshold_deg: int) -> float:
    """AUC@T in percent: the mean over thresholds t = 1, 2, ..., T deg of the fraction of pairs whose
    max(rotation error, translation-direction error) < t. 0 when there are no pairs."""
    if not pair_errors:
        return 0.0
    err = np.array([p.max_err_deg for p in pair_errors], dtype=np.float64)
    err = np.where(np.isnan(err), np.inf, err)
    thresholds = np.arange(1, int(threshold_deg) + 1, dtype=np.float64)
    return float(100.0 * np.mean(err[None, :] < thresholds[:, None]))


def mean_focal_px(camera: CameraIntrinsics) -> float:
    """Mean of the model's focal parameters (fx, fy or f) in pixels."""
    return float(camera.to_pycolmap().mean_focal_length())


def focal_errors(est: Mapping[str, CameraIntrinsics],
                 gt: Mapping[str, CameraIntrinsics]) -> dict[str, float]:
    """Relative focal error |f_est - f_gt| / f_gt (a fraction) per camera present in both, where f is
    the mean of the model's focal parameters."""
    out = {}
    for name, cam_gt in gt.items():
        if name in est:
            f_gt = mean_focal_px(cam_gt)
            out[name] = abs(mean_focal_px(est[name]) - f_gt) / f_gt
    return out


def principal_point_px(camera: CameraIntrinsics) -> np.ndarray:
    """(cx, cy) of a COLMAP camera, pixels."""
    cam = camera.to_pycolmap()
    return np.asarray(cam.params, float)[list(cam.principal_point_idxs())]


def principal_point_error_px(true: CameraIntrinsics, est: CameraIntrinsics) -> float:
    """Distance between the estimated and the true principal point, pixels."""
    return float(np.linalg.norm(principal_point_px(est) - principal_point_px(true)))


def invertible_pixel_rays(camera, xy_px: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(rays (N, 3), valid (N,)): camera's (pycolmap) rays of the pixels xy_px and which of them
    it maps back to their own pixel within 0.01 px: pycolmap's fisheye models do not invert
    beyond 90 deg off-axis."""
    rays = camera.cam_ray_from_img(xy_px)
    back = camera.img_from_cam(rays)
    return rays, np.isfinite(back).all(1) & (np.linalg.norm(back - xy_px, axis=1) < 0.01)


def projection_map_error(true: CameraIntrinsics, est: CameraIntrinsics,
                         grid_step_px: float = 16.0) -> dict:
    """Distance between the true and the estimated projection maps, in pixels.

    Pixels on a grid (step `grid_step_px`, COLMAP pixel coordinates) of the true image are unprojected
    to rays by the true camera and projected by the estimated camera; the error of a pixel is the
    distance between where it started and where it lands. Models may differ (e.g. RADIAL_FISHEYE vs
    OPENCV_FISHEYE). Only rays the true camera maps back to their own pixel (within 0.01 px) are
    used: pycolmap's fisheye models do not invert beyond 90 deg off-axis, so a 190-deg fisheye is
    compared on its central field. Rays the estimated camera cannot project (behind it, NaN) count
    as `num_unprojectable` and are excluded from the statistics.

    Returns dict(mean_px, median_px, max_px, num_points, num_unprojectable, fraction_used), with
    NaN statistics when no grid pixel could be compared.
    """
    if (true.width, true.height) != (est.width, est.height):
        raise ValueError(f"Image sizes differ: true {true.width}x{true.height}, "
                         f"estimated {est.width}x{est.height}; compare cameras of the same image.")
    cam_true, cam_est = true.to_pycolmap(), est.to_pycolmap()
    xs = np.arange(0.5, true.width, grid_step_px)
    ys = np.arange(0.5, true.height, grid_step_px)
    xy_px = np.stack(np.meshgrid(xs, ys), -1).reshape(-1, 2).astype(np.float64)
    rays_in_cam, valid = invertible_pixel_rays(cam_true, xy_px)
    xy_est = cam_est.img_from_cam(rays_in_cam[valid])
    projectable = np.isfinite(xy_est).all(1)
    err = np.linalg.norm(xy_est[projectable] - xy_px[valid][projectable], axis=1)
    stats = dict(num_points=int(err.size), num_unprojectable=int((~projectable).sum()),
                 fraction_used=float(valid.mean()))
    if err.size == 0:
        return dict(mean_px=float("nan"), median_px=float("nan"), max_px=float("nan"), **stats)
    return dict(mean_px=float(err.mean()), median_px=float(np.median(err)),
                max_px=float(err.max()), **stats)


def evaluate_calibration(est: RigCalibration, gt: RigCalibration,
                         grid_step_px: float = 16.0) -> dict:
    """Compare an estimated rig calibration with the ground truth; cameras are matched by name.

    Returns a JSON-ready dict: num_cameras, num_registered (est cameras that are in gt), auc3, auc30
    (percent; unregistered cameras' pairs count as failures), median_rot_err_deg (median over
    pairs of the relative rotation error; an unregistered camera's pairs count as inf),
    median_pp_err_px (median over registered cameras of the principal point's distance from the
    reference's), median_focal_err (fraction) and
    median_proj_err_px (median over registered cameras of each camera's mean projection-map error),
    and `cameras`: per camera focal_err, projection-map stats, registered flag; `pairs`: per pair
    errors. Medians are NaN when nothing was registered.
    """
    est_poses = {n: c.cam_from_rig for n, c in est.cameras.items() if n in gt.cameras}
    gt_poses = {n: c.cam_from_rig for n, c in gt.cameras.items()}
    pairs = relative_pose_errors(est_poses, gt_poses)
    focal = focal_errors({n: c.intrinsics for n, c in est.cameras.items()},
                         {n: c.intrinsics for n, c in gt.cameras.items()})
    cameras = {}
    for name, cam_gt in gt.cameras.items():
        rec = dict(registered=name in est_poses)
        if name in est_poses:
            rec["focal_err"] = focal[name]
            rec["pp_err_px"] = principal_point_error_px(cam_gt.intrinsics,
                                                        est.cameras[name].intrinsics)
            rec["model"] = est.cameras[name].intrinsics.model
            rec["projection"] = projection_map_error(cam_gt.intrinsics,
                                                     est.cameras[name].intrinsics, grid_step_px)
        cameras[name] = rec
    proj = [c["projection"]["mean_px"] for c in cameras.values()
            if c["registered"] and np.isfinite(c["projection"]["mean_px"])]
    pp = [c["pp_err_px"] for c in cameras.values() if c["registered"]]
    return dict(
        num_cameras=len(gt.cameras),
        num_registered=len(est_poses),
        auc3=auc(pairs, 3),
        auc30=auc(pairs, 30),
        median_rot_err_deg=float(np.median([p.rot_err_deg for p in pairs])) if pairs
        else float("nan"),
        median_pp_err_px=float(np.median(pp)) if pp else float("nan"),
        median_focal_err=float(np.median(list(focal.values()))) if focal else float("nan"),
        median_proj_err_px=float(np.median(proj)) if proj else float("nan"),
        cameras=cameras,
        pairs=[dict(i=p.i, j=p.j, rot_err_deg=p.rot_err_deg, trans_dir_err_deg=p.trans_dir_err_deg)
               for p in pairs],
    )
