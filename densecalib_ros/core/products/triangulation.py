"""A scene point from its pixels in two or more calibrated cameras (`densecalib triangulate`):
measuring with the rig (a door's height in a forensic scene, an animal's nose in an arena, a
known length to check the metric scale).

Pixels are in the OpenCV/ROS convention (top-left pixel centre at (0, 0)), as image viewers and
annotation tools give them, on the original (distorted) images. The point starts at the
least-squares meeting point of the cameras' rays (each pixel undistorted by its camera's model)
and is refined by Gauss-Newton on the reprojection error. Its covariance assumes independent
pixel errors of sigma_px per coordinate: (sigma^2 (J^T J)^-1), so it grows as the rays get
parallel. Coordinates are in the rig frame (and in the floor frame when the calibration has one),
in the rig's units (metres with a known baseline).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from ..errors import InputError
from ..types import RigCalibration

DEFAULT_PIXEL_SIGMA = 1.0
MIN_PARALLAX_DEG = 1.0  # below, the depth is barely determined (a warning, not an error)
# A pixel further than this from the point's projection (in sigmas, and at least px) was not
# clicked on the same point as the others (a warning: a mis-click or a stale calibration).
MISFIT_SIGMAS, MIN_MISFIT_PX = 5.0, 3.0
_GAUSS_NEWTON_STEPS = 20


@dataclass
class TriangulatedPoint:
    xyz_rig: np.ndarray  # (3,)
    covariance_rig: np.ndarray  # (3, 3)
    residuals_px: dict  # camera -> reprojection error [px]
    parallax_deg: float  # widest angle between two of its rays
    xyz_floor: Optional[np.ndarray] = None  # (3,) when the calibration has a floor frame
    warnings: list = field(default_factory=list)

    @property
    def std(self) -> np.ndarray:
        """1-sigma along the rig axes."""
        return np.sqrt(np.clip(np.diag(self.covariance_rig), 0.0, None))


def _rays(rig: RigCalibration, observations: dict) -> tuple[list, np.ndarray, np.ndarray]:
    names = list(observations)
    unknown = [n for n in names if n not in rig.cameras]
    if unknown:
        raise InputError(f"Camera(s) {', '.join(unknown)} are not in the calibration (its "
                         f"cameras: {', '.join(rig.cameras)}).")
    if len(names) < 2:
        raise InputError("A point needs its pixel in at least two cameras to be triangulated.")
    centres, directions = [], []
    for name in names:
        cam = rig.cameras[name]
        x, y = (float(v) for v in observations[name])
        w, h = cam.intrinsics.width, cam.intrinsics.height
        if not (-0.5 <= x <= w - 0.5 and -0.5 <= y <= h - 0.5):
            raise InputError(f"Pixel ({x:g}, {y:g}) lies outside camera {name}'s {w}x{h} image "
                             "(pixels: top-left pixel centre at (0, 0)).")
        ray = np.asarray(cam.intrinsics.to_pycolmap().cam_ray_from_img(
            np.array([[x + 0.5, y + 0.5]])), dtype=np.float64).reshape(3)
        if not np.isfinite(ray).all():
            raise InputError(f"Pixel ({x:g}, {y:g}) of camera {name} lies outside its lens "
                             "model's field of view.")
        pose = np.asarray(cam.cam_from_rig, dtype=np.float64)
        centres.append(-pose[:3, :3].T @ pose[:3, 3])
        d = pose[:3, :3].T @ ray
        directions.append(d / np.linalg.norm(d))
    return names, np.array(centres), np.array(directions)


def project(rig: RigCalibration, name: str, xyz_rig: np.ndarray) -> np.ndarray:
    """OpenCV-convention pixels (N, 2) of rig-frame points (N, 3) (or (3,) -> (2,)) in camera
    `name`, with its lens distortion; nan for points behind it."""
    cam = rig.cameras[name]
    points = np.asarray(xyz_rig, dtype=np.float64)
    pose = np.asarray(cam.cam_from_rig, dtype=np.float64)
    x_cam = points.reshape(-1, 3) @ pose[:3, :3].T + pose[:3, 3]
    pixels = np.full((len(x_cam), 2), np.nan)
    front = x_cam[:, 2] > 0
    if front.any():
        pixels[front] = np.asarray(cam.intrinsics.to_pycolmap().img_from_cam(x_cam[front]),
                                   dtype=np.float64).reshape(-1, 2) - 0.5
    return pixels.reshape(2) if points.ndim == 1 else pixels


def triangulate(rig: RigCalibration, observations: dict,
                sigma_px: float = DEFAULT_PIXEL_SIGMA) -> TriangulatedPoint:
    """The point seen at observations {camera: (x, y) OpenCV pixels} (module docstring)."""
    names, centres, dirs = _rays(rig, observations)
    projector = np.eye(3)[None] - dirs[:, :, None] * dirs[:, None, :]  # (I - d d^T) per ray
    xyz = np.linalg.lstsq(projector.sum(0), np.einsum("kij,kj->i", projector, centres),
                          rcond=None)[0]
    observed = np.array([observations[n] for n in names], dtype=np.float64).reshape(-1)

    def residuals(p):
        return np.concatenate([project(rig, n, p) for n in names]) - observed

    scale = max(float(np.linalg.norm(xyz - centres.mean(0))), 1e-9)
    jac = np.zeros((len(observed), 3))
    for _ in range(_GAUSS_NEWTON_STEPS):
        r = residuals(xyz)
        if not np.isfinite(r).all():
            break
        for i in range(3):
            step = np.zeros(3)
            step[i] = 1e-7 * scale
            jac[:, i] = (residuals(xyz + step) - residuals(xyz - step)) / (2 * step[i])
        delta = np.linalg.lstsq(jac, -r, rcond=None)[0]
        xyz = xyz + delta
        if np.linalg.norm(delta) < 1e-12 * scale:
            break
    r = residuals(xyz)
    behind = [n for n, (a, b) in zip(names, r.reshape(-1, 2)) if not np.isfinite(a + b)]
    if behind:
        raise InputError(f"The rays do not meet in front of camera(s) {', '.join(behind)}: "
                         "check that the pixels show the same point in every camera.")
    cos = np.clip(dirs @ dirs.T, -1.0, 1.0)
    parallax = float(np.degrees(np.arccos(cos.min())))
    covariance = sigma_px ** 2 * np.linalg.pinv(jac.T @ jac)
    point = TriangulatedPoint(xyz, covariance,
                              {n: float(np.hypot(*rr)) for n, rr in zip(names, r.reshape(-1, 2))},
                              parallax)
    worst = max(point.residuals_px.values())
    if worst > MISFIT_SIGMAS * sigma_px and worst > MIN_MISFIT_PX:
        point.warnings.append(
            "its pixels do not meet at one point (misses of "
            + ", ".join(f"{n} {e:.1f}" for n, e in point.residuals_px.items())
            + f" px; clicks are good to about {sigma_px:g} px): one may show another scene "
            "point, or the calibration no longer fits; the standard deviations assume neither")
    if parallax < MIN_PARALLAX_DEG:
        point.warnings.append(f"its rays meet at only {parallax:.2f} deg: the depth is barely "
                              "determined (see the standard deviations)")
    floor = rig.quality.floor
    if floor:
        floor_from_rig = np.asarray(floor["floor_from_rig"], dtype=np.float64).reshape(4, 4)
        point.xyz_floor = floor_from_rig[:3, :3] @ xyz + floor_from_rig[:3, 3]
    return point


def distance(a: TriangulatedPoint, b: TriangulatedPoint) -> tuple[float, float]:
    """The distance between two triangulated points and its 1-sigma (rig units: metres once the
    rig has a scale), to first order along the line between them, the points' errors taken as
    independent (each was clicked on its own)."""
    d = b.xyz_rig - a.xyz_rig
    dist = float(np.linalg.norm(d))
    u = d / max(dist, 1e-300)
    return dist, float(np.sqrt(max(u @ (a.covariance_rig + b.covariance_rig) @ u, 0.0)))
