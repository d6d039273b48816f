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

import contextlib
from typing import Callable, Optional

import cv2
import numpy as np
from threadpoolctl import threadpool_limits

from ...compiled import compiled
from ...errors import InputError
from ...parallel import available_cores, map_threads
from ...types import SiteMatchSet
from .base import Matcher, Steps
from .descriptor_products import (Product, integer_descriptors, norm_parts, numpy_product,
                                  onednn_product_for, onednn_products)
from .utils import (match_unordered_pairs, mutual_pair_maps, opencv_to_original,
                    resize_for_matching, to_gray)

# The distance matrix is computed and reduced one tile at a time, BLOCK_SITES row sites (with
# their further keypoints) by TILE_COLUMNS column keypoints: ~10 MB, which stays in the shared
# last-level cache from the product to the one pass that reduces it (nearest_sites_in_tile), and
# large enough that the per-tile Python calls stay a few percent of the product.
BLOCK_SITES = 512
TILE_COLUMNS = 4096
# Where keypoints are wanted in a region only (a later frame set's new content), the image is
# detected on the region's bounding box grown by this fraction of the detected image's long
# side: the window SIFT's descriptor reads around a keypoint (about 5.3 times its size) for
# keypoints up to 16 px at 1024 px (95 % of asift's there), 85 px; keypoints scale with the
# image. The scale spaces (most of asift's time) then cover the box, not the whole image;
# keypoints near the box's edge may differ in the last subpixel.
REGION_MARGIN_FRACTION = 0.083


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
    the others, each extended by ones and its squared norm's parts (_row_blocks); each column's
    site; every site's columns (n_c, width), padded with its first)."""
    firsts_c, extras_c, extra_site_c = _site_layout(site_c)
    desc_cols = desc_c[np.concatenate([firsts_c, extras_c])]
    col_site = np.concatenate([np.arange(n_c), extra_site_c])
    width = 1 + int(np.bincount(extra_site_c, minlength=n_c).max(initial=0))
    site_cols = np.repeat(np.arange(n_c)[:, None], width, axis=1)
    site_cols[extra_site_c, 1 + _rank_within_site(extra_site_c)] = n_c + np.arange(len(extras_c))
    cols = np.empty((len(desc_cols), desc_cols.shape[1] + 6), np.float32)
    cols[:, :-6] = desc_cols
    cols[:, -6:-3] = 1.0
    cols[:, -3:] = norm_parts(np.einsum("ij,ij->i", desc_cols, desc_cols))
    return cols, col_site, site_cols


def _row_blocks(desc_r: np.ndarray, site_r: np.ndarray, n_r: int):
    """Yield (s0, s1, rows, row_site): the row side of the distance matrix for row sites s0..s1,
    BLOCK_SITES at a time: each site's first keypoint then the block's other keypoints, as
    (-2 r, |r|^2, 1); row_site: each row's site less s0 (int32).

    |r - c|^2 = -2 r.c + |r|^2 + |c|^2 is one matrix product of these rows with the columns
    (c, 1, |c|^2) (_columns): three passes over the tile fewer than adding the norms after it.
    Each norm is given as three parts (descriptor_products.norm_parts, with three ones opposite),
    which a bfloat16 product holds exactly.
    OpenCV's SIFT descriptors are integers scaled to a norm of about 512, so every partial sum
    is an integer below 2^21, exact in float32 in any order and any tiling: the same distances
    whatever the blocks and whichever product (RootSIFT's differ in the last bits)."""
    firsts_r, extras_r, extra_site_r = _site_layout(site_r)
    for s0 in range(0, n_r, BLOCK_SITES):
        s1 = min(n_r, s0 + BLOCK_SITES)
        lo, hi = np.searchsorted(extra_site_r, [s0, s1])
        desc_rows = desc_r[np.concatenate([firsts_r[s0:s1], extras_r[lo:hi]])]
        rows = np.empty((len(desc_rows), desc_rows.shape[1] + 6), np.float32)
        np.multiply(desc_rows, -2.0, out=rows[:, :-6])
        rows[:, -6:-3] = norm_parts(np.einsum("ij,ij->i", desc_rows, desc_rows))
        rows[:, -3:] = 1.0
        row_site = np.concatenate([np.arange(s1 - s0), extra_site_r[lo:hi] - s0])
        yield s0, s1, rows, row_site.astype(np.int32)


