"""A calibrated rig and its scene points as one PLY file (ASCII), for point-cloud viewers
(CloudCompare, MeshLab, Blender): every camera as a coloured pyramid (apex at its optical
centre, base through the rays of its image corners, open at the base), the scene points of the
saved COLMAP model in their colour in the images (grey for a model saved without colours).
World = the floor frame when the calibration has one (z up), else the rig frame; lengths in
metres when the rig is metric, else in its arbitrary unit (the header's comments say which).
"""
from __future__ import annotations

import math
from typing import Optional

import numpy as np

from ..types import CameraIntrinsics, RigCalibration
from .floor import world_from_rig
from .layout_plot import camera_colours, pixel_rays
from .report import camera_centres_in_rig

POINT_GREY = (128, 128, 128)
PYRAMID_FRACTION = 0.08  # pyramid depth, of the camera positions' extent (or of the scene's)
_MAX_CORNER_ANGLE_RAD = math.radians(80.0)  # wide fisheye corners: the base stays in front


def corner_rays(intrinsics: CameraIntrinsics) -> np.ndarray:
    """(4, 3) unit rays (camera frame) through the image's corners, clockwise from top-left,
    distortion included; rays past 80 deg off the axis (fisheye) are pulled back to 80 deg."""
    w, h = intrinsics.width, intrinsics.height
    return pixel_rays(intrinsics, np.array([[0.0, 0.0], [w, 0.0], [w, h], [0.0, h]]),
                      _MAX_CORNER_ANGLE_RAD)


def scene_ply(rig: RigCalibration, points_rig: Optional[np.ndarray] = None,
              point_colours: Optional[np.ndarray] = None) -> str:
    """The PLY text (module docstring) of the rig and optional rig-frame scene points (N, 3),
    coloured by point_colours (N, 3) RGB uint8 if given, else grey."""
    world_from_rig_, world = world_from_rig(rig)
    rotation, shift = world_from_rig_[:3, :3], world_from_rig_[:3, 3]
    points, point_rgb = np.zeros((0, 3)), np.zeros((0, 3), np.uint8)
    if points_rig is not None and len(points_rig):
        points = np.asarray(points_rig, np.float64).reshape(-1, 3)
        point_rgb = (np.full((len(points), 3), POINT_GREY, np.uint8) if point_colours is None
                     else np.asarray(point_colours, np.uint8).reshape(-1, 3))
        finite = np.isfinite(points).all(1)
        points, point_rgb = points[finite] @ rotation.T + shift, point_rgb[finite]
    names = list(rig.cameras)
    centres = np.array(list(camera_centres_in_rig(rig).values())) @ rotation.T + shift
    rig_from_cams = [np.asarray(rig.cameras[n].cam_from_rig, np.float64)[:3, :3].T for n in names]
    extent = float(np.ptp(centres, axis=0).max()) if len(centres) > 1 else 0.0
    if extent <= 0 and len(points):
        extent = float(np.ptp(np.percentile(points, [5, 95], axis=0), axis=0).max())
    depth = PYRAMID_FRACTION * (extent if extent > 0 else 1.0)
    vertices, colours, faces = [], [], []
    for i, (name, colour) in enumerate(zip(names, camera_colours(len(names)))):
        rgb = colour[::-1]  # camera_colours gives BGR
        base = len(vertices)
        rays = corner_rays(rig.cameras[name].intrinsics)
        corner_depths = depth / rays[:, 2]  # the base at `depth` along the optical axis
        corners = centres[i] + (rotation @ rig_from_cams[i] @ (rays * corner_depths[:, None]).T).T
        vertices += [centres[i], *corners]
        colours += [rgb] * 5
        faces += [(base, base + 1 + k, base + 1 + (k + 1) % 4) for k in range(4)]
    vertices = np.round(np.array(vertices + list(points)).reshape(-1, 3), 9) + 0.0  # no -0, 1e-33
    colours += [tuple(int(v) for v in rgb) for rgb in point_rgb]
    units = "metres" if rig.metric_scale else "arbitrary units (no metric scale)"
    header = ["ply", "format ascii 1.0",
              f"comment densecalib rig calibration; world = {world}; lengths in {units}",
              "comment cameras (pyramids, apex = optical centre, vertices 5i..5i+4): "
              + ", ".join(names),
              f"element vertex {len(vertices)}", "property double x", "property double y",
              "property double z", "property uchar red", "property uchar green",
              "property uchar blue", f"element face {len(faces)}",
              "property list uchar int vertex_indices", "end_header"]
    body = [f"{x:.9g} {y:.9g} {z:.9g} {r} {g} {b}"
            for (x, y, z), (r, g, b) in zip(vertices, colours)]
    body += [f"3 {a} {b} {c}" for a, b, c in faces]
    return "\n".join(header + body) + "\n"
