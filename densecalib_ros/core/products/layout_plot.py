"""A picture of a calibrated rig: every camera (its optical centre, viewing direction and field of
view) and the scene points, seen from above and from the side, with a scale bar. It shows at a
glance what no table does: a camera placed on the wrong side of the arena, one looking the wrong
way, a rig mirrored, a scene bent or split in two.

The plot frame: the floor frame (z up) when the calibration has a floor; otherwise "up" is the
cameras' mean image-up direction (cameras mounted roughly upright), and x is the reference
camera's viewing direction laid flat. The top view shows x-y, the side view x-z.
"""
from __future__ import annotations

import colorsys
import math
from typing import Optional

import cv2
import numpy as np

from ..errors import InputError
from ..types import CameraIntrinsics, RigCalibration
from .floor import world_from_rig
from .report import camera_centres_in_rig

PANEL_PX = 640
MAX_POINTS = 50_000  # drawn; a random subset beyond
_BACKGROUND = (255, 255, 255)
_POINT_GREY = (150, 150, 150)
_BEFORE = (90, 90, 90)  # the other calibration's cameras (--against)
_TEXT = (30, 30, 30)
_FONT = cv2.FONT_HERSHEY_SIMPLEX


def plot_from_rig(rig: RigCalibration) -> tuple[np.ndarray, str]:
    """The 4x4 transform from the rig frame to the plot frame (module docstring) and its name."""
    if rig.quality.floor:
        return world_from_rig(rig)[0], "the floor frame"
    poses = [np.asarray(c.cam_from_rig, dtype=np.float64) for c in rig.cameras.values()]
    up = -sum(p[1, :3] for p in poses)  # each camera's image-up (-y) in the rig frame
    if np.linalg.norm(up) < 1e-6:
        up = np.array([0.0, -1.0, 0.0])  # the reference camera's image-up
    up /= np.linalg.norm(up)
    ref = np.asarray(rig.cameras[rig.reference_camera].cam_from_rig, dtype=np.float64)
    x = ref[2, :3] - (ref[2, :3] @ up) * up
    if np.linalg.norm(x) < 1e-6:  # the reference looks straight down: its image x instead
        x = ref[0, :3] - (ref[0, :3] @ up) * up
    x /= np.linalg.norm(x)
    plot_from_rig_ = np.eye(4)
    plot_from_rig_[:3, :3] = np.stack([x, np.cross(up, x), up])
    return plot_from_rig_, "no floor: up = the cameras' mean image-up"


def pixel_rays(intrinsics: CameraIntrinsics, xy_px: np.ndarray,
               max_angle_rad: float) -> np.ndarray:
    """(N, 3) unit rays (camera frame) through COLMAP pixels xy_px (N, 2), distortion included;
    fisheye lenses by their equidistant angle (their normalised coordinates end at 90 deg), held
    at most max_angle_rad off the axis."""
    camera = intrinsics.to_pycolmap()
    xy_px = np.atleast_2d(np.asarray(xy_px, dtype=np.float64))
    if "FISHEYE" not in intrinsics.model:
        rays = np.column_stack([camera.cam_from_img(xy_px), np.ones(len(xy_px))])
        return rays / np.linalg.norm(rays, axis=1, keepdims=True)
    offsets = (xy_px - [camera.principal_point_x, camera.principal_point_y]) / \
        [camera.focal_length_x, camera.focal_length_y]
    radius = np.linalg.norm(offsets, axis=1)
    theta = np.minimum(radius, max_angle_rad)
    direction = offsets / np.maximum(radius, 1e-12)[:, None]
    return np.column_stack([direction * np.sin(theta)[:, None], np.cos(theta)])


def half_fov_rad(intrinsics: CameraIntrinsics, axis: int) -> float:
    """Half the field of view across the image's x (axis 0) or y (axis 1) through its centre
    (pixel_rays; fisheye lenses up to 100 deg)."""
    edge = np.array([intrinsics.width / 2.0, intrinsics.height / 2.0])
    edge[axis] = 0.0
    ray = pixel_rays(intrinsics, edge, math.radians(100.0))[0]
    return float(math.atan2(abs(ray[axis]), ray[2]))


