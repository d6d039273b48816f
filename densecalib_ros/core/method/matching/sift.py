"""OpenCV SIFT with Lowe's ratio test and a mutual nearest-neighbour check (no torch).

root_sift=True compares RootSIFT descriptors (L1-normalised, element-wise square root: Euclidean
distance then compares them by the Hellinger kernel, Arandjelovic & Zisserman 2012; COLMAP's
default). It gives better matches, but end to end it measured worse: on weakly connected rigs
small input changes flip the outcome (a different sampling seed does too; see
core/robust/consensus.py), so one bench run cannot show a match-quality gain there. Opt-in for
now (docs/design-notes.md, SIFT RootSIFT option).

Sites are keypoint locations; OpenCV returns several keypoints at one location (one per dominant
orientation), which are merged into one site whose descriptor distance to another site is the
smallest over their keypoints. The ratio test compares the nearest and second-nearest *site*,
so orientation duplicates do not reject each other. (j, i) is the exact inverse of (i, j).
"""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from typing import Optional

import cv2
import numpy as np

from ...errors import InputError
from ...parallel import available_cores
from ...types import SiteMatchSet
from .base import Matcher
from .utils import (match_unordered_pairs, mutual_pair_maps, opencv_to_original,
                    resize_for_matching, to_gray)

# Row sites per block of the distance matrix, so that a pair's memory does not grow with the
# square of the keypoints: with asift's ~40k keypoints per image a block and its working copies
# take ~300 MB per pair at 512 (~600 MB at 1024, in the same time; 256 is slower).
BLOCK_SITES = 512


