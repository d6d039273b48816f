"""Burnt-in info strips found automatically: the bar most trail cameras (and many DVRs) draw along
the top or bottom edge of every image, with the date, time, temperature or camera name in it.

Its glyphs are the same at the same pixels in every camera, so they match each other across
cameras, survive the cycle checks and enter the reconstruction as points that fit no real
geometry, raising the reprojection error and pulling the focals (docs/design-notes.md, Info
strips). Ignoring the bar's rows (core.method.masks) removes them.

A bar is told from the scene by what no scene does at an image edge: rows from the very edge
inward in which most pixels, and those at both ends, have one flat colour (the bar's); among
them rows holding several separate runs of pixels far from it (glyphs); and clean rows of the bar
between its text and the scene (a bar pads its text). A dark night ground, a flat sky or snow
are flat but hold no text; the black border of a fisheye's image circle holds the circle's
scene, one run growing up to where the border ends. With several images of a camera, the bar
must be found in most of them at about one height (it does not move).
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Sequence

import numpy as np

log = logging.getLogger(__name__)

MAX_STRIP_FRACTION = 0.15  # a bar taller than this share of the image is not a bar
MIN_STRIP_FRACTION = 0.012  # nor one lower than this (no text fits)
BAR_TOLERANCE = 14  # 8-bit levels around the bar colour that count as the bar (JPEG noise)
MIN_BAR_SHARE = 0.3  # of a row's pixels on the bar colour (dense bold text covers up to 60 %)
TEXT_CONTRAST = 80  # levels from the bar colour that make a pixel text
MIN_TEXT_ROWS = 0.25  # share of the bar's rows that must hold text
MIN_TEXT_SHARE = 0.005  # share of a row's pixels that are text for the row to hold text
MIN_GLYPHS = 6  # separate runs of text pixels in a row of the bar's text (a few characters)
EDGE_PX = 2  # the bar reaches both image sides: these columns at each end are the bar's
MAX_BAR_DEVIATION = 4  # median levels of the bar's pixels from its colour: drawn flat, not shaded
MARGIN_PX = 4  # ignored beyond the bar's last row (JPEG blurs and rings its edge)
SIDES = ("top", "bottom")


@dataclass(frozen=True)
class InfoStrip:
    side: str  # "top" | "bottom"
    rows: int  # its height [px], margin included

    def mask(self, height: int, width: int) -> np.ndarray:
        """bool (height, width), True on the strip (core.method.masks' convention: ignored)."""
        ignored = np.zeros((height, width), dtype=bool)
        if self.side == "top":
            ignored[:self.rows] = True
        else:
            ignored[height - self.rows:] = True
        return ignored

    def describe(self) -> str:
        return f"{self.rows} px at the {self.side}"


def _grey(image: np.ndarray) -> np.ndarray:
    image = np.asarray(image)
    return image.astype(np.float32) if image.ndim == 2 else \
        image[..., :3].astype(np.float32) @ np.array([0.299, 0.587, 0.114], np.float32)


def strip_rows(image: np.ndarray, side: str) -> int:
    """Height [px] of an info strip along `side` of one image (module docstring), 0 if none."""
    height = np.asarray(image).shape[0]
    limit = int(MAX_STRIP_FRACTION * height)
    edge_rows = image[:limit + 1] if side == "top" else image[::-1][:limit + 1]
    rows = _grey(edge_rows)  # only the rows a strip may take, from the edge inward
    edge = EDGE_PX
    bar = float(np.median(rows[0]))
    n, text_rows, last_text_row, most_glyphs = 0, 0, -1, 0
    while n < limit:
        deviation = np.abs(rows[n] - bar)
        on_bar = deviation <= BAR_TOLERANCE
        if np.mean(on_bar) < MIN_BAR_SHARE or not (on_bar[:edge].all() and on_bar[-edge:].all()) \
                or np.median(deviation[on_bar]) > MAX_BAR_DEVIATION:
            break  # not the bar: too little of it, not edge to edge, or not flat
        text = deviation >= TEXT_CONTRAST
        if np.mean(text) >= MIN_TEXT_SHARE:
            text_rows += 1
            last_text_row = n
            # separate runs of text pixels: glyphs, not one block of scene
            most_glyphs = max(most_glyphs, int(np.count_nonzero(np.diff(text.astype(np.int8))
                                                                == 1)))
        n += 1
    if n >= limit or n < max(2, MIN_STRIP_FRACTION * height):
        return 0  # the whole edge region is flat (sky, night) or too thin for text
    if text_rows < MIN_TEXT_ROWS * n or most_glyphs < MIN_GLYPHS:
        return 0  # no text in it
    if n - 1 - last_text_row < max(1, 0.1 * n):
        return 0  # text up to the scene: a bar pads its text; a fisheye's image circle does not
    return n


def find_info_strip(images: Sequence[np.ndarray]) -> list[InfoStrip]:
    """The info strips of one camera (top, bottom or both) from its images (each (H, W[, 3])
    uint8): each found in at least half of them within a few rows of one height."""
    out = []
    for side in SIDES:
        heights = [strip_rows(image, side) for image in images]
        found = [h for h in heights if h]
        if not found or len(found) * 2 < len(heights):
            continue
        if max(found) - min(found) > max(3, 0.2 * max(found)):
            continue  # a bar keeps its height; flat regions of a changing scene do not
        out.append(InfoStrip(side, max(found) + MARGIN_PX))
    return out


def find_info_strips(frame_sets: Sequence[Sequence[np.ndarray]],
                     camera_names: Sequence[str]) -> dict[str, list[InfoStrip]]:
    """Camera name -> its info strips, for the cameras that have any (frame_sets[t][c])."""
    out = {}
    for c, name in enumerate(camera_names):
        strips = find_info_strip([frames[c] for frames in frame_sets])
        if strips:
            out[name] = strips
    return out


def strips_mask(strips: Sequence[InfoStrip], height: int, width: int) -> np.ndarray:
    """bool (height, width): True on any of the strips."""
    ignored = np.zeros((height, width), dtype=bool)
    for strip in strips:
        ignored |= strip.mask(height, width)
    return ignored
