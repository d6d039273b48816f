"""Where a later frame set shows something the earlier ones did not: only there can it give new
correspondences.

The rig is rigid and its cameras do not move, so what stayed put between frame sets (walls,
floor, furniture) looks the same in each of them, and its matches were found in the first frame
set already: matched again in every later one, the same points come back, re-detected with the
frame's noise, and a keypoint matcher pays for them each time (asift: tens of times sift's
matching time per frame set; docs/design-notes.md, Later frame sets). What a later
frame set adds is what moved into view (a person, an animal, a board carried around) and what it
uncovered. So in frame set t > 0 keypoints are kept only where the image differs from every
earlier frame set of the same camera (a region that differs from one earlier set but not from
another showed this content before); both ends of a new correspondence lie in such regions, as a
scene point that moved changed in every view that sees it. Where nothing is new (a static scene
filmed twice), the frame set adds no matches; where the light changed, it is matched whole.

This assumes the cameras stayed put over the frame sets. A camera bumped in between sees all new,
its partners nothing new, so its later frame sets give it no matches: what judges each frame set
on its own (checks, recalibration) matches them whole (pipeline.match_frame_sets' each_on_its_own).
"""
from __future__ import annotations

from typing import Iterator, Optional, Sequence

import cv2
import numpy as np

from .matching.utils import resize_for_matching, to_gray

# The images are compared at most this large (long side, px), blurred: enough to outline what
# moved, and the earlier frame sets kept for the comparison stay small (uint8).
COMPARE_SIDE_PX = 640
# Blur sigma (px at the compared size): video compression and sensor noise vary pixel by pixel,
# what moved changes whole patches.
BLUR_SIGMA_PX = 2.0
# Grey levels (0-255) a blurred pixel must differ by from every earlier frame set to count as new:
# well above the noise of blurred video frames (a few levels) and well below the contrast of the
# textured things that carry matches.
CHANGE_GREY_LEVELS = 20
# New regions are grown by this fraction of the image's long side: a keypoint's descriptor looks
# at a patch around it (SIFT: about 8x its scale), so features on the edge of what moved, half
# on the unchanged background, are kept.
MARGIN_FRACTION = 0.02


def _small_grey(image: np.ndarray) -> np.ndarray:
    small, _ = resize_for_matching(to_gray(image), COMPARE_SIDE_PX)
    return cv2.GaussianBlur(small, (0, 0), BLUR_SIGMA_PX)


def new_content_regions(frame_sets: Sequence[Sequence[np.ndarray]]
                        ) -> Iterator[list[Optional[np.ndarray]]]:
    """Per frame set (one at a time, as they are matched), per camera bool (H, W) of the image's
    size: where that image shows what no earlier frame set of the camera showed (module
    docstring), or None where the whole image is to be matched (the first frame set; a camera
    whose image size changed)."""
    earlier: dict[int, list[np.ndarray]] = {}
    for t, frames in enumerate(frame_sets):
        row: list[Optional[np.ndarray]] = []
        for c, image in enumerate(frames):
            small = _small_grey(image)
            seen = earlier.setdefault(c, [])
            if t == 0 or any(g.shape != small.shape for g in seen):
                row.append(None)
            else:
                new = np.ones(small.shape, bool)
                for g in seen:
                    new &= cv2.absdiff(small, g) > CHANGE_GREY_LEVELS
                height, width = image.shape[:2]
                margin = max(1, int(round(MARGIN_FRACTION * max(small.shape))))
                kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (2 * margin + 1,) * 2)
                grown = cv2.dilate(new.astype(np.uint8), kernel)
                row.append(cv2.resize(grown, (width, height),
                                      interpolation=cv2.INTER_NEAREST) > 0)
            seen.append(small)
        yield row


def describe(regions: Sequence[Optional[np.ndarray]]) -> str:
    """How much of each camera's image a frame set matches, for the log ("100 %, 23 %, ...")."""
    return ", ".join("100 %" if r is None else f"{100.0 * r.mean():.0f} %" for r in regions)
