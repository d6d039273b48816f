"""A picture of a calibrated rig: every camera (its optical centre, optical axis and field of
view) and the scene points, seen from above and from the side, with axes in metres (or the rig's
own unit where nothing set the scale) and a legend. It shows at a glance what no table does: a
camera placed on the wrong side of the arena, one looking the wrong way, a rig mirrored, a scene
bent or split in two.

The plot frame: the floor frame (z up) when the calibration has a floor; otherwise "up" is the
cameras' mean image-up direction (cameras mounted roughly upright), and x is the reference
camera's viewing direction laid flat. The top view shows x-y, the side view x-z, both at one
scale per view (a metre is as long across as up). Every scene point is in view: the few a
calibration triangulates far off (STRAY_FENCE) are drawn at the edge of the view and counted in
the legend, rather than shrinking the scene to a dot.

Drawn with matplotlib on its Agg canvas, imported inside draw_layout only: the core imports
without it.
"""
from __future__ import annotations

import colorsys
import math
from dataclasses import dataclass
from typing import Any, Optional

import numpy as np

from ..errors import InputError
from ..method.plausibility import perspective_fold_radius
from ..types import CameraIntrinsics, RigCalibration
from .floor import world_from_rig
from .report import camera_centres_in_rig

FIGURE_PX = (1400, 700)  # width, height: two views and a legend column side by side
DPI = 100  # pixels per inch: font sizes are in points (1/72 inch)
MAX_POINTS = 50_000  # drawn; a random subset beyond (the picture would not change)
# A scene point further beyond the scene's 5-95 % range (and the cameras) than that range's
# largest extent is a stray triangulation (a point at a small angle, far off): it would shrink
# the scene to a dot, so it is drawn at the edge of the view and counted in the legend.
STRAY_FENCE = 1.0
MIN_POINTS_FOR_FENCE = 20  # fewer points have no "bulk" to judge strays by: all are shown
FRUSTUM_FRACTION = 0.08  # frustum depth: this fraction of what is drawn (cameras and scene)
AXIS_LENGTH = 1.8  # the optical axis arrow, in frustum depths: it reaches out of the frustum
MAX_CORNER_ANGLE_RAD = math.radians(80.0)  # wide fisheye corners: the frustum stays in front
MARGIN_FRACTION = 0.08  # free space around what is drawn, of the view's span: room for labels
LABEL_CHARS = 22  # camera names longer than this are shortened on the plot and in the legend
# Label offsets tried around a camera's dot, in points: nearest ring first, each ring's
# directions from upper right round; a label beyond the first ring gets a leader line.
LABEL_RADII_PT = (6.0, 14.0, 26.0, 42.0, 62.0, 86.0)
LABEL_DIRECTIONS = 8
LABEL_FONT_PT = 9.0
DOT_PT = 7.0  # camera dot diameter
# Axes rectangles (figure fractions: left, bottom, width, height): top view, side view; the
# legend's column starts at LEGEND_LEFT. Room between them for tick labels and axis labels.
VIEW_RECTS = {"top": (0.055, 0.1, 0.36, 0.8), "side": (0.475, 0.1, 0.36, 0.8)}
LEGEND_LEFT = 0.845
POINT_GREY = (0.55, 0.55, 0.55)
STRAY_COLOUR = (0.75, 0.2, 0.2)
BEFORE_GREY = (0.3, 0.3, 0.3)  # the other calibration's cameras (--against)


