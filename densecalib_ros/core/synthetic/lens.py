"""Exact unprojection of COLMAP's RADIAL, OPENCV (radial terms only: p1 = p2 = 0) and
OPENCV_FISHEYE models, including fisheye rays beyond 90 degrees.

pycolmap 4.2.1's `Camera.cam_ray_from_img` is wrong for OPENCV_FISHEYE beyond 90 degrees (it
returns a ray of a smaller angle, e.g. ~60 deg for a pixel at theta_d = 1.7 rad), and
`img_from_cam` returns NaN for points with z <= 0. Both models are radially symmetric in normalised
coordinates, so the inverse is a 1D Newton solve of the radial distortion function g:
  RADIAL, OPENCV:  r_d = g(r) = r (1 + k1 r^2 + k2 r^4),            r = tan(theta)
  OPENCV_FISHEYE:  theta_d = g(theta) = theta (1 + k1 th^2 + ... + k4 th^8)
The forward direction equals pycolmap's `img_from_cam` for points in front (test_synthetic checks it).
"""
from __future__ import annotations

import numpy as np

from ..types import CameraIntrinsics

SUPPORTED_MODELS = ("RADIAL", "OPENCV", "OPENCV_FISHEYE")
PERSPECTIVE_MODELS = ("RADIAL", "OPENCV")


def is_perspective(cam: CameraIntrinsics) -> bool:
    """Whether cam's radial variable is r = tan(theta) (else theta: a fisheye)."""
    return cam.model in PERSPECTIVE_MODELS


def _split(cam: CameraIntrinsics):
    p = np.asarray(cam.params, np.float64)
    if cam.model == "RADIAL":
        return p[0], p[0], p[1], p[2], np.array([p[3], p[4]])
    if cam.model == "OPENCV":
        if p[6] != 0.0 or p[7] != 0.0:
            raise ValueError("OPENCV cameras here are radial only (p1 = p2 = 0).")
        return p[0], p[1], p[2], p[3], np.array([p[4], p[5]])
    return p[0], p[1], p[2], p[3], p[4:8].copy()


def radial_g(cam: CameraIntrinsics, a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """g(a) and g'(a) of the model's radial distortion (a = r for RADIAL, theta for fisheye)."""
    k = _split(cam)[4]
    a2 = a * a
    poly = np.zeros_like(a)
    dpoly = np.zeros_like(a)
    for i in range(len(k) - 1, -1, -1):  # Horner in a^2: sum k_i a^(2i+2)
        poly = (poly + k[i]) * a2
        dpoly = dpoly * a2 + (2 * i + 3) * k[i]
    dpoly = dpoly * a2
    return a * (1 + poly), 1 + dpoly


def monotonic_limit(cam: CameraIntrinsics, a_max: float) -> float:
    """Largest a <= a_max up to which g stays strictly increasing (g' > 0.2): beyond it the model
    folds back and pixels no longer map to a unique ray."""
    a = np.linspace(0.0, a_max, 4001)
    bad = np.nonzero(radial_g(cam, a)[1] <= 0.2)[0]
    return float(a_max if bad.size == 0 else a[max(bad[0] - 1, 0)])


def cam_rays(cam: CameraIntrinsics, xy_px: np.ndarray, a_limit: float,
             dtype=np.float64) -> tuple[np.ndarray, np.ndarray]:
    """COLMAP pixels (n, 2) -> unit rays (n, 3) in the camera frame and valid (n,) bool.

    valid is False where the pixel lies beyond a_limit (r or theta; the lens circle of a fisheye
    or the fold-back of a strong distortion); those rays are NaN.
    """
    fx, fy, cx, cy, _ = _split(cam)
    xy = np.asarray(xy_px, np.float64)
    xd = (xy[:, 0] - cx) / fx
    yd = (xy[:, 1] - cy) / fy
    rd = np.hypot(xd, yd)
    g_lim = radial_g(cam, np.array([a_limit]))[0][0]
    valid = rd <= g_lim
    # Start from a table inverse of g (monotonic on [0, a_limit]), polish with Newton.
    a_tab = np.linspace(0.0, a_limit, 2049)
    a = np.interp(rd, radial_g(cam, a_tab)[0], a_tab)
    for _ in range(20):
        g, dg = radial_g(cam, a)
        step = (g - rd) / dg
        a = np.clip(a - step, 0.0, a_limit)
        if np.max(np.abs(step), initial=0.0) < 1e-13:
            break
    with np.errstate(divide="ignore", invalid="ignore"):
        scale = np.where(rd > 0, 1.0 / rd, 0.0)
    if is_perspective(cam):
        # a = r = tan(theta): ray ~ (x_u, y_u, 1)
        rays = np.stack([xd * scale * a, yd * scale * a, np.ones_like(a)], axis=1)
        rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    else:
        s = np.sin(a)
        rays = np.stack([xd * scale * s, yd * scale * s, np.cos(a)], axis=1)
    rays[~valid] = np.nan
    return rays.astype(dtype, copy=False), valid


def img_from_cam_any(cam: CameraIntrinsics, points_cam: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Projection of camera-frame points (n, 3) for any viewing angle: theta = atan2(r, z), so
    fisheye points behind the image plane (theta > 90 deg) project too. Returns xy_px (n, 2) and
    theta (n,) in radians. For perspective models, points with z <= 0 get NaN."""
    fx, fy, cx, cy, _ = _split(cam)
    p = np.asarray(points_cam, np.float64)
    rxy = np.hypot(p[:, 0], p[:, 1])
    theta = np.arctan2(rxy, p[:, 2])
    if is_perspective(cam):
        with np.errstate(divide="ignore", invalid="ignore"):
            a = np.where(p[:, 2] > 0, rxy / p[:, 2], np.nan)
    else:
        a = theta
    g = radial_g(cam, a)[0]
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(rxy > 0, g / rxy, 0.0)
    xy = np.stack([fx * p[:, 0] * s + cx, fy * p[:, 1] * s + cy], axis=1)
    return xy, theta
