"""RoMa backend end to end with the real romatch model at random initialisation and a tiny
resolution (its trained weights cannot be obtained here), and the torchvision stand-in it imports
with (`densecalib_ros.core.method.matching.tv_compat`)."""
import importlib.util
import sys

import numpy as np
import pytest
import torch

from densecalib_ros.core.method.matching import create_matcher
from densecalib_ros.core.method.matching import tv_compat
from densecalib_ros.core.types import SiteMatchSet

COARSE_RES, UPSAMPLE_RES = 14 * 4, 64  # RoMa's defaults are 560 / 864


pytestmark = pytest.mark.usefixtures("torch_one_thread")


def no_network(monkeypatch):
    """Any attempt to open a connection (a weights download) fails the test."""
    import socket

    def refuse(*args, **kwargs):
        raise AssertionError("network access attempted")
    monkeypatch.setattr(socket.socket, "connect", refuse)
    monkeypatch.setattr(socket, "create_connection", refuse)


@pytest.fixture(scope="module")
def random_checkpoints(tmp_path_factory):
    """(roma.pth, dinov2.pth): state dicts of RoMa outdoor and DINOv2 ViT-L/14 at their own random
    initialisation, written as checkpoint files (the real ones are ~1.6 GB together)."""
    romatch = tv_compat.import_romatch()
    from romatch.models.matcher import RegressionMatcher
    from romatch.models.transformer.dinov2 import DinoVisionTransformer

    torch.manual_seed(0)
    built = []
    with pytest.MonkeyPatch.context() as mp:
        # romatch loads given weights right after building; keep the random ones instead.
        mp.setattr(RegressionMatcher, "load_state_dict", lambda self, state, *a, **k: built.append(self))
        mp.setattr(DinoVisionTransformer, "load_state_dict", lambda self, state, *a, **k: None)
        no_network(mp)
        romatch.roma_outdoor(device="cpu", weights={}, dinov2_weights={}, coarse_res=COARSE_RES,
                             upsample_res=UPSAMPLE_RES, use_custom_corr=False)
    folder = tmp_path_factory.mktemp("roma_weights")
    paths = folder / "roma_outdoor.pth", folder / "dinov2_vitl14_pretrain.pth"
    torch.save(built[0].state_dict(), paths[0])
    torch.save(built[0].encoder.dinov2_vitl14[0].state_dict(), paths[1])
    return paths