@dataclass
class LayoutPlot:
    """draw_layout's figure and what its tests and callers look at."""

    figure: Any  # matplotlib.figure.Figure on an Agg canvas, FIGURE_PX at DPI
    views: dict  # "top", "side" -> matplotlib Axes
    labels: dict  # view -> [camera name Text, in the rig's camera order]
    scene: dict  # view -> [scatter of the scene points, scatter of the stray ones at the edge]
    num_stray_points: int  # scene points beyond the view, drawn at its edge
    unit: str  # of the axes: "m" or "rig units"


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
    at most max_angle_rad off the axis; pixels beyond a perspective lens's fold by the ray just
    inside it."""
    camera = intrinsics.to_pycolmap()
    xy_px = np.atleast_2d(np.asarray(xy_px, dtype=np.float64))
    if "FISHEYE" not in intrinsics.model:
        rays = np.column_stack([camera.cam_from_img(_within_fold(intrinsics, camera, xy_px)),
                                np.ones(len(xy_px))])
        return rays / np.linalg.norm(rays, axis=1, keepdims=True)
    offsets = (xy_px - [camera.principal_point_x, camera.principal_point_y]) / \
        [camera.focal_length_x, camera.focal_length_y]
    radius = np.linalg.norm(offsets, axis=1)
    theta = np.minimum(radius, max_angle_rad)
    direction = offsets / np.maximum(radius, 1e-12)[:, None]
    return np.column_stack([direction * np.sin(theta)[:, None], np.cos(theta)])


# Just inside the fold, where the undistortion still converges.
_INSIDE_FOLD = 0.99


def _within_fold(intrinsics: CameraIntrinsics, camera: Any, xy_px: np.ndarray) -> np.ndarray:
    """xy_px (N, 2) with the pixels beyond a perspective lens's fold (its fitted distortion
    stops increasing before the image corner: plausibility.corner_fold_warning) pulled in along
    their radius to just inside it, the widest ray the model has in their direction; others as
    they are. camera: intrinsics as a pycolmap.Camera."""
    fold = perspective_fold_radius(intrinsics)
    if fold is None:
        return xy_px
    centre = np.array([camera.principal_point_x, camera.principal_point_y])
    focal = np.array([camera.focal_length_x, camera.focal_length_y])
    offsets = (xy_px - centre) / focal
    radius = np.linalg.norm(offsets, axis=1, keepdims=True)
    scale = np.minimum(1.0, _INSIDE_FOLD * fold / np.maximum(radius, 1e-12))
    return centre + offsets * scale * focal


def camera_colours(n: int) -> list[tuple[int, int, int]]:
    """n distinct colours (BGR uint8 values), one per camera, spread round the hue circle."""
    out = []
    for i in range(n):
        r, g, b = colorsys.hsv_to_rgb(i / max(n, 1), 0.85, 0.8)
        out.append((int(255 * b), int(255 * g), int(255 * r)))  # BGR
    return out


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


def short_label(name: str) -> str:
    """A camera name as the plot writes it: at most LABEL_CHARS, a longer one keeping its head
    and its tail (where rigs number their cameras) around an ellipsis."""
    if len(name) <= LABEL_CHARS:
        return name
    tail = LABEL_CHARS // 3
    return name[:LABEL_CHARS - 1 - tail] + "\u2026" + name[-tail:]


@dataclass
class _Scene:
    """What is drawn, in the plot frame: (C, 3) camera centres, (C, 6, 3) frusta (apex, four
    image corners, the end of the optical axis), (N, 3) scene points, (M, 3) stray points
    (already moved to the edge of the box), (C, 3) the other calibration's centres or None, and
    the box (lo, hi) everything lies in."""

    centres: np.ndarray
    frusta: np.ndarray
    points: np.ndarray
    strays: np.ndarray
    before: Optional[np.ndarray]
    lo: np.ndarray
    hi: np.ndarray


def _scene(rig: RigCalibration, points_rig: Optional[np.ndarray], seed: int,
           against: Optional[RigCalibration]) -> _Scene:
    plot_from_rig_, _ = plot_from_rig(rig)
    rotation, shift = plot_from_rig_[:3, :3], plot_from_rig_[:3, 3]
    centres = np.array(list(camera_centres_in_rig(rig).values())) @ rotation.T + shift
    points = np.zeros((0, 3))
    if points_rig is not None and len(points_rig):
        points = np.asarray(points_rig, dtype=np.float64).reshape(-1, 3)
        points = points[np.isfinite(points).all(1)]
        if len(points) > MAX_POINTS:
            points = points[np.random.default_rng(seed).choice(len(points), MAX_POINTS,
                                                               replace=False)]
        points = points @ rotation.T + shift
    stray = np.zeros(len(points), bool)
    if len(points) >= MIN_POINTS_FOR_FENCE:
        lo = np.minimum(np.percentile(points, 5, axis=0), centres.min(0))
        hi = np.maximum(np.percentile(points, 95, axis=0), centres.max(0))
        fence = STRAY_FENCE * float((hi - lo).max())
        stray = ((points < lo - fence) | (points > hi + fence)).any(1)
    before = None
    if against is not None:
        before = centres_as_in(rig, against) @ rotation.T + shift
    shown = np.vstack([centres, points[~stray]] + (
        [before[np.isfinite(before).all(1)]] if before is not None else []))
    extent = float(np.ptp(shown, axis=0).max()) if len(shown) > 1 else 0.0
    depth = FRUSTUM_FRACTION * (extent if extent > 0 else 1.0)
    frusta = []
    for name, centre in zip(rig.cameras, centres):
        cam = rig.cameras[name]
        plot_from_cam = rotation @ np.asarray(cam.cam_from_rig, dtype=np.float64)[:3, :3].T
        w, h = cam.intrinsics.width, cam.intrinsics.height
        corners = pixel_rays(cam.intrinsics, np.array([[0.0, 0.0], [w, 0.0], [w, h], [0.0, h]]),
                             MAX_CORNER_ANGLE_RAD)
        rays = np.vstack([np.zeros(3), corners, [0.0, 0.0, AXIS_LENGTH]])
        frusta.append(centre + depth * rays @ plot_from_cam.T)
    frusta = np.array(frusta)
    box = np.vstack([shown, frusta.reshape(-1, 3)])
    lo, hi = box.min(0), box.max(0)
    return _Scene(centres, frusta, points[~stray], np.clip(points[stray], lo, hi), before, lo, hi)


def _limits(lo: np.ndarray, hi: np.ndarray, box_px: tuple[float, float]
            ) -> tuple[tuple[float, float], tuple[float, float]]:
    """(x limits, y limits) holding lo..hi with MARGIN_FRACTION around it, at one scale across
    and up in an axes box of box_px (width, height) pixels."""
    span = np.maximum(hi - lo, 1e-9)
    span = span + 2 * MARGIN_FRACTION * span.max()
    per_px = max(span[0] / box_px[0], span[1] / box_px[1])
    mid = (lo + hi) / 2.0
    half = 0.5 * per_px * np.array(box_px)
    return (mid[0] - half[0], mid[0] + half[0]), (mid[1] - half[1], mid[1] + half[1])


def draw_layout(rig: RigCalibration, points_rig: Optional[np.ndarray] = None,
                seed: int = 0, against: Optional[RigCalibration] = None) -> LayoutPlot:
    """The rig's top and side views and a legend (module docstring): cameras as dots with
    their names (placed clear of each other: place_labels), frustum through the image corners
    (thin) and optical axis (arrow), scene points (rig frame, (N, 3), optional) in grey; with
    `against` (another calibration of the rig, e.g. the previous one), where its cameras were,
    as grey rings joined to where they are now (centres_as_in). render() makes it an image."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    scene = _scene(rig, points_rig, seed, against)
    unit = "m" if rig.metric_scale else "rig units"
    figure = Figure(figsize=(FIGURE_PX[0] / DPI, FIGURE_PX[1] / DPI), dpi=DPI)
    FigureCanvasAgg(figure)
    names = list(rig.cameras)
    colours = [(r / 255, g / 255, b / 255) for b, g, r in camera_colours(len(names))]
    axis_unit = unit if rig.metric_scale else "rig units: no metric scale"
    plot = LayoutPlot(figure, {}, {}, {}, len(scene.strays), unit)
    for view, axes, title, ylabel in (
            ("top", (0, 1), "top view (looking down)", "y"),
            ("side", (0, 2), "side view (looking along +y)", "z, up")):
        ax = figure.add_axes(VIEW_RECTS[view])
        rect = VIEW_RECTS[view]
        xlim, ylim = _limits(scene.lo[list(axes)], scene.hi[list(axes)],
                             (rect[2] * FIGURE_PX[0], rect[3] * FIGURE_PX[1]))
        ax.set_xlim(*xlim)
        ax.set_ylim(*ylim)
        ax.set_title(title, fontsize=10)
        ax.set_xlabel(f"x [{axis_unit}]")
        ax.set_ylabel(f"{ylabel} [{axis_unit}]")
        ax.grid(True, color=(0.9, 0.9, 0.9), linewidth=0.6)
        ax.set_axisbelow(True)
        plot.views[view] = ax
        plot.scene[view] = _draw_view(ax, scene, list(axes), colours)
        frusta = scene.frusta[:, :, list(axes)]
        plot.labels[view] = place_labels(ax, scene.centres[:, list(axes)],
                                         [short_label(n) for n in names], colours,
                                         np.stack([frusta.min(1), frusta.max(1)], axis=1))
    frame = "in the floor frame" if rig.quality.floor else plot_from_rig(rig)[1]
    figure.suptitle(f"{len(names)} camera(s), {frame}; lengths in {axis_unit}", fontsize=11)
    _legend(figure, names, colours, scene, against is not None)
    return plot


