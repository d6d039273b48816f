"""Import `romatch` where torchvision cannot be imported, with a narrow stand-in for the few
torchvision parts romatch touches.

Why: romatch 0.1.2 imports torchvision at import time (`romatch.models.encoders`:
`torchvision.models.vgg19_bn`; `romatch.utils.utils`: `transforms.Resize/Normalize` and
`InterpolationMode`; `romatch.models.tiny`: `transforms.ToTensor`). No torchvision build matches
this project's pinned CPU torch (the PyPI wheel fails at import: "operator torchvision::nms does
not exist"), yet RoMa's inference uses only a VGG19-BN feature stack (random init, its weights come
from the RoMa checkpoint) and PIL-image resizing / tensor normalisation. This module implements
exactly those parts, with torchvision's semantics and state-dict key names, and nothing else.

Scope: `import_romatch()` uses the real torchvision whenever it imports (e.g. a GPU machine with a
matching build). Otherwise it puts the stand-in into `sys.modules` only while romatch is being
imported and restores `sys.modules` afterwards, so the rest of the process never sees a
"torchvision"; romatch keeps its references to the stand-in objects. Pretrained torchvision weights
are refused (RoMa builds VGG with `pretrained=False`): nothing here downloads.
"""
from __future__ import annotations

import enum
import importlib
import importlib.util
import sys
import types
from typing import Sequence

import numpy as np
import torch
from torch import nn

# torchvision's VGG19 configuration "E": conv widths, "M" = 2x2 max pooling.
_VGG19_CFG = [64, 64, "M", 128, 128, "M", 256, 256, 256, 256, "M",
              512, 512, 512, 512, "M", 512, 512, 512, 512, "M"]


class VGG(nn.Module):
    """torchvision.models.VGG (same submodules, so the same state-dict keys: `features.<i>.*`,
    `classifier.<i>.*`). forward: float (B, 3, H, W) -> (B, num_classes) logits."""

    def __init__(self, features: nn.Sequential, num_classes: int = 1000, dropout: float = 0.5):
        super().__init__()
        self.features = features
        self.avgpool = nn.AdaptiveAvgPool2d((7, 7))
        self.classifier = nn.Sequential(
            nn.Linear(512 * 7 * 7, 4096), nn.ReLU(True), nn.Dropout(p=dropout),
            nn.Linear(4096, 4096), nn.ReLU(True), nn.Dropout(p=dropout),
            nn.Linear(4096, num_classes))
        # torchvision's initialisation (init_weights=True).
        for m in self.modules():
            if isinstance(m, nn.Conv2d):
                nn.init.kaiming_normal_(m.weight, mode="fan_out", nonlinearity="relu")
                nn.init.constant_(m.bias, 0)
            elif isinstance(m, nn.BatchNorm2d):
                nn.init.constant_(m.weight, 1)
                nn.init.constant_(m.bias, 0)
            elif isinstance(m, nn.Linear):
                nn.init.normal_(m.weight, 0, 0.01)
                nn.init.constant_(m.bias, 0)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.classifier(torch.flatten(self.avgpool(self.features(x)), 1))


def _vgg_features(batch_norm: bool) -> nn.Sequential:
    layers: list[nn.Module] = []
    in_channels = 3
    for v in _VGG19_CFG:
        if v == "M":
            layers.append(nn.MaxPool2d(kernel_size=2, stride=2))
            continue
        layers.append(nn.Conv2d(in_channels, v, kernel_size=3, padding=1))
        if batch_norm:
            layers.append(nn.BatchNorm2d(v))
        layers.append(nn.ReLU(inplace=True))
        in_channels = v
    return nn.Sequential(*layers)


def vgg19_bn(*, weights=None, progress: bool = True, **kwargs) -> VGG:
    """torchvision.models.vgg19_bn with random initialisation only (`weights=None`)."""
    if weights is not None:
        raise RuntimeError("Pretrained torchvision weights are not available here (no torchvision, no "
                           "downloads); RoMa loads its VGG weights from its own checkpoint.")
    return VGG(_vgg_features(batch_norm=True), **kwargs)


class InterpolationMode(enum.Enum):
    """torchvision.transforms.InterpolationMode (the values torchvision uses)."""
    NEAREST = "nearest"
    NEAREST_EXACT = "nearest-exact"
    BILINEAR = "bilinear"
    BICUBIC = "bicubic"
    BOX = "box"
    HAMMING = "hamming"
    LANCZOS = "lanczos"


