"""The floor under a rig, found in its reconstructed scene points (`calibrate --floor`).

SfM gives the rig in the frame of its reference camera; arena tracking and forensic measurement
want heights above the floor. The floor is a plane of many scene points with the cameras above it:
planes are found by RANSAC one after another (each removing its points), and the floor is the one
with the most points among those that have (nearly) every camera on one side, the "up" side, and
face up: their up normal lies within MAX_TILT_DEG of the cameras' mean image-up direction (cameras
are mounted with upright images; one pitched down by 50 deg still has its image-up 50 deg from
the world's). A wall faced by cameras looking down has its normal more than 90 deg from their
image-up, a ceiling faces down; a table top can only win over the floor with more points.
Cameras that all look straight down (view="top") have image-ups that say nothing of the world's:
there the floor is the largest plane that every camera looks down onto (within
MAX_TOP_VIEW_DEG). That is a choice the user makes, not a fallback: level cameras facing a wall
see the same geometry, and taking the wall for the floor would give wrong heights silently.

The floor frame: z up (the plane normal), origin at the centre of the floor points on the plane,
x along the reference camera's viewing direction laid flat on the floor. Units are the rig's
(metres with a known baseline).
"""
from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

import numpy as np

from ..errors import InputError
from ..types import RigCalibration
from .scale import rig_units_per_model_unit

log = logging.getLogger(__name__)

MAX_TILT_DEG = 60.0
MAX_TOP_VIEW_DEG = 45.0
MIN_FLOOR_POINTS = 30
MIN_PLANE_FRACTION = 0.05  # planes holding fewer of the points are not looked at
MAX_PLANES = 6
RANSAC_ITERATIONS = 2000
# inlier distance as a fraction of the points' median distance from their median: SfM points on
# a flat floor lie within ~0.5 % of the scene's size of it
INLIER_FRACTION_OF_SCENE = 0.01
CAMERAS_ABOVE_FRACTION = 0.9
NO_FLOOR_WARNING = "no floor frame: "  # how record_floor's warning in rig.quality begins


@dataclass(frozen=True)
class Floor:
    floor_from_rig: np.ndarray  # 4x4
    num_points: int  # scene points on the floor plane
    rms: float  # their distance from it, rig units
    camera_heights: dict  # camera name -> height of its optical centre above the floor

    def to_dict(self) -> dict:
        return {"floor_from_rig": [float(v) for v in self.floor_from_rig.reshape(-1)],
                "num_points": int(self.num_points), "rms": float(self.rms),
                "camera_heights": {k: float(v) for k, v in self.camera_heights.items()}}


def _fit_plane(points: np.ndarray) -> tuple[np.ndarray, float]:
    """Least-squares plane (unit normal n, offset d: n.x + d = 0) through points."""
    centre = points.mean(0)
    normal = np.linalg.svd(points - centre)[2][-1]
    return normal, -float(normal @ centre)


def _planes(points: np.ndarray, threshold: float, rng: np.random.Generator):
    """(normal, d, inlier indices) of up to MAX_PLANES planes, the largest first."""
    remaining = np.arange(len(points))
    min_size = max(MIN_FLOOR_POINTS, int(MIN_PLANE_FRACTION * len(points)))
    for _ in range(MAX_PLANES):
        if len(remaining) < min_size:
            return
        pts = points[remaining]
        triples = rng.integers(0, len(pts), (RANSAC_ITERATIONS, 3))
        a, b, c = pts[triples[:, 0]], pts[triples[:, 1]], pts[triples[:, 2]]
        normals = np.cross(b - a, c - a)
        norms = np.linalg.norm(normals, axis=1)
        ok = norms > 1e-12
        normals, a = normals[ok] / norms[ok, None], a[ok]
        if not len(normals):
            return
        counts = np.zeros(len(normals), int)
        for start in range(0, len(normals), 200):  # (200, N) distances at a time
            n = normals[start:start + 200]
            dist = np.abs(pts @ n.T - np.einsum("ij,ij->i", n, a[start:start + 200]))
            counts[start:start + 200] = (dist < threshold).sum(0)
        best = int(np.argmax(counts))
        inliers = np.abs((pts - a[best]) @ normals[best]) < threshold
        if inliers.sum() < min_size:
            return
        normal, d = _fit_plane(pts[inliers])  # refit, then take the points near the refit
        inliers = np.abs(pts @ normal + d) < threshold
        yield normal, d, remaining[inliers]
        remaining = remaining[~inliers]