def textured(width, height, seed):
    """(H, W, 3) uint8 smooth colour noise."""
    import cv2

    rng = np.random.default_rng(seed)
    noise = rng.random((height // 8 + 2, width // 8 + 2, 3)).astype(np.float32)
    return (cv2.resize(noise, (width, height), interpolation=cv2.INTER_CUBIC).clip(0, 1) * 255).astype(np.uint8)


def test_roma_matches_every_pair_with_random_weights(random_checkpoints, monkeypatch):
    no_network(monkeypatch)
    roma_path, dinov2_path = random_checkpoints
    matcher = create_matcher("roma", weights_path=str(roma_path), dinov2_weights_path=str(dinov2_path),
                             coarse_res=COARSE_RES, upsample_res=UPSAMPLE_RES, device="cpu")
    matcher.load()
    if importlib.util.find_spec("torchvision") is None:  # the stand-in is gone after the import
        assert not [name for name in sys.modules if name.split(".")[0] == "torchvision"]
        from romatch.models import encoders
        assert encoders.tvm.vgg19_bn is tv_compat.vgg19_bn

    # Sizes differ; image 2 is uniform grey. RoMa predicts each direction from the features of its
    # source image, so with any weights every site of a uniform source gets the same prediction
    # (one target, flat certainty) while a textured source gets varied ones: this tells the two
    # halves of RoMa's symmetric warp apart.
    images = [textured(320, 240, 1), textured(288, 224, 2), np.full((200, 150, 3), 128, np.uint8)]
    ms = matcher.match(images)
    assert isinstance(ms, SiteMatchSet)
    n, sites_per_image = len(images), UPSAMPLE_RES * UPSAMPLE_RES
    assert set(ms.pairs) == {(i, j) for i in range(n) for j in range(n) if i != j}
    for c, image in enumerate(images):
        h, w = image.shape[:2]
        assert ms.image_sizes[c] == (w, h)
        s = ms.sites[c]
        assert s.shape == (sites_per_image, 2) and s.dtype == np.float64
        assert np.all((s > 0) & (s < [w, h])), "sites outside the original image"
        assert len(np.unique(s, axis=0)) == sites_per_image
    for (i, j), m in ms.pairs.items():
        assert m.target.dtype == np.int32 and m.target.shape == (sites_per_image,)
        assert np.all((m.target >= -1) & (m.target < sites_per_image))
        assert np.all(m.certainty[m.target < 0] == 0)
        assert np.all((m.certainty >= 0) & (m.certainty <= 1))
        assert (m.target >= 0).sum() > 0, f"no match above min_certainty in {(i, j)}"
        # The continuous target (original px of image j) lies in the target site's grid cell.
        ok = m.target >= 0
        assert m.target_xy_px.shape == (sites_per_image, 2)
        assert np.isfinite(m.target_xy_px[ok]).all() and np.isnan(m.target_xy_px[~ok]).all()
        w_j, h_j = ms.image_sizes[j]
        half_cell = 0.5 * np.array([w_j, h_j]) / UPSAMPLE_RES + 1e-6
        assert np.all(np.abs(m.target_xy_px[ok] - ms.sites[j][m.target[ok]]) <= half_cell)
    for j in (0, 1):
        from_uniform, from_textured = ms.pairs[(2, j)], ms.pairs[(j, 2)]
        assert len(np.unique(from_uniform.target)) <= 4 < 50 <= len(np.unique(from_textured.target))
        assert from_uniform.certainty.std() < 0.2 * from_textured.certainty.std()
    assert len(np.unique(ms.pairs[(0, 1)].target)) >= 50 and len(np.unique(ms.pairs[(1, 0)].target)) >= 50


def test_vgg19_bn_stand_in_has_torchvisions_layout():
    torch.manual_seed(0)
    model = tv_compat.vgg19_bn()
    assert sum(p.numel() for p in model.parameters()) == 143678248  # torchvision's VGG19_BN num_params
    keys = model.state_dict().keys()
    for key in ("features.0.weight", "features.1.running_var", "features.49.weight", "features.50.bias",
                "classifier.0.weight", "classifier.6.bias"):
        assert key in keys
    # RoMa's encoder keeps features[:40] and reads the input of each max pooling: scales 1..8.
    x, feats = torch.rand(1, 3, 32, 48), []
    with torch.no_grad():
        for layer in model.features[:40]:
            if isinstance(layer, torch.nn.MaxPool2d):
                feats.append(tuple(x.shape[1:]))
            x = layer(x)
    assert feats == [(64, 32, 48), (128, 16, 24), (256, 8, 12), (512, 4, 6)]
    with pytest.raises(RuntimeError, match="Pretrained"):
        tv_compat.vgg19_bn(weights="IMAGENET1K_V1")


def test_transform_stand_ins_follow_torchvision():
    from PIL import Image

    rgb = textured(40, 30, 4)
    image = Image.fromarray(rgb)
    resized = tv_compat.Resize((16, 24), tv_compat.InterpolationMode.BICUBIC)(image)
    assert resized.size == (24, 16)  # size is (height, width), as in torchvision
    np.testing.assert_array_equal(np.asarray(resized), np.asarray(image.resize((24, 16), Image.BICUBIC)))
    with pytest.raises(TypeError):
        tv_compat.Resize(16)
    tensor = tv_compat.ToTensor()(image)
    assert tensor.shape == (3, 30, 40) and tensor.dtype == torch.float32
    np.testing.assert_allclose(tensor.permute(1, 2, 0).numpy(), rgb / 255.0, atol=1e-6)
    normalized = tv_compat.Normalize([0.5, 0.25, 0.0], [0.5, 2.0, 1.0])(tensor)
    np.testing.assert_allclose(normalized[1].numpy(), (tensor[1].numpy() - 0.25) / 2.0, atol=1e-6)
    assert torch.equal(tensor, tv_compat.ToTensor()(image))  # not in place
