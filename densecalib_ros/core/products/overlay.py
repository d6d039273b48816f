"""Reprojection residuals drawn on a camera's image: where the calibration's points are, and how
well each camera's model explains them (a visual check a table of RMS values cannot give: a corner
with no points, or residuals that grow toward the border, which points at the lens model).

Works on the COLMAP model a calibration writes (OUT/colmap): image = camera name, its keypoints and
the 3D points they observe. Pixels are returned in the OpenCV convention (pixel centres at
integers; COLMAP's are at +0.5).
"""
from __future__ import annotations

import cv2
import numpy as np
import pycolmap

from ..errors import InputError

# Residual colour bands [px] (RGB): within 1 px green, within 3 px yellow, beyond red.
BANDS_PX = ((1.0, (40, 200, 40)), (3.0, (240, 200, 0)), (np.inf, (230, 30, 30)))


def camera_residuals(rec: pycolmap.Reconstruction, camera_name: str
                     ) -> tuple[np.ndarray, np.ndarray]:
    """(observed, reprojected) pixel positions (N, 2) of the keypoints of `camera_name`'s image that
    observe a 3D point."""
    image = next((im for im in rec.images.values() if im.name == camera_name), None)
    if image is None:
        raise InputError(f"The COLMAP model has no image of camera {camera_name!r}: it has "
                         f"{', '.join(sorted(im.name for im in rec.images.values()))}.")
    obs = [(p2.xy, rec.point3D(p2.point3D_id).xyz) for p2 in image.points2D if p2.has_point3D()]
    if not obs:
        return np.zeros((0, 2)), np.zeros((0, 2))
    xy = np.array([o[0] for o in obs], float)
    xyz_world = np.array([o[1] for o in obs], float)
    cam_from_world = image.cam_from_world().matrix()
    xyz_cam = xyz_world @ cam_from_world[:, :3].T + cam_from_world[:, 3]
    proj = rec.camera(image.camera_id).img_from_cam(xyz_cam)
    return xy - 0.5, np.asarray(proj, float) - 0.5


def draw_residuals(image_rgb: np.ndarray, observed: np.ndarray, reprojected: np.ndarray,
                   scale: float = 10.0, title: str = "") -> np.ndarray:
    """A copy of image_rgb with each observation as a dot coloured by its residual band and a line
    toward its reprojection, `scale` times the residual; a legend line at the top."""
    out = np.ascontiguousarray(image_rgb.copy() if image_rgb.ndim == 3 else
                               np.repeat(image_rgb[..., None], 3, axis=2))
    err = np.linalg.norm(reprojected - observed, axis=1)
    shift = 4  # sub-pixel drawing: coordinates in 1/16 px
    for (x, y), (px, py), e in zip(observed, reprojected, err):
        colour = next(c for limit, c in BANDS_PX if e <= limit)
        start = (int(round(x * 16)), int(round(y * 16)))
        end = (int(round((x + scale * (px - x)) * 16)), int(round((y + scale * (py - y)) * 16)))
        cv2.line(out, start, end, colour, 1, cv2.LINE_AA, shift)
        cv2.circle(out, start, 2 * 16, colour, -1, cv2.LINE_AA, shift)
    if len(err):
        stats = (f"{len(err)} points, residual median {np.median(err):.2f} px, 90% "
                 f"{np.percentile(err, 90):.2f} px; lines x{scale:g}; green <1 px, yellow <3, red")
    else:
        stats = "no points"
    text = f"{title}: {stats}" if title else stats
    font_scale = max(0.4, out.shape[1] / 2400)
    (w, h), base = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, font_scale, 1)
    cv2.rectangle(out, (0, 0), (w + 8, h + base + 8), (0, 0, 0), -1)
    cv2.putText(out, text, (4, h + 4), cv2.FONT_HERSHEY_SIMPLEX, font_scale, (255, 255, 255), 1,
                cv2.LINE_AA)
    return out