VIEWS = ("upright", "top")


def find_floor(points_rig: np.ndarray, rig: RigCalibration, view: str = "upright",
               seed: int = 0) -> Floor:
    """The floor plane in rig-frame scene points (module docstring), for cameras mounted upright
    (view "upright") or all looking down onto it ("top"); InputError when no plane
    qualifies."""
    if view not in VIEWS:
        raise InputError(f"Unknown camera view {view!r} for the floor: use one of "
                         f"{', '.join(VIEWS)}.")
    points = np.asarray(points_rig, dtype=np.float64).reshape(-1, 3)
    points = points[np.isfinite(points).all(1)]
    if len(points) < MIN_FLOOR_POINTS:
        raise InputError(f"Only {len(points)} scene points: too few to find the floor.")
    poses = {n: np.asarray(c.cam_from_rig, dtype=np.float64) for n, c in rig.cameras.items()}
    centres = np.array([-p[:3, :3].T @ p[:3, 3] for p in poses.values()])
    image_up = -np.array([p[1, :3] for p in poses.values()])  # -y of each camera, rig frame
    views = np.array([p[2, :3] for p in poses.values()])  # +z: viewing directions
    mean_up = image_up.sum(0) / max(np.linalg.norm(image_up.sum(0)), 1e-12)
    scene = float(np.median(np.linalg.norm(points - np.median(points, 0), axis=1)))
    threshold = INLIER_FRACTION_OF_SCENE * scene
    candidates, seen = [], []
    for normal, d, inliers in _planes(points, threshold, np.random.default_rng(seed)):
        side = centres @ normal + d
        if np.mean(side < 0) > 0.5:  # orient the normal toward the cameras
            normal, d, side = -normal, -d, -side
        above = np.mean(side > threshold) >= CAMERAS_ABOVE_FRACTION
        seen.append(f"{len(inliers)} points, tilt "
                    f"{np.degrees(np.arccos(np.clip(normal @ mean_up, -1, 1))):.0f} deg"
                    f"{'' if above else ', cameras on both sides'}")
        if above:
            candidates.append((normal, d, inliers))
    if view == "upright":
        floors = [c for c in candidates if c[0] @ mean_up >= np.cos(np.radians(MAX_TILT_DEG))]
    else:
        floors = [c for c in candidates
                  if np.all(views @ c[0] <= -np.cos(np.radians(MAX_TOP_VIEW_DEG)))]
    best = max(floors, key=lambda c: len(c[2]), default=None)
    if best is None:
        need = ("the cameras upright (image up = world up; if they all look straight down, "
                "use the top view: calibrate --floor top, densecalib floor --view top)"
                if view == "upright" else
                f"every camera looking down onto it (within {MAX_TOP_VIEW_DEG:g} deg)")
        raise InputError("No floor found among the scene's planes (" + "; ".join(seen or [
            "none"]) + "): the floor needs many matched points with every camera above it, and "
            + need + ".")
    normal, d, inliers = best
    on_floor = points[inliers]
    origin = on_floor.mean(0) - (on_floor.mean(0) @ normal + d) * normal
    ref = poses[rig.reference_camera]
    x = ref[2, :3] - (ref[2, :3] @ normal) * normal  # reference view direction, laid flat
    if np.linalg.norm(x) < 1e-6:  # looking straight down: its image x instead
        x = ref[0, :3] - (ref[0, :3] @ normal) * normal
    x /= np.linalg.norm(x)
    rig_from_floor = np.eye(4)
    rig_from_floor[:3, :3] = np.column_stack([x, np.cross(normal, x), normal])
    rig_from_floor[:3, 3] = origin
    floor_from_rig = np.linalg.inv(rig_from_floor)
    heights = {n: float(c @ normal + d) for n, c in zip(poses, centres)}
    rms = float(np.sqrt(np.mean((on_floor @ normal + d) ** 2)))
    return Floor(floor_from_rig, int(len(inliers)), rms, heights)


def world_from_rig(rig: RigCalibration) -> tuple[np.ndarray, str]:
    """(4x4 world_from_rig, the world's description) of the world frame that exports and views
    use: the floor frame when the calibration has one (z up, so points come out as heights above
    the floor), else the rig frame."""
    floor = rig.quality.floor
    if floor:
        return (np.asarray(floor["floor_from_rig"], dtype=np.float64).reshape(4, 4),
                "the floor frame (z up, origin on the floor)")
    return np.eye(4), f"the rig frame (reference camera {rig.reference_camera})"


