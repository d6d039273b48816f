"""RoMa (the paper's dense matcher) through the `romatch` package, weights from configured paths.

Sites are the pixels of the warp grid of each image (RoMa's `upsample_res`, or `coarse_res`
without upsampling), mapped to the original image: grid cell (r, c) of an (h, w) grid over a
W x H image is the site at ((c + 0.5) W / w, (r + 0.5) H / h). For each pair RoMa predicts both
directions (symmetric model); a target coordinate is rounded to the nearest target grid site, with
RoMa's certainty, and also kept as the sub-pixel SiteMatches.target_xy_px (cycles compose on the
rounded sites, track observations use the continuous coordinate; see
sampling.cycle_observations_px). The weights (RoMa outdoor + DINOv2 ViT-L/14) are never
downloaded: they come from the options `weights_path` / `dinov2_weights_path` or the environment
variables DENSECALIB_ROMA_WEIGHTS / DENSECALIB_DINOV2_WEIGHTS.

Requirements beyond the core: romatch 0.1.2 installed with --no-deps, plus pillow, einops and
loguru (requirements-nodeps.txt / requirements.txt; scripts/setup_env.sh installs them). romatch
imports torchvision; where no working torchvision exists (as with this project's CPU torch) a
narrow stand-in is used while importing it (see `tv_compat`).
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Optional

import numpy as np

from ...errors import InputError, ModelWeightsError
from ...types import SiteMatches, SiteMatchSet
from .base import Matcher, Steps
from .utils import resize_for_matching, resolve_device, to_rgb

WEIGHTS_ENV = "DENSECALIB_ROMA_WEIGHTS"
DINOV2_WEIGHTS_ENV = "DENSECALIB_DINOV2_WEIGHTS"


def grid_sites(width: int, height: int, grid_w: int, grid_h: int) -> np.ndarray:
    """float64 (grid_h * grid_w, 2) original COLMAP coordinates of the grid cells, row-major."""
    cols, rows = np.meshgrid(np.arange(grid_w), np.arange(grid_h))
    return np.stack([(cols.ravel() + 0.5) * width / grid_w, (rows.ravel() + 0.5) * height / grid_h],
                    axis=1)


def warp_to_site_matches(target_norm: np.ndarray, certainty: np.ndarray, min_certainty: float,
                         target_size: tuple[int, int]) -> SiteMatches:
    """One direction of a RoMa warp as a site map.

    target_norm: (h, w, 2) target coordinates in [-1, 1] (RoMa's normalised convention, the image
    border at +-1) for every source grid cell; certainty: (h, w); target_size: (width, height) of
    the original target image. The target grid has the same (h, w) shape. A target is the grid
    cell containing the coordinate, i.e. the nearest target site; -1 where certainty <=
    min_certainty or the coordinate is not finite. target_xy_px holds the continuous coordinate in
    original COLMAP px, x = (u + 1) / 2 * width (NaN where target is -1).
    """
    h, w = certainty.shape
    t = np.asarray(target_norm, dtype=np.float64).reshape(-1, 2)
    cert = np.asarray(certainty, dtype=np.float32).reshape(-1)
    finite = np.isfinite(t).all(axis=1) & np.isfinite(cert)
    t = np.where(finite[:, None], t, 0.0)
    col = np.clip(np.floor((t[:, 0] + 1.0) * 0.5 * w), 0, w - 1).astype(np.int64)
    row = np.clip(np.floor((t[:, 1] + 1.0) * 0.5 * h), 0, h - 1).astype(np.int64)
    ok = finite & (cert > min_certainty)
    target = np.where(ok, row * w + col, -1).astype(np.int32)
    xy = np.where(ok[:, None], (t + 1.0) * 0.5 * np.asarray(target_size, np.float64), np.nan)
    return SiteMatches(target, np.where(ok, np.clip(cert, 0.0, 1.0), 0.0).astype(np.float32), xy)


def _weights_file(option_value: Optional[str], env: str, option: str, what: str) -> Path:
    value = option_value or os.environ.get(env)
    if not value:
        raise ModelWeightsError(f"No {what} weights configured: set the matcher option {option}= "
                                f"or the environment variable {env} to the checkpoint file.")
    path = Path(value).expanduser()
    if not path.is_file():
        raise ModelWeightsError(f"{what} weights not found at {path}: set the matcher option "
                                f"{option}= or {env} to an existing checkpoint file.")
    return path


class RomaMatcher(Matcher):
    name = "roma"

    def __init__(self, max_image_side_px: Optional[int] = None, weights_path: Optional[str] = None,
                 dinov2_weights_path: Optional[str] = None, coarse_res: int = 560,
                 upsample_res: Optional[int] = 864, min_certainty: float = 0.05,
                 device: Optional[str] = None):
        """coarse_res / upsample_res: RoMa's square working resolutions (multiples of 14 / 8;
        upsample_res None = no upsampling, the warp grid is coarse_res); max_image_side_px: cap
        on the images handed to RoMa (RoMa resizes them itself); min_certainty: matches at or below
        it are dropped. device: 'cpu' or 'cuda' (default: cuda when available)."""
        super().__init__(max_image_side_px)
        self.weights_path = weights_path
        self.dinov2_weights_path = dinov2_weights_path
        self.coarse_res = int(coarse_res)
        self.upsample_res = None if upsample_res is None else int(upsample_res)
        self.min_certainty = float(min_certainty)
        self.device = device

    def _load(self) -> None:
        weights = _weights_file(self.weights_path, WEIGHTS_ENV, "weights_path", "RoMa (roma_outdoor.pth)")
        dinov2 = _weights_file(self.dinov2_weights_path, DINOV2_WEIGHTS_ENV, "dinov2_weights_path",
                               "DINOv2 ViT-L/14 (dinov2_vitl14_pretrain.pth)")
        import torch

        from .tv_compat import import_romatch

        try:
            roma_outdoor = import_romatch().roma_outdoor
        except Exception as exc:  # ImportError (romatch or a dependency missing), or a broken install
            raise InputError(
                f"Matcher 'roma' needs the romatch package, which cannot be imported here ({exc}). "
                "Run scripts/setup_env.sh (installs romatch==0.1.2 with --no-deps plus pillow, einops, "
                "loguru), or choose another matcher (sift, xfeat-lighterglue, xfeat-star).") from exc
        self.device = resolve_device(self.device)
        states = []
        for path in (weights, dinov2):
            try:
                states.append(torch.load(str(path), map_location=self.device, weights_only=True))
            except Exception as exc:
                raise ModelWeightsError(f"Weights at {path} are unreadable ({exc}).") from exc
        amp_dtype = torch.float16 if self.device.startswith("cuda") else torch.float32
        try:
            self.model = roma_outdoor(
                device=self.device, weights=states[0], dinov2_weights=states[1],
                coarse_res=self.coarse_res, upsample_res=self.upsample_res or self.coarse_res,
                amp_dtype=amp_dtype, upsample_preds=self.upsample_res is not None,
                use_custom_corr=False)  # the fused CUDA kernel is an optional extra package
        except RuntimeError as exc:  # load_state_dict: missing / unexpected keys, wrong shapes
            raise ModelWeightsError(f"RoMa weights {weights} / {dinov2} do not fit the model ({exc}).") from exc
        self.model.eval()

    def _grid_shape(self) -> tuple[int, int]:
        res = self.upsample_res or self.coarse_res
        return res, res

    def _match(self, images: list[np.ndarray], steps: Steps) -> SiteMatchSet:
        from PIL import Image

        grid_h, grid_w = self._grid_shape()
        pil = [Image.fromarray(to_rgb(resize_for_matching(im, self.max_image_side_px)[0])) for im in images]
        sizes = [(im.shape[1], im.shape[0]) for im in images]  # (width, height)
        pairs = {}
        for i in range(len(images)):
            for j in range(i + 1, len(images)):
                warp, certainty = self.model.match(pil[i], pil[j], device=self.device)
                warp = warp[0].float().cpu().numpy()  # (h, 2w, 4): [A->B | B->A], (x_A, y_A, x_B, y_B)
                certainty = certainty[0].float().cpu().numpy()  # (h, 2w)
                if warp.shape[:2] != (grid_h, 2 * grid_w):
                    raise InputError(f"RoMa returned a {warp.shape[:2]} warp, expected {(grid_h, 2 * grid_w)}: "
                                     "this romatch version is not supported.")
                pairs[(i, j)] = warp_to_site_matches(warp[:, :grid_w, 2:], certainty[:, :grid_w],
                                                     self.min_certainty, sizes[j])
                pairs[(j, i)] = warp_to_site_matches(warp[:, grid_w:, :2], certainty[:, grid_w:],
                                                     self.min_certainty, sizes[i])
                steps.done()
        return SiteMatchSet(sites=[grid_sites(w, h, grid_w, grid_h) for w, h in sizes],
                            pairs=pairs, image_sizes=sizes)