def _nice_length(span: float) -> float:
    """1, 2 or 5 x 10^k, about a fifth of span."""
    raw = span / 5.0
    power = 10.0 ** math.floor(math.log10(raw))
    return next(m * power for m in (5.0, 2.0, 1.0) if m * power <= raw * 1.5)


def camera_colours(n: int) -> list[tuple[int, int, int]]:
    out = []
    for i in range(n):
        r, g, b = colorsys.hsv_to_rgb(i / max(n, 1), 0.85, 0.8)
        out.append((int(255 * b), int(255 * g), int(255 * r)))  # BGR
    return out


def _panel(title: str, axes: tuple[int, int], centres: np.ndarray, rays: list, points: np.ndarray,
           names: list[str], unit: str, before: Optional[np.ndarray] = None) -> np.ndarray:
    """One view: the plot-frame coordinates `axes` (e.g. (0, 1) = x right, y up on the image).
    before: (C, 3) the cameras' centres in another calibration (NaN: not in it), drawn as grey
    rings joined to where the cameras are now."""
    image = np.full((PANEL_PX, PANEL_PX, 3), _BACKGROUND, np.uint8)
    cam2 = centres[:, axes]
    pts2 = points[:, axes] if len(points) else np.zeros((0, 2))
    old2 = before[:, axes] if before is not None else np.zeros((0, 2))
    known = np.isfinite(old2).all(1)
    lo = np.vstack([cam2, old2[known]]).min(0)
    hi = np.vstack([cam2, old2[known]]).max(0)
    if len(pts2) >= 20:  # the bulk of the scene, not its stray points
        lo = np.minimum(lo, np.percentile(pts2, 5, axis=0))
        hi = np.maximum(hi, np.percentile(pts2, 95, axis=0))
    span = float(max((hi - lo).max(), 1e-9))
    mid = (lo + hi) / 2.0
    margin = 60
    scale = (PANEL_PX - 2 * margin) / (1.15 * span)  # px per unit

    def px(xy: np.ndarray) -> np.ndarray:
        uv = (np.atleast_2d(xy) - mid) * scale
        return np.column_stack([PANEL_PX / 2 + uv[:, 0], PANEL_PX / 2 - uv[:, 1]])

    if len(pts2):
        uv = np.round(px(pts2)).astype(int)
        inside = (uv >= 0).all(1) & (uv[:, 0] < PANEL_PX) & (uv[:, 1] < PANEL_PX)
        image[uv[inside, 1], uv[inside, 0]] = _POINT_GREY
    for i in np.flatnonzero(known):  # where the other calibration had each camera
        was, now = (tuple(np.round(px(xy)[0]).astype(int)) for xy in (old2[i], cam2[i]))
        cv2.line(image, was, now, _BEFORE, 1, cv2.LINE_AA)
        cv2.circle(image, was, 7, _BEFORE, 2, cv2.LINE_AA)
    wedge = 0.12 * span
    for i, (name, colour) in enumerate(zip(names, camera_colours(len(names)))):
        c = px(cam2[i])[0]
        for ray in rays[i]:  # field-of-view edges, then the optical axis
            end = px(cam2[i] + wedge * ray[list(axes)])[0]
            cv2.line(image, tuple(np.round(c).astype(int)), tuple(np.round(end).astype(int)),
                     colour, 2 if ray is rays[i][-1] else 1, cv2.LINE_AA)
        cv2.circle(image, tuple(np.round(c).astype(int)), 5, colour, -1, cv2.LINE_AA)
        cv2.putText(image, name, (int(c[0]) + 7, int(c[1]) - 7), _FONT, 0.45, colour, 1,
                    cv2.LINE_AA)
    bar = _nice_length(span)
    y = PANEL_PX - 20
    cv2.line(image, (margin, y), (margin + int(round(bar * scale)), y), _TEXT, 2)
    cv2.putText(image, f"{bar:g} {unit}", (margin, y - 8), _FONT, 0.5, _TEXT, 1, cv2.LINE_AA)
    cv2.putText(image, title, (12, 24), _FONT, 0.5, _TEXT, 1, cv2.LINE_AA)
    cv2.rectangle(image, (0, 0), (PANEL_PX - 1, PANEL_PX - 1), (200, 200, 200), 1)
    return image