def _draw_view(ax, scene: _Scene, axes: list[int], colours: list) -> list:
    """One view's points, frusta, axes, dots and rings; returns [points, strays] scatters."""
    points = ax.scatter(scene.points[:, axes[0]], scene.points[:, axes[1]], s=1.5,
                        color=POINT_GREY, linewidths=0, rasterized=True, zorder=1)
    strays = ax.scatter(scene.strays[:, axes[0]], scene.strays[:, axes[1]], s=14, marker="x",
                        color=STRAY_COLOUR, linewidths=0.8, zorder=2)
    if scene.before is not None:
        for was, now in zip(scene.before[:, axes], scene.centres[:, axes]):
            if np.isfinite(was).all():
                ax.plot([was[0], now[0]], [was[1], now[1]], color=BEFORE_GREY, lw=0.8, zorder=3)
                ax.plot(*was, "o", mfc="none", mec=BEFORE_GREY, ms=11, mew=1.5, zorder=3)
    for frustum, colour in zip(scene.frusta[:, :, axes], colours):
        apex, corners, tip = frustum[0], frustum[1:5], frustum[5]
        for corner in corners:
            ax.plot(*np.stack([apex, corner]).T, color=colour, lw=0.7, zorder=4)
        ax.plot(*np.vstack([corners, corners[:1]]).T, color=colour, lw=0.7, zorder=4)
        ax.annotate("", xy=tip, xytext=apex, zorder=5,
                    arrowprops=dict(arrowstyle="-|>", color=colour, lw=1.6, shrinkA=0,
                                    shrinkB=0, mutation_scale=10))
    for centre, colour in zip(scene.centres[:, axes], colours):
        ax.plot(*centre, "o", color=colour, ms=DOT_PT, mec="black", mew=0.6, zorder=6)
    return [points, strays]


