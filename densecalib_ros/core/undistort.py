"""Undistorted images: each camera's images resampled to an ideal pinhole camera (no distortion)
with the same optical centre and axes, so straight lines are straight and pixel positions can be
measured with K alone (forensic measurement, tools that assume pinhole cameras).

The pinhole keeps the image size, puts the principal point at the image centre and keeps the
camera's focal length, unless that would show more than max_fov_deg across the width (fisheye
lenses): then the focal grows until the width spans max_fov_deg. Output pixels whose ray the
original camera does not image (outside a fisheye's circle, beyond the modelled field) are black.
The rig's extrinsics are unchanged: undistorting rotates nothing.
"""
from __future__ import annotations

import numpy as np

from .types import CameraIntrinsics

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


def undistortion_maps(source: CameraIntrinsics, target: CameraIntrinsics
                      ) -> tuple[np.ndarray, np.ndarray]:
    """cv2.remap maps (float32, target's H x W, OpenCV pixel convention): for each target pixel,
    where the same ray falls in the source image; -1 where the source does not image it."""
    src, dst = source.to_pycolmap(), target.to_pycolmap()
    xs = np.arange(target.width) + 0.5
    ys = np.arange(target.height) + 0.5
    xy = np.stack(np.meshgrid(xs, ys), -1).reshape(-1, 2)
    rays = dst.cam_ray_from_img(xy)
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
