"""Undistorted images: each camera's images resampled to an ideal pinhole camera (no distortion)
with the same optical centre and axes, so straight lines are straight and pixel positions can be
measured with K alone (forensic measurement, tools that assume pinhole cameras).

The pinhole keeps the image size, puts the principal point at the image centre and keeps the
camera's focal length, unless that would show more than max_fov_deg across the width (fisheye
lenses): then the focal grows until the width spans max_fov_deg. Output pixels whose ray the
original camera does not image (outside a fisheye's circle, beyond the modelled field) are black.
The rig's extrinsics are unchanged: undistorting rotates nothing.

A stereo pair can instead be resampled to its rectified cameras (core.products.stereo): pinholes
from the pair's projection matrices P1, P2, turned by R1, R2 so that corresponding points share a
row, as cv2.initUndistortRectifyMap does with the same R and P.
"""
from __future__ import annotations

from typing import Optional

import numpy as np

from ..types import CameraIntrinsics

DEFAULT_MAX_FOV_DEG = 120.0
RAY_AGREEMENT_RAD = 1e-4  # a source pixel images the target ray when its own ray is this close


def pinhole_for(intrinsics: CameraIntrinsics,
                max_fov_deg: float = DEFAULT_MAX_FOV_DEG) -> CameraIntrinsics:
    """The PINHOLE camera (COLMAP model; fx = fy, centred) that images are undistorted to."""
    if not 0.0 < max_fov_deg < 180.0:
        raise ValueError(f"max_fov_deg must be in (0, 180), got {max_fov_deg}")
    cam = intrinsics.to_pycolmap()
    focal = float(np.mean([cam.focal_length_x, cam.focal_length_y]))
    w, h = int(intrinsics.width), int(intrinsics.height)
    focal = max(focal, (w / 2.0) / np.tan(np.deg2rad(max_fov_deg) / 2.0))
    return CameraIntrinsics("PINHOLE", w, h, np.array([focal, focal, w / 2.0, h / 2.0]))


def rectified_pinhole(projection: np.ndarray, width: int, height: int) -> CameraIntrinsics:
    """The PINHOLE camera (COLMAP pixel convention) of a rectified camera's 3x4 projection
    matrix P (OpenCV/ROS convention, as core.products.stereo gives it)."""
    p = np.asarray(projection, dtype=np.float64)
    return CameraIntrinsics("PINHOLE", int(width), int(height),
                            np.array([p[0, 0], p[1, 1], p[0, 2] + 0.5, p[1, 2] + 0.5]))


def undistortion_maps(source: CameraIntrinsics, target: CameraIntrinsics,
                      target_from_source: Optional[np.ndarray] = None
                      ) -> tuple[np.ndarray, np.ndarray]:
    """cv2.remap maps (float32, target's H x W, OpenCV pixel convention): for each target pixel,
    where the same ray falls in the source image; -1 where the source does not image it.
    target_from_source: the 3x3 rotation of the target camera's frame from the source's (a
    stereo rectification R1 or R2); default none."""
    src, dst = source.to_pycolmap(), target.to_pycolmap()
    xs = np.arange(target.width) + 0.5
    ys = np.arange(target.height) + 0.5
    xy = np.stack(np.meshgrid(xs, ys), -1).reshape(-1, 2)
    rays = dst.cam_ray_from_img(xy)
    if target_from_source is not None:  # row vectors: ray_src = R^T ray_tgt
        rays = rays @ np.asarray(target_from_source, dtype=np.float64)
    src_xy = np.asarray(src.img_from_cam(rays), float)
    ok = np.isfinite(src_xy).all(1)
    # A ray the source model folds back (fisheye beyond its invertible field) lands on a pixel
    # that belongs to another ray: keep only pixels whose own ray is this one.
    back = src.cam_ray_from_img(src_xy[ok])
    ok[ok] = np.einsum("ij,ij->i", back, rays[ok] / np.linalg.norm(rays[ok], axis=1)[:, None]) \
        > np.cos(RAY_AGREEMENT_RAD)
    src_xy[~ok] = 0.5 - 2.0  # -> -1.5 after the shift: outside, so remap fills the border value
    maps = (src_xy - 0.5).astype(np.float32).reshape(target.height, target.width, 2)
    return maps[..., 0], maps[..., 1]