def place_labels(ax, dots: np.ndarray, texts: list[str], colours: list,
                 avoid: np.ndarray) -> list:
    """Each camera's name as a Text beside its dot (dots: (C, 2) data coordinates), at the
    first offset (LABEL_RADII_PT x LABEL_DIRECTIONS) whose box is inside the axes and clear of
    the labels placed before, of every dot and of the boxes `avoid` ((K, 2, 2): lower and upper
    corners in data coordinates; the frusta); where none is, the offset that overlaps least. A
    label away from its dot gets a leader line. The axes' position and limits must be final."""
    from matplotlib.transforms import Bbox, offset_copy

    figure = ax.figure
    renderer = figure.canvas.get_renderer()
    inside = ax.get_window_extent(renderer)
    to_px = ax.transData.transform
    dot_px = to_px(dots)
    half_dot = 0.5 * DOT_PT * figure.dpi / 72.0 + 1.0
    obstacles = [Bbox.from_extents(x - half_dot, y - half_dot, x + half_dot, y + half_dot)
                 for x, y in dot_px]
    obstacles += [Bbox(to_px(corners)) for corners in avoid]
    placed, out = [], []
    for i, (text, colour) in enumerate(zip(texts, colours)):
        label = ax.text(*dots[i], text, fontsize=LABEL_FONT_PT, color=colour, zorder=7,
                        fontweight="bold",
                        bbox=dict(boxstyle="square,pad=0.1", fc="white", ec="none", alpha=0.75))
        best = None
        for ring, radius in enumerate(LABEL_RADII_PT):
            for k in range(LABEL_DIRECTIONS):
                angle = math.pi / 4 + 2 * math.pi * k / LABEL_DIRECTIONS
                dx, dy = radius * math.cos(angle), radius * math.sin(angle)
                label.set_transform(offset_copy(ax.transData, figure, dx, dy, units="points"))
                label.set_ha("left" if dx > 1e-6 else "right" if dx < -1e-6 else "center")
                label.set_va("bottom" if dy > 1e-6 else "top" if dy < -1e-6 else "center")
                box = label.get_window_extent(renderer).padded(2.0)
                cost = sum(_overlap(box, other) for other in placed + obstacles) + \
                    box.width * box.height - _overlap(box, inside)
                if best is None or cost < best[0]:
                    best = (cost, ring, dx, dy, label.get_ha(), label.get_va(), box)
                if cost == 0:
                    break
            if best[0] == 0:
                break
        _, ring, dx, dy, ha, va, box = best
        label.set_transform(offset_copy(ax.transData, figure, dx, dy, units="points"))
        label.set_ha(ha)
        label.set_va(va)
        placed.append(box)
        if ring:
            end = ax.transData.inverted().transform(dot_px[i] + np.array([dx, dy]) * figure.dpi
                                                    / 72.0)
            ax.plot([dots[i][0], end[0]], [dots[i][1], end[1]], color=colour, lw=0.6, zorder=6)
        out.append(label)
    return out