def reconstruction_points_in_rig(reconstruction, rig: RigCalibration) -> np.ndarray:
    """(N, 3) scene points of a pycolmap.Reconstruction in the rig frame (its reference camera's
    image gives the rig's pose in the reconstruction's world)."""
    ref = next((im for im in reconstruction.images.values()
                if im.name == rig.reference_camera), None)
    if ref is None:
        raise InputError(f"The reconstruction has no image of the reference camera "
                         f"{rig.reference_camera}: cannot place its points in the rig frame.")
    rig_from_world = np.asarray(ref.cam_from_world().matrix(), dtype=np.float64)
    xyz = np.array([p.xyz for p in reconstruction.points3D.values()], dtype=np.float64)
    if not len(xyz):
        return np.zeros((0, 3))
    # the reconstruction's unit may differ from the rig file's (scale_reconstruction_to_baseline
    # keeps both metric; otherwise scale them to the rig's by the reference's baseline)
    points = xyz @ rig_from_world[:3, :3].T + rig_from_world[:3, 3]
    return points * rig_units_per_model_unit(reconstruction, rig)


def saved_scene_points(folder: str | os.PathLike, rig: RigCalibration
                       ) -> Optional[tuple[np.ndarray, Optional[np.ndarray]]]:
    """The scene points of the COLMAP model saved beside a calibration (export.read_saved_model):
    (N, 3) in the rig frame and unit, and their colours (N, 3) RGB uint8 (None for a model saved
    before points were coloured); None when no model was saved."""
    from ..io.export import read_saved_model

    reconstruction = read_saved_model(folder)
    if reconstruction is None:
        return None
    colours = np.array([p.color for p in reconstruction.points3D.values()],
                       np.uint8).reshape(-1, 3)
    return (reconstruction_points_in_rig(reconstruction, rig),
            colours if colours.any() else None)


def record_floor(result, view: str = "upright") -> None:
    """Find the floor of a pipeline CalibrationResult and record it in rig.quality.floor
    (Floor.to_dict), or, when there is none, say why in rig.quality.warnings: the
    calibration itself is worth keeping either way."""
    rig = result.rig
    try:
        if result.reconstruction is None:
            raise InputError("the calibration has no scene points (dense matcher without "
                             "keypoint matches)")
        floor = find_floor(reconstruction_points_in_rig(result.reconstruction, rig), rig, view)
    except InputError as exc:
        warning = f"{NO_FLOOR_WARNING}{exc}"
        log.warning("%s", warning)
        rig.quality.warnings.append(warning)
        return
    set_floor(rig, floor)
    unit = "m" if rig.metric_scale else "units"
    log.info("floor: %d points (rms %.3g %s); camera heights %s", floor.num_points, floor.rms,
             unit, ", ".join(f"{n} {h:.3g}" for n, h in floor.camera_heights.items()))


def find_floor_of_saved_calibration(folder: str | os.PathLike, rig: RigCalibration,
                                    view: str = "upright") -> Floor:
    """The floor of a calibration already written (`densecalib floor`): found in the scene points
    of the COLMAP model saved beside its calibration.json (folder/colmap), so a rig calibrated
    without --floor, or whose floor was not found as "upright", needs no new calibration."""
    scene = saved_scene_points(folder, rig)
    if scene is None:
        raise InputError(f"{folder} has no COLMAP model ({Path(folder) / 'colmap'}) with the "
                         "scene points: calibrate again with --floor (a dense matcher without "
                         "keypoint matches writes none).")
    return find_floor(scene[0], rig, view)


def set_floor(rig: RigCalibration, floor: Floor) -> None:
    """Record `floor` in rig.quality.floor, dropping an earlier "no floor" warning."""
    rig.quality.floor = floor.to_dict()
    rig.quality.warnings = [w for w in rig.quality.warnings if not w.startswith(NO_FLOOR_WARNING)]


def warn_if_floor_lost(rig: RigCalibration, previous: Optional[RigCalibration], how: str) -> None:
    """A recalibration of a calibration with a floor frame that came out without one: say so in
    rig.quality.warnings (exports would silently change their world to the rig frame).
    how: what finds it again, in the caller's terms."""
    if previous is None or not previous.quality.floor or rig.quality.floor:
        return
    warning = f"no floor frame: the previous calibration had one, this one has none; {how}"
    log.warning("%s", warning)
    rig.quality.warnings.append(warning)
