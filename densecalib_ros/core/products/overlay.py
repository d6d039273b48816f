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
LEGEND_MIN_FONT = 0.3  # cv2 font scale: about 7 px letters, the smallest still legible
LEGEND_PAD_PX = 4  # around and between the legend's lines and swatches
LEGEND_SHADE = 0.35  # the image under the legend, darkened to this: white letters stand out


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
    """A copy of image_rgb (RGB, or grey; same size) with each observation as a dot coloured by
    its residual band and a line toward its reprojection, `scale` times the residual, and a
    legend (legend_lines, wrapped to the image's width: legend_band) across the top or the
    bottom, whichever covers fewer observations, over the image darkened beneath it."""
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
    band = legend_band(legend_lines(err, scale, title), out.shape[1])[:out.shape[0]]
    height = len(band)
    at_top = (observed[:, 1] < height).sum() <= (observed[:, 1] >= out.shape[0] - height).sum()
    rows = slice(0, height) if at_top else slice(out.shape[0] - height, out.shape[0])
    ink = band.any(axis=2)
    out[rows] = np.where(ink[..., None], band, (LEGEND_SHADE * out[rows]).astype(np.uint8))
    return out


def legend_lines(err: np.ndarray, scale: float, title: str = "") -> list[list[tuple]]:
    """The legend's words, as lines of (text, swatch colour or None) pieces: the numbers, then
    the colour key."""
    if len(err):
        stats = (f"{len(err)} points, residual median {np.median(err):.2f} px, 90% "
                 f"{np.percentile(err, 90):.2f} px, lines x{scale:g}")
    else:
        stats = "no points"
    key = [("dots:", None)]
    for (_, colour), text in zip(BANDS_PX, ("< 1 px,", "< 3 px,", "beyond")):
        key.append((text, colour))
    return [[(f"{title}: {stats}" if title else stats, None)], key]


def legend_band(lines: list[list[tuple]], width: int) -> np.ndarray:
    """A black RGB band `width` wide holding the legend lines in white, each piece with its
    colour swatch before it, words wrapped to the width (never cut off: the font shrinks, down
    to LEGEND_MIN_FONT, until the longest word fits)."""
    font = cv2.FONT_HERSHEY_SIMPLEX
    words = [[(w, colour if i == 0 else None) for text, colour in line
              for i, w in enumerate(text.split())] for line in lines]
    longest = max((w for line in words for w, _ in line), key=len, default="")
    font_scale = max(LEGEND_MIN_FONT, width / 2400)
    while font_scale > LEGEND_MIN_FONT and \
            cv2.getTextSize(longest, font, font_scale, 1)[0][0] + 3 * LEGEND_PAD_PX > width:
        font_scale = max(LEGEND_MIN_FONT, 0.9 * font_scale)
    (_, text_h), base = cv2.getTextSize("Ag", font, font_scale, 1)
    line_h = text_h + base + LEGEND_PAD_PX
    placed, x, y = [], LEGEND_PAD_PX, LEGEND_PAD_PX + text_h
    for line in words:
        for word, colour in line:
            word_w = cv2.getTextSize(word, font, font_scale, 1)[0][0] + \
                (text_h + LEGEND_PAD_PX if colour is not None else 0)
            if x > LEGEND_PAD_PX and x + word_w > width - LEGEND_PAD_PX:
                x, y = LEGEND_PAD_PX, y + line_h
            placed.append((word, colour, x, y))
            x += word_w + cv2.getTextSize(" ", font, font_scale, 1)[0][0]
        x, y = LEGEND_PAD_PX, y + line_h
    band = np.zeros((y - text_h, width, 3), np.uint8)
    for word, colour, x, y in placed:
        if colour is not None:
            cv2.rectangle(band, (x, y - text_h), (x + text_h, y), colour, -1)
            x += text_h + LEGEND_PAD_PX
        cv2.putText(band, word, (x, y), font, font_scale, (255, 255, 255), 1, cv2.LINE_AA)
    return band