def _overlap(a, b) -> float:
    """The area (px^2) two boxes share."""
    w = min(a.x1, b.x1) - max(a.x0, b.x0)
    h = min(a.y1, b.y1) - max(a.y0, b.y0)
    return max(w, 0.0) * max(h, 0.0)


def _legend(figure, names: list[str], colours: list, scene: _Scene, against: bool) -> None:
    """The legend, in its column right of the views."""
    from matplotlib.lines import Line2D

    handles = [Line2D([], [], ls="none", marker="o", color=c, ms=DOT_PT, mec="black", mew=0.6,
                      label=short_label(n)) for n, c in zip(names, colours)]
    handles += [Line2D([], [], ls="none", marker="o", color=POINT_GREY, ms=3,
                       label=f"scene points ({len(scene.points)})"),
                Line2D([], [], color="black", lw=1.6, label="optical axis (arrow)"),
                Line2D([], [], color="black", lw=0.7, label="field of view\n(image corners)")]
    if len(scene.strays):
        handles.append(Line2D([], [], ls="none", marker="x", color=STRAY_COLOUR, ms=6,
                              label=f"{len(scene.strays)} stray scene point(s)\nbeyond the "
                                    "view, drawn\nat its edge"))
    if against:
        handles.append(Line2D([], [], ls="none", marker="o", mfc="none", mec=BEFORE_GREY, ms=9,
                              mew=1.5, label="camera in the\nother calibration"))
    figure.legend(handles=handles, loc="upper left", bbox_to_anchor=(LEGEND_LEFT, 0.9),
                  fontsize=9, frameon=True, borderaxespad=0.0)


def render(plot: LayoutPlot) -> np.ndarray:
    """The figure drawn: BGR uint8 (FIGURE_PX[1], FIGURE_PX[0], 3), for cv2.imencode."""
    canvas = plot.figure.canvas
    canvas.draw()
    rgba = np.asarray(canvas.buffer_rgba())
    return np.ascontiguousarray(rgba[:, :, 2::-1])
