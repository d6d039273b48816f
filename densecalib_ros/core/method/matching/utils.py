"""Helpers shared by the matcher backends: input checks, resizing with exact coordinate maps,
one-to-one pair maps.

Coordinates: COLMAP pixels (the centre of the top-left pixel is (0.5, 0.5)). A backend that works
on a resized image of size (w, h) for an original of size (W, H) maps a resized COLMAP coordinate
x_r to the original by x = x_r * (W / w) (per axis): both conventions put the image border at 0,
so the map is a pure scale. OpenCV/XFeat keypoints (pixel centre at 0) get +0.5 first.
"""
from __future__ import annotations

from typing import Optional, Sequence

import cv2
import numpy as np

from ...errors import InputError
from ...parallel import map_threads
from ...types import SiteMatches, SiteMatchSet


def check_images(images: Sequence[np.ndarray]) -> list[np.ndarray]:
    """Validate a frame set: at least two images, each (H, W, 3) uint8 RGB or (H, W) uint8 gray."""
    images = list(images)
    if len(images) < 2:
        raise InputError(f"Matching needs at least two images, got {len(images)}.")
    for c, image in enumerate(images):
        image = np.asarray(image)
        ok_shape = image.ndim == 2 or (image.ndim == 3 and image.shape[2] == 3)
        if not ok_shape or image.dtype != np.uint8 or min(image.shape[:2]) < 16:
            raise InputError(
                f"Image {c} has shape {image.shape} and dtype {image.dtype}: expected (H, W, 3) uint8 RGB "
                "or (H, W) uint8 grayscale, at least 16 px on each side.")
        images[c] = image
    return images


def to_gray(image: np.ndarray) -> np.ndarray:
    """(H, W) uint8 grayscale from (H, W) gray or (H, W, 3) RGB."""
    return image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)


def to_rgb(image: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 RGB from (H, W) gray or (H, W, 3) RGB."""
    return image if image.ndim == 3 else cv2.cvtColor(image, cv2.COLOR_GRAY2RGB)


def resized_size(width: int, height: int, max_side_px: Optional[int],
                 multiple: int = 1) -> tuple[int, int]:
    """(w, h) of the matching resolution: the image scaled so that its longer side is at most
    `max_side_px` (None: no limit), each side then rounded down to a multiple of `multiple`."""
    factor = 1.0 if not max_side_px else min(1.0, max_side_px / max(width, height))
    w = max(multiple, int(round(width * factor)) // multiple * multiple)
    h = max(multiple, int(round(height * factor)) // multiple * multiple)
    return w, h


def resize_for_matching(image: np.ndarray, max_side_px: Optional[int],
                        multiple: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Resize an image for matching.

    Returns (resized image, scale_xy) where scale_xy = float64 (2,) = (W / w, H / h) maps resized
    COLMAP coordinates to original COLMAP coordinates: xy_orig = xy_resized * scale_xy.
    """
    height, width = image.shape[:2]
    w, h = resized_size(width, height, max_side_px, multiple)
    scale_xy = np.array([width / w, height / h], dtype=np.float64)
    if (w, h) == (width, height):
        return image, scale_xy
    interp = cv2.INTER_AREA if w < width and h < height else cv2.INTER_LINEAR
    return cv2.resize(image, (w, h), interpolation=interp), scale_xy


def opencv_to_original(xy_opencv_resized: np.ndarray, scale_xy: np.ndarray) -> np.ndarray:
    """float64 (N, 2) original COLMAP coordinates from (N, 2) OpenCV-convention coordinates
    (pixel centre at 0) in the resized image."""
    return (np.asarray(xy_opencv_resized, dtype=np.float64) + 0.5) * scale_xy


def mutual_pair_maps(src: np.ndarray, dst: np.ndarray, certainty: np.ndarray, num_src: int,
                     num_dst: int) -> tuple[SiteMatches, SiteMatches]:
    """One-to-one maps i -> j and j -> i (exact inverses) from candidate site correspondences.

    src, dst: int (M,) site indices in cameras i and j; certainty: (M,) in [0, 1]. Where several
    candidates share a site (e.g. SIFT keypoints at one location with different orientations), a
    candidate is kept only if it is the most certain one for both of its sites (ties broken by
    order).
    """
    src = np.asarray(src, dtype=np.int64)
    dst = np.asarray(dst, dtype=np.int64)
    certainty = np.clip(np.asarray(certainty, dtype=np.float32), 0.0, 1.0)
    order = np.lexsort((np.arange(len(src)), -certainty))  # most certain first, stable
    s, d, c = src[order], dst[order], certainty[order]
    _, first_src = np.unique(s, return_index=True)
    _, first_dst = np.unique(d, return_index=True)
    keep = np.zeros(len(s), dtype=bool)
    keep[np.intersect1d(first_src, first_dst)] = True
    s, d, c = s[keep], d[keep], c[keep]
    forward = SiteMatches(np.full(num_src, -1, np.int32), np.zeros(num_src, np.float32))
    backward = SiteMatches(np.full(num_dst, -1, np.int32), np.zeros(num_dst, np.float32))
    forward.target[s], forward.certainty[s] = d, c
    backward.target[d], backward.certainty[d] = s, c
    return forward, backward


def match_unordered_pairs(images: Sequence[np.ndarray], sites: Sequence[np.ndarray], match_pair,
                          workers: int = 1, steps=None) -> SiteMatchSet:
    """SiteMatchSet of a detector-based matcher: `match_pair(a, b)` is called once per unordered
    camera pair (a < b) and returns the (a -> b, b -> a) SiteMatches; sites[c] is camera c's site
    table (COLMAP px in the original image). workers > 1: that many pairs at a time in threads
    (for a match_pair whose work releases the GIL, numpy's; each pair's result is its own).
    steps: the frame set's base.Steps, told of each pair done."""
    keys = [(i, j) for i in range(len(images)) for j in range(i + 1, len(images))]
    results = map_threads(lambda ij: match_pair(*ij), keys, max(1, workers),
                          steps.done if steps is not None else None)
    pairs = {}
    for (i, j), (ab, ba) in zip(keys, results):
        pairs[(i, j)], pairs[(j, i)] = ab, ba
    return SiteMatchSet(sites=list(sites), pairs=pairs,
                        image_sizes=[(im.shape[1], im.shape[0]) for im in images])


def resolve_device(device: Optional[str]) -> str:
    """'cuda' when available unless told otherwise; InputError for an unusable device."""
    import torch

    if device is None:
        return "cuda" if torch.cuda.is_available() else "cpu"
    if device not in ("cpu", "cuda") and not str(device).startswith("cuda:"):
        raise InputError(f"Unknown device {device!r}: use 'cpu' or 'cuda'.")
    if str(device).startswith("cuda") and not torch.cuda.is_available():
        raise InputError(f"Device {device!r} requested but CUDA is not available: use device='cpu'.")
    return str(device)