@compiled()
def nearest_sites_in_tile(tile, scale, row_terms, col_terms, row_site, col_site, s0, c0,
                          d1, d1_col, d2, col_d1, col_d2, col_best, dist, worst
                          ):  # pragma: no cover - compiled
    """Merge one tile of the distance matrix (rows of sites s0.. by the columns c0..) into the
    running nearest sites both ways (nearest_sites_both_ways), in one pass over the tile.

    Each row's distances (row_terms[i] + col_terms[c0 + j] + scale x tile[i, j], into dist: int32
    where they are integers, whose min passes vectorise) give the tile's nearest column and the
    nearest column of another site; merged into the row's site: d1 the nearest distance so far,
    d1_col its column, d2 the nearest distance to another b site. Each column likewise keeps
    col_d1, col_best (the nearest a site) and col_d2 (the next a site's distance). A site's
    further keypoints are rows of their own merged into the same site, so the running values are
    the smallest over each site's keypoints (module docstring). Ties go to the lowest column and
    the lowest row site, as numpy's argmin over the whole matrix gives them, whatever the tiles.
    worst: the largest value of dist's dtype (infinity for floats)."""
    n_cols = tile.shape[1]
    sites_c = col_site[c0:c0 + n_cols]  # views: the loops below vectorise on them
    terms_c = col_terms[c0:c0 + n_cols]
    near_c, next_c = col_d1[c0:c0 + n_cols], col_d2[c0:c0 + n_cols]
    best_c = col_best[c0:c0 + n_cols]
    for i in range(tile.shape[0]):
        values, term = tile[i], row_terms[i]
        for j in range(n_cols):
            dist[j] = term + terms_c[j] + scale * values[j]
        near = worst
        for j in range(n_cols):
            near = min(near, dist[j])
        j_near = 0
        while dist[j_near] != near:
            j_near += 1
        site_near = sites_c[j_near]
        other = worst
        for j in range(n_cols):
            other = min(other, dist[j] if sites_c[j] != site_near else worst)
        s = s0 + row_site[i]
        if d1_col[s] >= 0 and col_site[d1_col[s]] == site_near:  # the same site: both shrink
            if near < d1[s]:
                d1[s], d1_col[s] = near, c0 + j_near
            d2[s] = min(d2[s], other)
        elif d1_col[s] < 0 or near < d1[s] or (near == d1[s] and c0 + j_near < d1_col[s]):
            d2[s] = min(d1[s], other)  # the old nearest is the next, or the tile's other
            d1[s], d1_col[s] = near, c0 + j_near
        else:
            d2[s] = min(d2[s], near)
        site = col_best.dtype.type(s)
        for j in range(n_cols):  # branch-free: it vectorises
            v, c1, cb, c2 = dist[j], near_c[j], best_c[j], next_c[j]
            same = cb == site
            nearer = (v < c1) | ((v == c1) & (site < cb))
            next_c[j] = c2 if same else (c1 if nearer else min(c2, v))
            near_c[j] = min(c1, v)
            best_c[j] = site if (nearer and not same) else cb


