"""Two-view geometry between the cameras of a rig: fundamental matrices (MAGSAC++), the F_err
epipolar filter, pair weights, relative poses from essential matrices and triangulation angles.

Conventions: pixel coordinates are COLMAP pixels of the original image (top-left pixel centre at
(0.5, 0.5)) and every F is defined on homogeneous COLMAP pixels, `x_j^T F_ji x_i = 0`. Poses follow
`cam_j_from_cam_i`: a point X_i in camera i's frame is `R_ji @ X_i + t_ji` in camera j's frame.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Optional

import cv2
import numpy as np

from ..types import Tracks


@dataclass
class TwoViewGeometry:
    """Robust two-view estimate of the ordered pair (i, j).

    F_ji: (3, 3) fundamental matrix with x_j^T F_ji x_i = 0 on COLMAP pixels, or None when the
      estimate failed or was made on rays (fisheye): then E_ji/R_ji/t_ji carry the geometry.
    inlier_mask: bool (N,) over the correspondences the estimate was made from.
    E_ji, R_ji, t_ji: optional essential matrix on camera rays and relative pose cam_j_from_cam_i
      (t_ji unit length), filled when a pose was estimated.
    """

    F_ji: Optional[np.ndarray]
    inlier_mask: np.ndarray
    num_inliers: int
    E_ji: Optional[np.ndarray] = None
    R_ji: Optional[np.ndarray] = None
    t_ji: Optional[np.ndarray] = None


# Fewer correspondences than this give no usable MAGSAC++ estimate (7/8-point minimal solvers).
MIN_CORRESPONDENCES = 15
# MAGSAC++ scale of the fundamental matrices (px): COLMAP's default max error, where the paper's
# robustification starts.
F_THRESHOLD_PX = 1.0


def _as_points(xy: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(np.asarray(xy, dtype=np.float64).reshape(-1, 2))


def estimate_fundamental(xy_i_px: np.ndarray, xy_j_px: np.ndarray,
                         threshold_px: float = F_THRESHOLD_PX,
                         confidence: float = 0.9999, max_iters: int = 10000,
                         seed: int = 0) -> TwoViewGeometry:
    """F_ji from N correspondences (xy_i_px[n] in camera i <-> xy_j_px[n] in camera j), (N, 2)
    COLMAP pixels each, with OpenCV's MAGSAC++ (cv2.USAC_MAGSAC). Deterministic for a fixed seed
    (OpenCV's RNG is seeded). Returns F_ji=None and an all-False mask when N < 15 or the estimate
    fails. F is defined on COLMAP pixels: OpenCV's pixel origin does not matter because the same
    coordinates go in and the constraint is evaluated on them."""
    xy_i, xy_j = _as_points(xy_i_px), _as_points(xy_j_px)
    n = xy_i.shape[0]
    if xy_j.shape[0] != n:
        raise ValueError(f"estimate_fundamental: {n} points in image i but {xy_j.shape[0]} in j")
    empty = TwoViewGeometry(None, np.zeros(n, dtype=bool), 0)
    if n < MIN_CORRESPONDENCES:
        return empty
    cv2.setRNGSeed(int(seed))
    F, mask = cv2.findFundamentalMat(xy_i, xy_j, cv2.USAC_MAGSAC, float(threshold_px),
                                     float(confidence), int(max_iters))
    if F is None or F.shape != (3, 3) or mask is None:
        return empty
    inliers = mask.reshape(-1).astype(bool)
    # OpenCV's F is rank 2 only to ~1e-6; enforce it so E = K^T F K is exactly rank 2.
    u, s, vt = np.linalg.svd(F)
    F = u @ np.diag([s[0], s[1], 0.0]) @ vt
    F = F / np.linalg.norm(F)
    return TwoViewGeometry(F, inliers, int(inliers.sum()))


def estimate_essential_from_rays(rays_i: np.ndarray, rays_j: np.ndarray, threshold_rad: float,
                                 confidence: float = 0.9999, max_iters: int = 10000,
                                 seed: int = 0, min_z: float = 0.34) -> TwoViewGeometry:
    """E_ji and the pose cam_j_from_cam_i from (N, 3) camera rays (fisheye or known intrinsics),
    MAGSAC++ on the normalised plane (x/z, y/z) with `threshold_rad` (~ threshold_px / focal_px).

    Only rays with z > min_z (default cos 70 deg) in both cameras take part: near 90 deg the
    normalised plane stretches errors without bound. Returns F_ji=None; inlier_mask (N,) is False
    for rays left out."""
    rays_i = np.asarray(rays_i, np.float64).reshape(-1, 3)
    rays_j = np.asarray(rays_j, np.float64).reshape(-1, 3)
    n = rays_i.shape[0]
    mask = np.zeros(n, dtype=bool)
    with np.errstate(invalid="ignore"):
        use = np.flatnonzero((rays_i[:, 2] > min_z * np.linalg.norm(rays_i, axis=1))
                             & (rays_j[:, 2] > min_z * np.linalg.norm(rays_j, axis=1)))
    if use.size < MIN_CORRESPONDENCES:
        return TwoViewGeometry(None, mask, 0)
    n_i = np.ascontiguousarray(rays_i[use, :2] / rays_i[use, 2:3])
    n_j = np.ascontiguousarray(rays_j[use, :2] / rays_j[use, 2:3])
    cv2.setRNGSeed(int(seed))
    E, inl = cv2.findEssentialMat(n_i, n_j, np.eye(3), cv2.USAC_MAGSAC, float(confidence),
                                  float(threshold_rad), int(max_iters))
    if E is None or E.shape != (3, 3) or inl is None:
        return TwoViewGeometry(None, mask, 0)
    inl = inl.reshape(-1).astype(bool)
    R, t, front = relative_pose_from_rays(E, rays_i[use][inl], rays_j[use][inl])
    mask[use[inl]] = True
    return TwoViewGeometry(None, mask, int(mask.sum()), E_ji=E / np.linalg.norm(E), R_ji=R,
                           t_ji=t)


def symmetric_epipolar_distance_px(F_ji: np.ndarray, xy_i_px: np.ndarray,
                                   xy_j_px: np.ndarray) -> np.ndarray:
    """(N,) max over both images of the point-to-epipolar-line distance in pixels: the distance of
    x_j to the line F_ji x_i and of x_i to the line F_ji^T x_j (the paper's F_err measure)."""
    xy_i, xy_j = _as_points(xy_i_px), _as_points(xy_j_px)
    hi = np.concatenate([xy_i, np.ones((len(xy_i), 1))], axis=1)
    hj = np.concatenate([xy_j, np.ones((len(xy_j), 1))], axis=1)
    line_j = hi @ F_ji.T  # lines in image j: F x_i
    line_i = hj @ F_ji  # lines in image i: F^T x_j
    alg = np.einsum("nk,nk->n", hj, line_j)
    d_j = np.abs(alg) / np.maximum(np.hypot(line_j[:, 0], line_j[:, 1]), 1e-300)
    d_i = np.abs(alg) / np.maximum(np.hypot(line_i[:, 0], line_i[:, 1]), 1e-300)
    return np.maximum(d_i, d_j)


def pair_weights(num_matches: dict) -> dict:
    """Paper's w_ij = n_ij / max n over all pairs ({(i, j): count} -> {(i, j): weight in [0,
    1]})."""
    if not num_matches:
        return {}
    top = max(num_matches.values())
    if top <= 0:
        return {k: 0.0 for k in num_matches}
    return {k: float(v) / float(top) for k, v in num_matches.items()}


def essential_from_fundamental(F_ji: np.ndarray, K_i: np.ndarray, K_j: np.ndarray) -> np.ndarray:
    """E_ji = K_j^T F_ji K_i (3, 3), the constraint on normalised rays: r_j^T E_ji r_i = 0."""
    return K_j.T @ F_ji @ K_i


def relative_pose_from_essential(F_ji: np.ndarray, K_i: np.ndarray, K_j: np.ndarray,
                                 xy_i_px: np.ndarray, xy_j_px: np.ndarray):
    """Relative pose cam_j_from_cam_i from F_ji and pinhole calibrations K_i, K_j (3x3, COLMAP px).

    E = K_j^T F K_i is decomposed and the cheirality of the (N, 2) correspondences picks among the
    four solutions (cv2.recoverPose on normalised coordinates). Returns (R_ji (3, 3), t_ji (3,)
    unit, mask (N,) bool of the points in front of both cameras)."""
    xy_i, xy_j = _as_points(xy_i_px), _as_points(xy_j_px)
    E = essential_from_fundamental(F_ji, K_i, K_j)
    return relative_pose_from_rays(E, pixels_to_rays(xy_i, K_i), pixels_to_rays(xy_j, K_j))


def pixels_to_rays(xy_px: np.ndarray, K: np.ndarray) -> np.ndarray:
    """(N, 3) pinhole rays K^-1 [x, y, 1] (z = 1) of (N, 2) COLMAP pixels."""
    xy = _as_points(xy_px)
    h = np.concatenate([xy, np.ones((len(xy), 1))], axis=1)
    return h @ np.linalg.inv(K).T


def relative_pose_from_rays(E_ji: np.ndarray, rays_i: np.ndarray, rays_j: np.ndarray):
    """Decompose E_ji (r_j^T E r_i = 0) with a cheirality check on (N, 3) rays with z > 0.
    Returns (R_ji, t_ji unit (3,), mask (N,) bool of points in front of both cameras)."""
    rays_i, rays_j = np.asarray(rays_i, np.float64), np.asarray(rays_j, np.float64)
    n_i = np.ascontiguousarray(rays_i[:, :2] / rays_i[:, 2:3])
    n_j = np.ascontiguousarray(rays_j[:, :2] / rays_j[:, 2:3])
    # Large threshold: the cheirality test should count every point, the mask from recoverPose
    # then means "in front of both cameras" rather than "inlier of E".
    _, R, t, mask, _ = cv2.recoverPose(np.ascontiguousarray(E_ji, dtype=np.float64), n_i, n_j,
                                    np.eye(3), distanceThresh=1e6)
    t = t.reshape(3)
    return R, t / max(np.linalg.norm(t), 1e-300), mask.reshape(-1) > 0


def triangulation_angles_deg(R_ji: np.ndarray, t_ji: np.ndarray, rays_i: np.ndarray,
                             rays_j: np.ndarray) -> np.ndarray:
    """(N,) angle in degrees between the two viewing rays of each correspondence, for the relative
    pose cam_j_from_cam_i (R_ji, t_ji) and (N, 3) rays in camera i's and camera j's frames.

    The point is triangulated with the midpoint method; a point behind either camera (or rays
    that are parallel, i.e. at infinity) gets NaN, which the score function maps to 0."""
    d_i = np.asarray(rays_i, np.float64)
    d_i = d_i / np.linalg.norm(d_i, axis=1, keepdims=True)
    d_j = np.asarray(rays_j, np.float64) @ np.asarray(R_ji)  # R^T r_j (rays of j in frame i)
    d_j = d_j / np.linalg.norm(d_j, axis=1, keepdims=True)
    c_j = -np.asarray(R_ji).T @ np.asarray(t_ji, np.float64).reshape(3)  # centre of j in frame i
    # Minimise |l_i d_i - (c_j + l_j d_j)|^2 over (l_i, l_j): 2x2 normal equations per point.
    b = np.einsum("nk,nk->n", d_i, d_j)
    p = d_i @ c_j
    q = d_j @ c_j
    den = 1.0 - b * b
    with np.errstate(divide="ignore", invalid="ignore"):
        l_i = (p - b * q) / den
        l_j = (b * p - q) / den
    cos_angle = np.clip(b, -1.0, 1.0)
    angle = np.degrees(np.arccos(cos_angle))
    valid = (den > 1e-12) & (l_i > 0) & (l_j > 0)
    return np.where(valid, angle, np.nan)


def fundamental_matrices(tracks: Tracks, seed: int = 0) -> dict:
    """{(i, j): TwoViewGeometry} for every camera pair i < j sharing >= 15 tracks (F_ji with
    x_j^T F_ji x_i = 0 on COLMAP px)."""
    obs = tracks.observed()
    out = {}
    for i in range(tracks.num_cameras):
        for j in range(i + 1, tracks.num_cameras):
            rows = np.flatnonzero(obs[:, i] & obs[:, j])
            if len(rows) >= MIN_CORRESPONDENCES:
                geom = estimate_fundamental(tracks.xy_px[rows, i], tracks.xy_px[rows, j],
                                            F_THRESHOLD_PX, seed=seed)
                if geom.F_ji is not None:
                    out[(i, j)] = geom
    return out


def epipolar_filter(tracks: Tracks, two_view: dict,
                    f_err_px: Callable[[int, int], Optional[float]]) -> Tracks:
    """Drop tracks with any observation pair (i, j) farther than f_err_px(i, j) from its epipolar
    line (symmetric point-to-line distance, the paper's F_err; None: that pair is not tested).
    Tracks are cycle-consistent, so a pair that fails the test makes the whole track suspect."""
    obs = tracks.observed()
    bad = np.zeros(tracks.num_tracks, dtype=bool)
    for (i, j), geom in two_view.items():
        threshold = f_err_px(i, j)
        if geom.F_ji is None or threshold is None:
            continue
        rows = np.flatnonzero(obs[:, i] & obs[:, j])
        d = symmetric_epipolar_distance_px(geom.F_ji, tracks.xy_px[rows, i], tracks.xy_px[rows, j])
        bad[rows[d > threshold]] = True
    return tracks.subset(~bad) if bad.any() else tracks