def _site_layout(site: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(each site's first keypoint, in site order; the other keypoints, by site; their sites)."""
    order = np.argsort(site, kind="stable")
    sorted_site = site[order]
    first = np.r_[True, sorted_site[1:] != sorted_site[:-1]]
    return order[first], order[~first], sorted_site[~first]


def _rank_within_site(sorted_site: np.ndarray) -> np.ndarray:
    """0, 1, 2 ... along each run of equal values of a sorted array."""
    return np.arange(len(sorted_site)) - np.searchsorted(sorted_site, sorted_site)


def _columns(desc_c: np.ndarray, site_c: np.ndarray, n_c: int
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The column side of the distance matrix: (descriptors, first keypoint of every site then
    the others, each extended by 1 and its squared norm (_site_blocks); each column's site;
    every site's columns (n_c, width), padded with its first)."""
    firsts_c, extras_c, extra_site_c = _site_layout(site_c)
    desc_cols = desc_c[np.concatenate([firsts_c, extras_c])]
    col_site = np.concatenate([np.arange(n_c), extra_site_c])
    width = 1 + int(np.bincount(extra_site_c, minlength=n_c).max(initial=0))
    site_cols = np.repeat(np.arange(n_c)[:, None], width, axis=1)
    site_cols[extra_site_c, 1 + _rank_within_site(extra_site_c)] = n_c + np.arange(len(extras_c))
    cols = np.empty((len(desc_cols), desc_cols.shape[1] + 2), np.float32)
    cols[:, :-2] = desc_cols
    cols[:, -2] = 1.0
    cols[:, -1] = np.einsum("ij,ij->i", desc_cols, desc_cols)
    return cols, col_site, site_cols


def _site_blocks(desc_r: np.ndarray, site_r: np.ndarray, n_r: int, cols: np.ndarray):
    """Yield (s0, s1, d2): the squared distances (s1 - s0, columns) of row sites s0..s1 to every
    column keypoint (cols: _columns), BLOCK_SITES row sites at a time, a site's further keypoints
    folded into its row (contiguous row operations; the block is the memory peak).

    |r - c|^2 = -2 r.c + |r|^2 + |c|^2 is one matrix product of rows (-2 r, |r|^2, 1) with
    columns (c, 1, |c|^2): three passes over the block fewer than adding the norms after it
    (a fifth of a pair's time). OpenCV's SIFT descriptors are integers scaled to a norm of about
    512, so every partial sum is an integer below 2^21, exact in float32 in any order: the same
    distances as before (RootSIFT's differ in the last bits)."""
    firsts_r, extras_r, extra_site_r = _site_layout(site_r)
    for s0 in range(0, n_r, BLOCK_SITES):
        s1 = min(n_r, s0 + BLOCK_SITES)
        lo, hi = np.searchsorted(extra_site_r, [s0, s1])
        desc_rows = desc_r[np.concatenate([firsts_r[s0:s1], extras_r[lo:hi]])]
        rows = np.empty((len(desc_rows), desc_rows.shape[1] + 2), np.float32)
        np.multiply(desc_rows, -2.0, out=rows[:, :-2])
        rows[:, -2] = np.einsum("ij,ij->i", desc_rows, desc_rows)
        rows[:, -1] = 1.0
        d2 = rows @ cols.T
        extra_rows_site = extra_site_r[lo:hi] - s0
        rank = _rank_within_site(extra_rows_site)
        for r in range(int(rank.max(initial=-1)) + 1):  # one keypoint per site at a time
            k = np.flatnonzero(rank == r)
            d2[extra_rows_site[k]] = np.minimum(d2[extra_rows_site[k]], d2[s1 - s0 + k])
        yield s0, s1, d2[:s1 - s0]


def _nearest_column_sites(d2: np.ndarray, col_site: np.ndarray, site_cols: np.ndarray
                          ) -> tuple[np.ndarray, np.ndarray]:
    """Per row of a block: the nearest column site and the distance ratio to the next; the
    nearest site's columns are set to infinity in d2 on the way (numpy reduces fast along rows
    only, so the columns are not folded)."""
    rows = np.arange(len(d2))
    nearest_col = np.argmin(d2, axis=1)
    nearest_d2 = d2[rows, nearest_col].copy()
    best = col_site[nearest_col]
    d2[rows[:, None], site_cols[best]] = np.inf
    return best, np.sqrt(np.maximum(nearest_d2, 0.0) / np.maximum(d2.min(axis=1), 1e-12))


def nearest_sites_both_ways(desc_a: np.ndarray, site_a: np.ndarray, n_a: int,
                            desc_b: np.ndarray, site_b: np.ndarray, n_b: int
                            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(best_ab, ratio_ab, best_ba, ratio_ba): for each site of a the nearest site of b (int64
    (n_a,)) and the ratio of the distances to the nearest and second-nearest site of b (float32
    (n_a,)), and the same from b to a; a site's distance to another is the smallest over their
    keypoints (module docstring). desc_*: float32 (K, 128) keypoint descriptors; site_*: int64
    (K,) each keypoint's site.

    One distance matrix, in blocks of BLOCK_SITES sites of a (_site_blocks), serves both
    directions: a -> b reduces the block's rows (the nearest column keypoint gives the nearest
    site, whose columns are set to infinity before the second-nearest is taken); b -> a keeps,
    per keypoint of b, its nearest a site and its distance to the second-nearest (numpy reduces
    along columns fast where no index is needed), and b's keypoints are folded into their sites
    at the end. Half the arithmetic of one matrix per direction, and both directions see the
    same distances."""
    cols, col_site, site_cols = _columns(desc_b, site_b, n_b)
    best_ab = np.empty(n_a, np.int64)
    ratio_ab = np.empty(n_a, np.float32)
    # per column keypoint of b: nearest a site, its distance, the distance to the next a site
    col_d1 = np.full(len(cols), np.inf, np.float32)
    col_d2 = np.full(len(cols), np.inf, np.float32)
    col_best = np.zeros(len(cols), np.int64)
    for s0, s1, d2 in _site_blocks(desc_a, site_a, n_a, cols):
        # b -> a, merged in per column: where this block holds a nearer a site, that site and
        # the next (taken on those columns only: numpy finds indices along rows fast only);
        # elsewhere its nearest is a candidate for the second
        near = d2.min(axis=0)
        closer = np.flatnonzero(near < col_d1)
        col_d2 = np.minimum(col_d2, near)
        if len(closer):
            sub = np.ascontiguousarray(d2[:, closer].T)
            first = np.argmin(sub, axis=1)
            sub[np.arange(len(closer)), first] = np.inf
            col_d2[closer] = np.minimum(col_d1[closer], sub.min(axis=1))
            col_best[closer] = s0 + first
            col_d1[closer] = near[closer]
        best_ab[s0:s1], ratio_ab[s0:s1] = _nearest_column_sites(d2, col_site, site_cols)
    # fold b's keypoints into their sites: the nearest a site over a site's keypoints, and the
    # nearest other a site: a keypoint's own second where its nearest is that site, else its
    # nearest
    which = np.argmin(col_d1[site_cols], axis=1)
    chosen_col = site_cols[np.arange(n_b), which]
    best_ba = col_best[chosen_col]
    nearest_ba = col_d1[chosen_col]
    other = np.where(col_best[site_cols] == best_ba[:, None], col_d2[site_cols],
                     col_d1[site_cols]).min(axis=1)
    ratio_ba = np.sqrt(np.maximum(nearest_ba, 0.0) / np.maximum(other, 1e-12)).astype(np.float32)
    return best_ab, ratio_ab, best_ba, ratio_ba


class SiftMatcher(Matcher):
    name = "sift"

    def __init__(self, max_image_side_px: Optional[int] = 1024, max_keypoints: int = 8000,
                 ratio_threshold: float = 0.8, contrast_threshold: float = 0.04,
                 root_sift: bool = False, device: Optional[str] = None):
        """max_keypoints: SIFT nfeatures per image; ratio_threshold: Lowe ratio (nearest /
        second-nearest site distance) below which a match is kept, applied in both directions.
        root_sift: compare RootSIFT descriptors instead of OpenCV's raw ones.
        device: only None or 'cpu' (OpenCV SIFT runs on the CPU)."""
        super().__init__(max_image_side_px)
        if device not in (None, "cpu"):
            raise InputError(f"Matcher 'sift' runs on the CPU only; got device={device!r}.")
        if not 0.0 < ratio_threshold <= 1.0:
            raise InputError(f"ratio_threshold must be in (0, 1], got {ratio_threshold}.")
        self.max_keypoints = int(max_keypoints)
        self.ratio_threshold = float(ratio_threshold)
        self.contrast_threshold = float(contrast_threshold)
        self.root_sift = bool(root_sift)

    def _features(self, image: np.ndarray, region: Optional[np.ndarray] = None
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Returns sites float64 (S, 2) original COLMAP px, keypoint site index int64 (K,),
        descriptors float32 (K, 128); keypoints only where `region` (bool, the image's size) is
        True, if given."""
        gray, scale_xy = resize_for_matching(to_gray(image), self.max_image_side_px)
        mask = None
        if region is not None:
            mask = cv2.resize(region.astype(np.uint8) * 255, gray.shape[::-1],
                              interpolation=cv2.INTER_NEAREST)
        keypoints, descriptors = self._detector().detectAndCompute(gray, mask)
        if not keypoints:
            return np.zeros((0, 2)), np.zeros(0, np.int64), np.zeros((0, 128), np.float32)
        xy = np.array([k.pt for k in keypoints], dtype=np.float64)
        # Within the image (asift maps keypoints of its tilted views back slightly beyond it).
        inside = np.all((xy >= -0.5) & (xy <= np.array(gray.shape[1::-1]) - 0.5), axis=1)
        xy, descriptors = xy[inside], descriptors[inside]
        unique_xy, site_of_kp = np.unique(xy, axis=0, return_inverse=True)
        descriptors = descriptors.astype(np.float32)
        if self.root_sift:  # SIFT descriptors are non-negative
            descriptors = np.sqrt(descriptors / np.maximum(
                descriptors.sum(axis=1, keepdims=True), 1e-12))
        return (opencv_to_original(unique_xy, scale_xy), site_of_kp.reshape(-1).astype(np.int64),
                descriptors)

    def _detector(self):
        return cv2.SIFT_create(nfeatures=self.max_keypoints,
                               contrastThreshold=self.contrast_threshold)

    def _match_pair(self, fa, fb):
        n_a, n_b = len(fa[0]), len(fb[0])
        if n_a < 2 or n_b < 2:
            empty = np.zeros(0, np.int64)
            return mutual_pair_maps(empty, empty, np.zeros(0), n_a, n_b)
        (_, site_a, desc_a), (_, site_b, desc_b) = fa, fb
        best_ab, ratio_ab, best_ba, ratio_ba = nearest_sites_both_ways(desc_a, site_a, n_a,
                                                                       desc_b, site_b, n_b)
        src = np.arange(n_a)
        keep = ((best_ba[best_ab] == src) & (ratio_ab < self.ratio_threshold)
                & (ratio_ba[best_ab] < self.ratio_threshold))
        src, dst = src[keep], best_ab[keep]
        certainty = 1.0 - np.maximum(ratio_ab[src], ratio_ba[dst])
        return mutual_pair_maps(src, dst, certainty, n_a, n_b)

    detects_in_regions = True

    def _match(self, images: list[np.ndarray],
               regions: Optional[list[Optional[np.ndarray]]] = None) -> SiteMatchSet:
        # OpenCV's SIFT leaves most of its work on one core and releases the GIL: one image per
        # core (the same features as one after another); the pairs' distance matrices likewise
        # (numpy's reductions run on one core, outside the GIL).
        cores = available_cores()
        regions = regions or [None] * len(images)
        with ThreadPoolExecutor(min(len(images), cores)) as pool:
            feats = list(pool.map(self._features, images, regions))
        return match_unordered_pairs(images, [f[0] for f in feats],
                                     lambda i, j: self._match_pair(feats[i], feats[j]), cores)


class AsiftMatcher(SiftMatcher):
    """SIFT on affine-simulated views of each image (ASIFT, Morel & Yu 2009, as OpenCV's
    AffineFeature: the image tilted by up to 5x in several directions), so that a surface seen
    from viewpoints 45-80 deg apart still has keypoints whose descriptors agree. Matched as
    `sift` is (sites, ratio test, mutual check); max_keypoints is per simulated view (about 40
    views: ~20 times the keypoints of `sift`, and its matching time)."""

    name = "asift"

    def __init__(self, max_image_side_px: Optional[int] = 1024, max_keypoints: int = 1000,
                 ratio_threshold: float = 0.8, contrast_threshold: float = 0.04,
                 root_sift: bool = False, device: Optional[str] = None):
        super().__init__(max_image_side_px, max_keypoints, ratio_threshold, contrast_threshold,
                         root_sift, device)

    def _detector(self):
        return cv2.AffineFeature_create(super()._detector())
