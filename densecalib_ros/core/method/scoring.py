"""Triangulation-angle score (paper Sec. 3.2, eq. 1) and per-cycle scores.

f(theta; alpha, sigma, p) = p * B(theta) G(theta) / max_{[0, pi]} (B G), with
G(theta) = exp(-((theta - alpha) / sigma)^2 / 2) and B(theta) = exp(-eps / (theta/pi (1 -
theta/pi))).

Why eps: the paper states the properties it wants — maximum at alpha = 30 deg, roughly covering
10-50 deg (the Ames Stereo Pipeline's 10-60 deg guideline), vanishing at 0 and pi — but eq. 1 as
printed (eps = 1) cannot have them: B is so steep near 0 that it moves the peak to 52.1 deg and
scores 20 deg at 0.008 p. We keep B's form, which enforces the vanishing ends, and soften it
(eps = 0.03 by default, `SamplingConfig.score_boundary_eps`): for alpha = 30, sigma = 20 the peak
is then at 32 deg, f(1) = 0.002 p, f(10) = 0.42 p, f(50) = 0.64 p, f(90) = 0.01 p (measured).
eps = 1 reproduces the printed formula
for ablations. A cycle's score is the sum of its top_k pair scores.

Pair angles come from relative poses: either estimated (F -> E with the initial focals -> R, t;
see sampling.py) or given (refinement: cam_from_rig + intrinsics, `pair_poses_from_rig`).
"""
from __future__ import annotations

from functools import lru_cache
from typing import Optional

import numpy as np

from ..types import CameraIntrinsics

DEFAULT_BOUNDARY_EPS = 0.03  # see the module doc: 1.0 = eq. 1 exactly as printed


def _boundary_gauss(theta_rad: np.ndarray, alpha_rad: float, sigma_rad: float,
                    eps: float) -> np.ndarray:
    u = np.asarray(theta_rad, np.float64) / np.pi
    with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
        b = np.where((u > 0) & (u < 1), np.exp(-eps / (u * (1.0 - u))), 0.0)
    g = np.exp(-0.5 * ((theta_rad - alpha_rad) / sigma_rad) ** 2)
    return b * g


@lru_cache(maxsize=32)
def _peak(alpha_rad: float, sigma_rad: float, eps: float) -> float:
    # Dense search then a local refinement: the normaliser of eq. 1 to 1e-10 relative.
    grid = np.linspace(0.0, np.pi, 20001)
    k = int(np.argmax(_boundary_gauss(grid, alpha_rad, sigma_rad, eps)))
    fine = np.linspace(grid[max(k - 1, 0)], grid[min(k + 1, len(grid) - 1)], 20001)
    return float(_boundary_gauss(fine, alpha_rad, sigma_rad, eps).max())


def angle_score(theta_deg: np.ndarray, alpha_deg: float = 30.0, sigma_deg: float = 20.0,
                p: float = 1.0, boundary_eps: float = DEFAULT_BOUNDARY_EPS) -> np.ndarray:
    """Eq. 1 (with the boundary sharpness eps, see the module doc) on angles in degrees (any
    shape); NaN (no valid triangulation) and angles outside [0, 180] score 0."""
    theta = np.radians(np.asarray(theta_deg, np.float64))
    a, s = np.radians(alpha_deg), np.radians(sigma_deg)
    val = _boundary_gauss(np.nan_to_num(theta, nan=0.0), a, s, boundary_eps)
    return np.where(np.isfinite(theta), p * val / _peak(a, s, boundary_eps), 0.0)


def top_k_sum(pair_scores: np.ndarray, top_k: int) -> np.ndarray:
    """(M, P) pair scores of M cycles -> (M,) sum of each cycle's top_k scores (all if P < k);
    top_k = 0 gives zeros (no scoring)."""
    pair_scores = np.asarray(pair_scores, np.float64)
    if top_k <= 0 or pair_scores.shape[1] == 0:
        return np.zeros(pair_scores.shape[0])
    k = min(top_k, pair_scores.shape[1])
    return -np.sort(-pair_scores, axis=1)[:, :k].sum(axis=1)


def pair_poses_from_rig(cam_from_rig: list[np.ndarray]) -> dict:
    """Given poses (4x4 cam_from_rig per camera) -> {(i, j): (R_ji, t_ji)} for i < j, the relative
    pose cam_j_from_cam_i (t_ji in rig units, not normalised)."""
    out = {}
    for i in range(len(cam_from_rig)):
        for j in range(i + 1, len(cam_from_rig)):
            T = np.asarray(cam_from_rig[j]) @ np.linalg.inv(np.asarray(cam_from_rig[i]))
            out[(i, j)] = (T[:3, :3], T[:3, 3])
    return out


def rays_from_intrinsics(intrinsics: CameraIntrinsics, xy_px: np.ndarray) -> np.ndarray:
    """(N, 2) COLMAP pixels -> (N, 3) unit rays in the camera frame through the camera's COLMAP
    model (distortion included); NaN rows where the model cannot unproject."""
    cam = intrinsics.to_pycolmap()
    xy = np.asarray(xy_px, np.float64).reshape(-1, 2)
    rays = np.asarray(cam.cam_ray_from_img(xy), np.float64).reshape(-1, 3)
    norm = np.linalg.norm(rays, axis=1, keepdims=True)
    with np.errstate(invalid="ignore", divide="ignore"):
        return rays / norm


def equidistant_rays(xy_px: np.ndarray, image_size: tuple, focal_px: float,
                     principal_point_px: Optional[tuple] = None) -> np.ndarray:
    """(N, 2) COLMAP pixels -> (N, 3) unit rays of an ideal equidistant fisheye (r = f * theta,
    principal point at the image centre unless given)."""
    w, h = image_size
    cx, cy = principal_point_px if principal_point_px is not None else (w / 2.0, h / 2.0)
    xy = np.asarray(xy_px, np.float64).reshape(-1, 2)
    dx, dy = xy[:, 0] - cx, xy[:, 1] - cy
    r = np.hypot(dx, dy)
    theta = r / focal_px
    with np.errstate(invalid="ignore", divide="ignore"):
        scale = np.where(r > 0, np.sin(theta) / r, 1.0 / focal_px)
    return np.stack([dx * scale, dy * scale, np.cos(theta)], axis=1)