def centres_as_in(rig: RigCalibration, other: RigCalibration) -> np.ndarray:
    """(C, 3) the optical centres of rig's cameras in `other`, in rig's frame and unit (NaN for
    cameras `other` lacks): both frames are their reference camera's, so they must share it; an
    up-to-scale calibration is brought to the other's unit by the cameras' distances from it."""
    if other.reference_camera != rig.reference_camera:
        raise InputError(f"The calibrations have different reference cameras "
                         f"({rig.reference_camera}, {other.reference_camera}): their rig frames "
                         "cannot be drawn together.")

    now, then = camera_centres_in_rig(rig), camera_centres_in_rig(other)
    common = [n for n in rig.cameras if n in other.cameras and n != rig.reference_camera]
    factor = 1.0
    if common and not (rig.metric_scale and other.metric_scale):
        factor = float(np.median([np.linalg.norm(now[n]) / max(np.linalg.norm(then[n]), 1e-12)
                                  for n in common]))
    return np.array([factor * then[n] if n in then else np.full(3, np.nan) for n in rig.cameras])


def draw_layout(rig: RigCalibration, points_rig: Optional[np.ndarray] = None,
                seed: int = 0, against: Optional[RigCalibration] = None) -> np.ndarray:
    """The rig's top and side views side by side (BGR uint8, PANEL_PX x 2 PANEL_PX): cameras as
    dots with their names, optical axis (thick) and field of view (thin), scene points (rig
    frame, (N, 3), optional) in grey, a scale bar in metres or the rig's unit; with `against`
    (another calibration of the rig, e.g. the previous one), where its cameras were, as grey
    rings joined to where they are now (centres_as_in)."""
    plot_from_rig_, frame_name = plot_from_rig(rig)
    rotation, shift = plot_from_rig_[:3, :3], plot_from_rig_[:3, 3]
    names = list(rig.cameras)
    centres = np.array(list(camera_centres_in_rig(rig).values())) @ rotation.T + shift
    rays_top, rays_side = [], []
    for name in names:
        cam = rig.cameras[name]
        plot_from_cam = rotation @ np.asarray(cam.cam_from_rig, dtype=np.float64)[:3, :3].T
        for rays, axis in ((rays_top, 0), (rays_side, 1)):
            a = half_fov_rad(cam.intrinsics, axis)
            edges = [np.eye(3)[axis] * s * math.sin(a) + np.array([0.0, 0.0, math.cos(a)])
                     for s in (-1.0, 1.0)]
            rays.append([plot_from_cam @ d for d in edges] + [plot_from_cam[:, 2]])
    points = np.zeros((0, 3))
    if points_rig is not None and len(points_rig):
        points = np.asarray(points_rig, dtype=np.float64).reshape(-1, 3)
        points = points[np.isfinite(points).all(1)]
        if len(points) > MAX_POINTS:
            points = points[np.random.default_rng(seed).choice(len(points), MAX_POINTS,
                                                               replace=False)]
        points = points @ rotation.T + shift
    before = None
    if against is not None:
        before = centres_as_in(rig, against) @ rotation.T + shift
    unit = "m" if rig.metric_scale else "units (no metric scale)"
    top = _panel(f"top view ({frame_name})", (0, 1), centres, rays_top, points,
                 names, unit, before)
    side = _panel("side view (x right, z up)", (0, 2), centres, rays_side, points, names, unit,
                  before)
    return np.hstack([top, side])