class Resize:
    """torchvision.transforms.Resize for PIL images and an explicit (height, width) size: what
    romatch's inference does (torchvision resizes PIL images with PIL's own filter)."""

    def __init__(self, size: Sequence[int], interpolation: InterpolationMode = InterpolationMode.BILINEAR):
        if isinstance(size, int) or len(size) != 2:
            raise TypeError(f"Resize stand-in supports only an explicit (height, width) size, got {size!r}.")
        self.size = (int(size[0]), int(size[1]))
        self.interpolation = InterpolationMode(interpolation)

    def __call__(self, image):
        from PIL import Image

        if not isinstance(image, Image.Image):
            raise TypeError(f"Resize stand-in supports only PIL images, got {type(image).__name__}.")
        pil_filter = {InterpolationMode.NEAREST: Image.NEAREST, InterpolationMode.BILINEAR: Image.BILINEAR,
                      InterpolationMode.BICUBIC: Image.BICUBIC, InterpolationMode.BOX: Image.BOX,
                      InterpolationMode.HAMMING: Image.HAMMING, InterpolationMode.LANCZOS: Image.LANCZOS}
        if self.interpolation not in pil_filter:
            raise TypeError(f"Resize stand-in: {self.interpolation} is not available for PIL images.")
        height, width = self.size
        return image.resize((width, height), pil_filter[self.interpolation])


class Normalize:
    """torchvision.transforms.Normalize: float (C, H, W) or (B, C, H, W) -> (x - mean) / std per
    channel (not in place)."""

    def __init__(self, mean: Sequence[float], std: Sequence[float], inplace: bool = False):
        self.mean, self.std, self.inplace = list(mean), list(std), inplace

    def __call__(self, tensor: torch.Tensor) -> torch.Tensor:
        if not tensor.is_floating_point():
            raise TypeError(f"Normalize expects a float tensor, got {tensor.dtype}.")
        mean = torch.as_tensor(self.mean, dtype=tensor.dtype, device=tensor.device).view(-1, 1, 1)
        std = torch.as_tensor(self.std, dtype=tensor.dtype, device=tensor.device).view(-1, 1, 1)
        return tensor.sub_(mean).div_(std) if self.inplace else (tensor - mean) / std


class ToTensor:
    """torchvision.transforms.ToTensor: PIL image or (H, W[, C]) array -> (C, H, W) tensor, uint8
    scaled to float32 in [0, 1], other dtypes kept."""

    def __call__(self, picture) -> torch.Tensor:
        array = np.array(picture, copy=True)
        if array.ndim == 2:
            array = array[:, :, None]
        tensor = torch.from_numpy(np.ascontiguousarray(array.transpose(2, 0, 1)))
        return tensor.float().div(255) if tensor.dtype == torch.uint8 else tensor


def _stand_in_modules() -> dict[str, types.ModuleType]:
    """The module objects of the stand-in, keyed by the names romatch imports."""
    root = types.ModuleType("torchvision", "Stand-in for the torchvision parts romatch uses (see "
                            f"{__name__}).")
    models = types.ModuleType("torchvision.models")
    models.VGG, models.vgg19_bn = VGG, vgg19_bn
    transforms = types.ModuleType("torchvision.transforms")
    functional = types.ModuleType("torchvision.transforms.functional")
    functional.InterpolationMode = InterpolationMode
    transforms.Resize, transforms.Normalize, transforms.ToTensor = Resize, Normalize, ToTensor
    transforms.InterpolationMode, transforms.functional = InterpolationMode, functional
    root.models, root.transforms = models, transforms
    modules = {m.__name__: m for m in (root, models, transforms, functional)}
    for module in modules.values():
        module.__path__ = []  # packages, so that submodule imports resolve through sys.modules
    return modules


def torchvision_works() -> bool:
    """Whether a real torchvision is installed and imports with the installed torch."""
    if "torchvision" in sys.modules:
        return True
    if importlib.util.find_spec("torchvision") is None:
        return False
    try:
        importlib.import_module("torchvision")
    except Exception:  # e.g. RuntimeError "operator torchvision::nms does not exist"
        return False
    return True


def import_romatch() -> types.ModuleType:
    """The `romatch` package, imported with the real torchvision when that works and with the
    stand-in otherwise (visible in sys.modules only during the import). Raises what the import
    raises (ImportError when romatch or one of its pure dependencies is missing)."""
    if "romatch" in sys.modules or torchvision_works():
        return importlib.import_module("romatch")
    # A failed earlier import leaves its completed submodules behind; import romatch afresh.
    for name in [n for n in sys.modules if n.startswith("romatch.")]:
        del sys.modules[name]
    saved = {n: m for n, m in sys.modules.items() if n == "torchvision" or n.startswith("torchvision.")}
    sys.modules.update(_stand_in_modules())
    try:
        return importlib.import_module("romatch")
    finally:
        for name in [n for n in sys.modules if n == "torchvision" or n.startswith("torchvision.")]:
            del sys.modules[name]
        sys.modules.update(saved)
