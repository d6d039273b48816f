"""Image masks: regions of a camera's image whose matches are not used.

What a camera sees that is not the scene: a trail camera's burnt-in info strip (date, temperature;
the same glyphs at the same place in every camera, which match each other across cameras and
survive the cycle checks), the rig's own structure in a fisheye's view, a lens hood, a moving
arm. COLMAP's convention: a mask is an image of the camera's size, black (< 128) where features
are ignored. Every match with an end in a masked region is dropped, in both directions, right
after matching, so the sampling, SfM and all-match refinement never see it.
"""
from __future__ import annotations

import logging
import os
from typing import Optional, Sequence

import cv2
import numpy as np

from ..config import PipelineConfig
from ..errors import InputError
from ..io.image_io import decode_file_bytes, read_file_bytes
from ..types import SiteMatchSet
from .sampling import refined_targets_px

log = logging.getLogger(__name__)


def read_mask(path: str | os.PathLike) -> np.ndarray:
    """bool (H, W), True where the mask image at `path` is black (< 128): ignored pixels."""
    gray = decode_file_bytes(read_file_bytes(path, "mask"), cv2.IMREAD_GRAYSCALE)
    if gray is None or gray.size == 0:
        raise InputError(f"Cannot read mask {path}: give an image file (black = ignore, white = "
                         "use) of the camera's size.")
    ignored = gray < 128
    if ignored.all():
        raise InputError(f"Mask {path} is black everywhere: it would ignore the whole image "
                         "(black = ignore, white = use).")
    return ignored


def _ignored_at(ignored: np.ndarray, xy_px: np.ndarray) -> np.ndarray:
    """Which COLMAP pixel positions (N, 2) fall on ignored pixels (NaN positions: False)."""
    out = np.zeros(len(xy_px), dtype=bool)
    ok = np.isfinite(xy_px).all(1)
    h, w = ignored.shape
    col = np.clip(np.floor(xy_px[ok, 0]).astype(int), 0, w - 1)
    row = np.clip(np.floor(xy_px[ok, 1]).astype(int), 0, h - 1)
    out[ok] = ignored[row, col]
    return out


def check_masks(masks: dict, camera_names: Sequence[str],
                image_sizes: Sequence[tuple[int, int]]) -> list[Optional[np.ndarray]]:
    """Per camera index its ignore mask or None, from {camera name: mask}; InputError for unknown
    cameras or a mask whose size is not the camera's (width, height)."""
    unknown = sorted(set(masks) - set(camera_names))
    if unknown:
        raise InputError(f"Masks for unknown camera(s) {', '.join(unknown)}: the cameras are "
                         f"{', '.join(camera_names)}.")
    out = []
    for name, (w, h) in zip(camera_names, image_sizes):
        mask = masks.get(name)
        if mask is not None and mask.shape != (h, w):
            raise InputError(f"The mask of camera {name} is {mask.shape[1]}x{mask.shape[0]}, its "
                             f"images {w}x{h}: make the mask the images' size.")
        out.append(mask)
    return out


def apply_masks(match_set: SiteMatchSet, ignored: Sequence[Optional[np.ndarray]]) -> int:
    """Drop (in place) every match of match_set with an end on an ignored pixel; returns how many
    were dropped."""
    if not any(m is not None for m in ignored):
        return 0
    site_ignored = [_ignored_at(m, s) if m is not None else np.zeros(len(s), dtype=bool)
                    for m, s in zip(ignored, match_set.sites)]
    dropped = 0
    for (i, j), pm in match_set.pairs.items():
        valid = pm.target >= 0
        drop = site_ignored[i] & valid
        if ignored[j] is not None:
            end = np.full((len(pm.target), 2), np.nan)
            rows = np.flatnonzero(valid)
            end[rows] = refined_targets_px(match_set, i, j, rows, pm.target[rows])
            on_site = site_ignored[j][np.maximum(pm.target, 0)]
            drop |= valid & (_ignored_at(ignored[j], end) | on_site)
        pm.target[drop] = -1
        pm.certainty[drop] = 0.0
        if pm.target_xy_px is not None:
            pm.target_xy_px[drop] = np.nan
        dropped += int(drop.sum())
    return dropped


def info_strips(frame_sets: Sequence[Sequence[np.ndarray]],
                camera_names: Optional[Sequence[str]], config: PipelineConfig) -> dict:
    """Camera name -> the info strips (core.method.info_strip) found in its images, for the cameras
    without a mask of the user's; {} when config.detect_info_strips is off."""
    from .info_strip import find_info_strips

    if not config.detect_info_strips or camera_names is None or not frame_sets:
        return {}
    found = find_info_strips(frame_sets, camera_names)
    return {n: strips for n, strips in found.items() if n not in config.cameras.masks}


def _info_strip_masks(strips: dict, frame_sets: Sequence[Sequence[np.ndarray]],
                      camera_names: Sequence[str]) -> dict:
    """Camera name -> bool mask of its info strips (info_strips), for core.method.masks."""
    from .info_strip import strips_mask

    masks = {}
    for name, found in strips.items():
        height, width = frame_sets[0][list(camera_names).index(name)].shape[:2]
        masks[name] = strips_mask(found, height, width)
        log.info("camera %s: its info strip (%s) is ignored", name,
                 ", ".join(s.describe() for s in found))
    return masks


def ignored_regions(frame_sets: Sequence[Sequence[np.ndarray]],
                    camera_names: Optional[Sequence[str]], config: PipelineConfig,
                    strips: dict) -> list:
    """Per camera its bool (H, W) mask of what no match may use (the user's config.cameras.masks,
    else the info strips found), or None; [] when no camera has one."""
    masks = {**_info_strip_masks(strips, frame_sets, camera_names), **config.cameras.masks}
    if not masks:
        return []
    if camera_names is None:
        raise ValueError("camera_masks need the camera names")
    sizes = [(int(im.shape[1]), int(im.shape[0])) for im in frame_sets[0]]
    return check_masks(masks, camera_names, sizes)
