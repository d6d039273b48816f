"""Does a calibration still fit the rig? New images are matched and every match is held against
the calibration's epipolar geometry: with the calibrated intrinsics and relative pose of two
cameras, a right match lies on its epipolar line. A camera that was bumped or refocused since
breaks that for all of its pairs, the others keep fitting, so the check names the camera to look
at, in seconds and without a recalibration.

Error of a match (px): the angle between each ray and the epipolar plane of the other, times that
camera's focal length, averaged over the two cameras. A pair's figure is the median over its
matches (outliers of the matcher do not move a median). A bump that only translates a camera
along its baselines leaves the epipolar planes in place and is not seen; bumps rotate cameras.
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from .types import RigCalibration, SiteMatchSet

# A pair below this many matches over all frame sets gets no figure (its median would be noise).
MIN_PAIR_MATCHES = 20
DEFAULT_TOLERANCE_PX = 2.0  # a pair fits when its median epipolar error is at most this


@dataclass
class PairCheck:
    cameras: tuple[str, str]
    num_matches: int
    median_error_px: float

    def fits(self, tolerance_px: float) -> bool:
        return self.median_error_px <= tolerance_px


def _skew(t: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])


def epipolar_errors_px(rig: RigCalibration, camera_names: Sequence[str],
                       match_sets: Sequence[SiteMatchSet]) -> dict[tuple[str, str], np.ndarray]:
    """Per unordered pair of calibrated cameras (names in camera_names order), the epipolar error
    (px, module docstring) of each of its matches over all frame sets."""
    cams = {n: rig.cameras[n] for n in camera_names if n in rig.cameras}
    colmap = {n: c.intrinsics.to_pycolmap() for n, c in cams.items()}
    focal = {n: float(np.mean([colmap[n].focal_length_x, colmap[n].focal_length_y])) for n in cams}
    out: dict[tuple[str, str], list[np.ndarray]] = {}
    for (i, a), (j, b) in itertools.combinations(enumerate(camera_names), 2):
        if a not in cams or b not in cams:
            continue
        b_from_a = cams[b].cam_from_rig @ np.linalg.inv(cams[a].cam_from_rig)
        t = b_from_a[:3, 3]
        if np.linalg.norm(t) < 1e-12:
            continue  # one optical centre: no epipolar geometry
        essential = _skew(t / np.linalg.norm(t)) @ b_from_a[:3, :3]
        errors = []
        for ms in match_sets:
            pm = ms.pairs.get((i, j))
            if pm is None:
                continue
            valid = np.flatnonzero(pm.target >= 0)
            xy_a = ms.sites[i][valid]
            xy_b = ms.sites[j][pm.target[valid]].copy()
            if pm.target_xy_px is not None:
                refined = np.isfinite(pm.target_xy_px[valid]).all(1)
                xy_b[refined] = pm.target_xy_px[valid][refined]
            ray_a = colmap[a].cam_ray_from_img(xy_a)
            ray_b = colmap[b].cam_ray_from_img(xy_b)
            ray_a /= np.linalg.norm(ray_a, axis=1, keepdims=True)
            ray_b /= np.linalg.norm(ray_b, axis=1, keepdims=True)
            plane_b = ray_a @ essential.T  # normal of the epipolar plane in camera b
            plane_a = ray_b @ essential  # ... and in camera a
            sin_b = np.abs(np.einsum("ij,ij->i", ray_b, plane_b)) / np.linalg.norm(plane_b, axis=1)
            sin_a = np.abs(np.einsum("ij,ij->i", ray_a, plane_a)) / np.linalg.norm(plane_a, axis=1)
            err = 0.5 * (np.arcsin(np.clip(sin_a, 0, 1)) * focal[a]
                         + np.arcsin(np.clip(sin_b, 0, 1)) * focal[b])
            errors.append(err[np.isfinite(err)])
        out[(a, b)] = np.concatenate(errors) if errors else np.zeros(0)
    return out


def check_pairs(errors: dict[tuple[str, str], np.ndarray]) -> list[PairCheck]:
    """PairCheck per pair with at least MIN_PAIR_MATCHES matches."""
    return [PairCheck(pair, len(e), float(np.median(e))) for pair, e in errors.items()
            if len(e) >= MIN_PAIR_MATCHES]


def suspect_cameras(checks: Sequence[PairCheck], tolerance_px: float) -> list[str]:
    """Cameras every one of whose checked pairs fails (with at least one pair failing): the ones
    that moved. When one pair fails alone, neither of its cameras is named (either may have)."""
    names = sorted({n for c in checks for n in c.cameras})
    out = []
    for name in names:
        mine = [c for c in checks if name in c.cameras]
        if mine and not any(c.fits(tolerance_px) for c in mine) and len(mine) >= 2:
            out.append(name)
    return out
