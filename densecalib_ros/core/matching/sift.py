"""OpenCV SIFT with Lowe's ratio test and a mutual nearest-neighbour check (no torch).

root_sift=True compares RootSIFT descriptors (L1-normalised, element-wise square root: Euclidean
distance then compares them by the Hellinger kernel, Arandjelovic & Zisserman 2012; COLMAP's
default). It gives better matches (bench-sampling --quick: raw inliers 0.946 -> 0.968 pinhole,
0.971 -> 0.982 fisheye; about half the wrong matches of weak 35 deg pairs gone), but end to end it
measured worse (full bench, incremental mean AUC@3 90.6 -> 83.7, the real fox scene 62 -> 7):
on weakly connected rigs small input changes flip the outcome (a different sampling seed does too;
see core/consensus.py), so one bench run cannot show a match-quality gain there. Opt-in for now.

Sites are keypoint locations; OpenCV returns several keypoints at one location (one per dominant
orientation), which are merged into one site whose descriptor distance to another site is the
smallest over their keypoints. The ratio test compares the nearest and second-nearest *site*,
so orientation duplicates do not reject each other. (j, i) is the exact inverse of (i, j).
"""
from __future__ import annotations

from typing import Optional

import cv2
import numpy as np

from ..errors import InputError
from ..types import SiteMatchSet
from .base import Matcher
from .utils import (match_unordered_pairs, mutual_pair_maps, opencv_to_original,
                    resize_for_matching, to_gray)


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

    def _features(self, image: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Returns sites float64 (S, 2) original COLMAP px, keypoint site index int64 (K,),
        descriptors float32 (K, 128)."""
        gray, scale_xy = resize_for_matching(to_gray(image), self.max_image_side_px)
        sift = cv2.SIFT_create(nfeatures=self.max_keypoints,
                               contrastThreshold=self.contrast_threshold)
        keypoints, descriptors = sift.detectAndCompute(gray, None)
        if not keypoints:
            return np.zeros((0, 2)), np.zeros(0, np.int64), np.zeros((0, 128), np.float32)
        xy = np.array([k.pt for k in keypoints], dtype=np.float64)
        unique_xy, site_of_kp = np.unique(xy, axis=0, return_inverse=True)
        descriptors = descriptors.astype(np.float32)
        if self.root_sift:  # SIFT descriptors are non-negative
            descriptors = np.sqrt(descriptors / np.maximum(
                descriptors.sum(axis=1, keepdims=True), 1e-12))
        return (opencv_to_original(unique_xy, scale_xy), site_of_kp.reshape(-1).astype(np.int64),
                descriptors)

    @staticmethod
    def _site_sq_distances(desc_a, site_a, n_a, desc_b, site_b, n_b) -> np.ndarray:
        """float32 (S_a, S_b): smallest squared descriptor distance between the keypoints of two
        sites (a plain keypoint distance matrix where no location holds several keypoints)."""
        order_a, order_b = np.argsort(site_a, kind="stable"), np.argsort(site_b, kind="stable")
        da, db = desc_a[order_a], desc_b[order_b]
        d2 = da @ db.T  # in place from here: the matrix is the memory peak
        d2 *= -2.0
        d2 += np.einsum("ij,ij->i", da, da)[:, None]
        d2 += np.einsum("ij,ij->i", db, db)[None, :]
        if n_b < len(site_b):
            d2 = np.minimum.reduceat(d2, np.searchsorted(site_b[order_b], np.arange(n_b)), axis=1)
        if n_a < len(site_a):
            d2 = np.minimum.reduceat(d2, np.searchsorted(site_a[order_a], np.arange(n_a)), axis=0)
        return d2

    @staticmethod
    def _two_nearest(d2: np.ndarray, axis: int) -> tuple[np.ndarray, np.ndarray]:
        """Index of the nearest entry along `axis` and the ratio nearest / second-nearest distance."""
        best = np.argmin(d2, axis=axis)
        other = np.arange(d2.shape[1 - axis])
        index = (other, best) if axis == 1 else (best, other)
        first = d2[index].copy()
        d2[index] = np.inf
        second = np.min(d2, axis=axis)
        d2[index] = first
        ratio = np.sqrt(np.maximum(first, 0.0) / np.maximum(second, 1e-12))
        return best, ratio

    def _match_pair(self, fa, fb):
        sites_a, site_a, desc_a = fa
        sites_b, site_b, desc_b = fb
        n_a, n_b = len(sites_a), len(sites_b)
        if n_a < 2 or n_b < 2:
            empty = np.zeros(0, np.int64)
            return mutual_pair_maps(empty, empty, np.zeros(0), n_a, n_b)
        d2 = self._site_sq_distances(desc_a, site_a, n_a, desc_b, site_b, n_b)
        best_ab, ratio_ab = self._two_nearest(d2, axis=1)
        best_ba, ratio_ba = self._two_nearest(d2, axis=0)
        src = np.arange(n_a)
        keep = ((best_ba[best_ab] == src) & (ratio_ab < self.ratio_threshold)
                & (ratio_ba[best_ab] < self.ratio_threshold))
        src, dst = src[keep], best_ab[keep]
        certainty = 1.0 - np.maximum(ratio_ab[src], ratio_ba[dst])
        return mutual_pair_maps(src, dst, certainty, n_a, n_b)

    def _match(self, images: list[np.ndarray]) -> SiteMatchSet:
        feats = [self._features(im) for im in images]
        return match_unordered_pairs(images, [f[0] for f in feats],
                                     lambda i, j: self._match_pair(feats[i], feats[j]))