def nearest_sites_both_ways(desc_a: np.ndarray, site_a: np.ndarray, n_a: int,
                            desc_b: np.ndarray, site_b: np.ndarray, n_b: int,
                            product_of: Callable[[np.ndarray], Product] = numpy_product
                            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(best_ab, ratio_ab, best_ba, ratio_ba): for each site of a the nearest site of b (int64
    (n_a,)) and the ratio of the distances to the nearest and second-nearest site of b (float32
    (n_a,)), and the same from b to a; a site's distance to another is the smallest over their
    keypoints (module docstring). desc_*: float32 (K, 128) keypoint descriptors; site_*: int64
    (K,) each keypoint's site.

    One distance matrix serves both directions, computed a tile at a time (BLOCK_SITES row sites
    of a with their further keypoints, by TILE_COLUMNS keypoints of b) and reduced into running
    nearest sites both ways while in cache (nearest_sites_in_tile); b's keypoints are folded
    into their sites at the end. Half the arithmetic of one matrix per direction, and both
    directions see the same distances. product_of(columns) gives the tiles' product
    (descriptor_products: numpy's, or oneDNN's or 8-bit integers' for integer descriptors: the
    same values). Distances of integer descriptors are integers, reduced as int32."""
    cols, col_site, site_cols = _columns(desc_b, site_b, n_b)
    product = product_of(cols)
    integer = integer_descriptors(desc_a) and integer_descriptors(desc_b)
    dist_type = np.int32 if integer else np.float32
    worst = dist_type(np.iinfo(np.int32).max if integer else np.inf)
    d1, d2 = np.full(n_a, worst), np.full(n_a, worst)
    d1_col = np.full(n_a, -1, np.int64)
    col_d1, col_d2 = np.full(len(cols), worst), np.full(len(cols), worst)
    col_best = np.full(len(cols), -1, np.int32)
    dist = np.empty(TILE_COLUMNS, dist_type)
    col_site = col_site.astype(np.int32)
    tile = np.empty(0, product.dtype)  # each tile contiguous: a product may need it so
    for s0, s1, rows, row_site in _row_blocks(desc_a, site_a, n_a):
        if len(rows) * TILE_COLUMNS > len(tile):
            tile = np.empty(len(rows) * TILE_COLUMNS, product.dtype)
        row_terms = product.row_terms(rows)
        for c0 in range(0, len(cols), TILE_COLUMNS):
            c1 = min(len(cols), c0 + TILE_COLUMNS)
            part = tile[:len(rows) * (c1 - c0)].reshape(len(rows), c1 - c0)
            product.fill(rows, c0, c1, part)
            nearest_sites_in_tile(part, product.scale, row_terms, product.col_terms, row_site,
                                  col_site, s0, c0, d1, d1_col, d2, col_d1, col_d2, col_best,
                                  dist, worst)
    d1, d2, col_d1, col_d2 = (_as_float(d, worst) for d in (d1, d2, col_d1, col_d2))
    best_ab = col_site[d1_col].astype(np.int64)
    ratio_ab = np.sqrt(np.maximum(d1, 0.0) / np.maximum(d2, 1e-12))
    # fold b's keypoints into their sites: the nearest a site over a site's keypoints, and the
    # nearest other a site: a keypoint's own second where its nearest is that site, else its
    # nearest
    which = np.argmin(col_d1[site_cols], axis=1)
    chosen_col = site_cols[np.arange(n_b), which]
    best_ba = col_best[chosen_col].astype(np.int64)
    nearest_ba = col_d1[chosen_col]
    other = np.where(col_best[site_cols] == best_ba[:, None], col_d2[site_cols],
                     col_d1[site_cols]).min(axis=1)
    ratio_ba = np.sqrt(np.maximum(nearest_ba, 0.0) / np.maximum(other, 1e-12)).astype(np.float32)
    return best_ab, ratio_ab, best_ba, ratio_ba


def _as_float(distances: np.ndarray, worst) -> np.ndarray:
    """Running distances as float32, the dtype's largest value (none found) as infinity."""
    return np.where(distances == worst, np.float32(np.inf), distances.astype(np.float32))


def _region_box(mask: np.ndarray, margin_px: int) -> Optional[tuple[slice, slice]]:
    """(rows, columns) of the bounding box of mask's nonzero pixels grown by margin_px within
    the image, or None where the mask is empty."""
    rows, cols = np.nonzero(mask.any(axis=1))[0], np.nonzero(mask.any(axis=0))[0]
    if not len(rows):
        return None
    height, width = mask.shape
    return (slice(max(0, rows[0] - margin_px), min(height, rows[-1] + 1 + margin_px)),
            slice(max(0, cols[0] - margin_px), min(width, cols[-1] + 1 + margin_px)))


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
        True, if given (detected on the region's box, REGION_MARGIN_FRACTION)."""
        gray, scale_xy = resize_for_matching(to_gray(image), self.max_image_side_px)
        none = np.zeros((0, 2)), np.zeros(0, np.int64), np.zeros((0, 128), np.float32)
        detected, mask, corner_xy = gray, None, np.zeros(2)
        if region is not None:
            mask = cv2.resize(region.astype(np.uint8) * 255, gray.shape[::-1],
                              interpolation=cv2.INTER_NEAREST)
            box = _region_box(mask, int(round(REGION_MARGIN_FRACTION * max(gray.shape))))
            if box is None:
                return none
            detected, mask = np.ascontiguousarray(gray[box]), np.ascontiguousarray(mask[box])
            corner_xy = np.array([box[1].start, box[0].start], np.float64)
        keypoints, descriptors = self._detector().detectAndCompute(detected, mask)
        if not keypoints:
            return none
        xy = np.array([k.pt for k in keypoints], dtype=np.float64) + corner_xy
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

    def _match_pair(self, fa, fb, product_of=numpy_product):
        n_a, n_b = len(fa[0]), len(fb[0])
        if n_a < 2 or n_b < 2:
            empty = np.zeros(0, np.int64)
            return mutual_pair_maps(empty, empty, np.zeros(0), n_a, n_b)
        (_, site_a, desc_a), (_, site_b, desc_b) = fa, fb
        best_ab, ratio_ab, best_ba, ratio_ba = nearest_sites_both_ways(
            desc_a, site_a, n_a, desc_b, site_b, n_b, product_of)
        src = np.arange(n_a)
        keep = ((best_ba[best_ab] == src) & (ratio_ab < self.ratio_threshold)
                & (ratio_ba[best_ab] < self.ratio_threshold))
        src, dst = src[keep], best_ab[keep]
        certainty = 1.0 - np.maximum(ratio_ab[src], ratio_ba[dst])
        return mutual_pair_maps(src, dst, certainty, n_a, n_b)

    detects_in_regions = True
    # The distance products by oneDNN (descriptor_products: the same matches, 1.6x faster; by
    # 8-bit integers where the CPU has AMX or VNNI, in under half that time again):
    # worth torch's import (about a second) only where the products take seconds, asift's.
    products_by_onednn = False

    def _match(self, images: list[np.ndarray], steps: Steps,
               regions: Optional[list[Optional[np.ndarray]]] = None) -> SiteMatchSet:
        # OpenCV's SIFT leaves most of its work on one core and releases the GIL: one image per
        # core (the same features as one after another); the pairs' distance matrices likewise
        # (numpy's reductions run on one core, outside the GIL).
        cores = available_cores()
        regions = regions or [None] * len(images)
        feats = map_threads(lambda k: self._features(images[k], regions[k]), range(len(images)),
                            min(len(images), cores), steps.done)
        # One pair per core, and each pair's products on its own core: a BLAS that spreads every
        # product over all the cores as well runs twice as many threads as cores, and its idle
        # threads spin while numpy reduces a tile. With fewer pairs than cores, BLAS takes the rest.
        pairs_at_once = max(1, min(cores, len(images) * (len(images) - 1) // 2))
        threads = max(1, cores // pairs_at_once)
        by_onednn = self.products_by_onednn and all(integer_descriptors(f[2]) for f in feats)
        with threadpool_limits(threads, user_api="blas"), \
                (onednn_products(threads) if by_onednn else contextlib.nullcontext()) as torch_there:
            product_of = (onednn_product_for([f[2] for f in feats]) if torch_there
                          else numpy_product)
            # the products' context is global to torch: the pairs run inside it, not alongside
            return match_unordered_pairs(
                images, [f[0] for f in feats],
                lambda i, j: self._match_pair(feats[i], feats[j], product_of), pairs_at_once,
                steps)


class AsiftMatcher(SiftMatcher):
    """SIFT on affine-simulated views of each image (ASIFT, Morel & Yu 2009, as OpenCV's
    AffineFeature: the image tilted by up to 5x in several directions), so that a surface seen
    from viewpoints 45-80 deg apart still has keypoints whose descriptors agree. Matched as
    `sift` is (sites, ratio test, mutual check); max_keypoints is per simulated view (about 40
    views: ~20 times the keypoints of `sift`, and its matching time)."""

    name = "asift"
    products_by_onednn = True

    def __init__(self, max_image_side_px: Optional[int] = 1024, max_keypoints: int = 1000,
                 ratio_threshold: float = 0.8, contrast_threshold: float = 0.04,
                 root_sift: bool = False, device: Optional[str] = None):
        super().__init__(max_image_side_px, max_keypoints, ratio_threshold, contrast_threshold,
                         root_sift, device)

    def _detector(self):
        return cv2.AffineFeature_create(super()._detector())
