"""Matcher backends: SiteMatchSet invariants, accuracy on a known homography, exact coordinate maps
under resizing, registry errors, RoMa's weight handling and warp-to-site plumbing, no torch for
sift, XFeat*'s shared keypoint tables (cycles close) and sub-pixel target positions on a rendered
rig."""
import subprocess
import sys

import cv2
import numpy as np
import pytest

from densecalib_ros.core.method.cycles import close_cycles
from densecalib_ros.core.errors import InputError, ModelWeightsError
from densecalib_ros.core.method.matching import available_matchers, create_matcher
from densecalib_ros.core.method.matching.roma import grid_sites, warp_to_site_matches
from densecalib_ros.core.method.matching.sift import nearest_sites_both_ways
from densecalib_ros.core.method.matching.utils import mutual_pair_maps
from densecalib_ros.core.synthetic import RigSpec, generate_rig
from densecalib_ros.core.types import SiteMatchSet


def textured_image(width, height, seed=0):
    """(H, W, 3) uint8: blurred colour noise plus random discs and boxes (corners for detectors)."""
    rng = np.random.default_rng(seed)
    img = np.zeros((height, width, 3), np.float32)
    for cell in (32, 8):
        noise = rng.random((height // cell + 2, width // cell + 2, 3)).astype(np.float32)
        img += cv2.resize(noise, (width, height), interpolation=cv2.INTER_LINEAR) * 60
    img = np.clip(img, 0, 255).astype(np.uint8)
    for _ in range(width * height // 400):
        colour = tuple(int(v) for v in rng.integers(0, 256, 3))
        x, y, r = int(rng.integers(0, width)), int(rng.integers(0, height)), int(rng.integers(2, 12))
        if rng.random() < 0.5:
            cv2.circle(img, (x, y), r, colour, -1, cv2.LINE_AA)
        else:
            cv2.rectangle(img, (x, y), (x + r, int(y + 1.5 * r)), colour, -1)
    return img


def apply_h(h_colmap, xy):
    p = np.c_[xy, np.ones(len(xy))] @ h_colmap.T
    return p[:, :2] / p[:, 2:]


def warp_colmap(image, h_colmap, size):
    """Warp with a homography given in COLMAP pixels (OpenCV's pixel centres are at 0)."""
    shift = np.array([[1, 0, -0.5], [0, 1, -0.5], [0, 0, 1.0]])
    return cv2.warpPerspective(image, shift @ h_colmap @ np.linalg.inv(shift), size, flags=cv2.INTER_LINEAR)


H_TRUE = np.array([[0.93, 0.07, 14.0], [-0.05, 0.98, 9.0], [1e-4, 6e-5, 1.0]])


@pytest.fixture(scope="module")
def image_pair():
    """A 320x240 RGB image and its homography warp rendered at 288x224 (sizes differ)."""
    image = textured_image(320, 240, seed=1)
    return image, warp_colmap(image, H_TRUE, (288, 224))


pytestmark = pytest.mark.usefixtures("torch_one_thread")


def check_invariants(ms: SiteMatchSet, images, inverse: bool):
    n = len(images)
    assert len(ms.sites) == n and len(ms.image_sizes) == n
    assert set(ms.pairs) == {(i, j) for i in range(n) for j in range(n) if i != j}
    for c, image in enumerate(images):
        w, h = image.shape[1], image.shape[0]
        assert ms.image_sizes[c] == (w, h)
        s = ms.sites[c]
        assert s.dtype == np.float64 and s.ndim == 2 and s.shape[1] == 2
        assert np.all((s >= 0) & (s <= [w, h])), "sites outside the original image"
        assert len(np.unique(s, axis=0)) == len(s), "duplicate sites"
    for (i, j), m in ms.pairs.items():
        assert m.target.dtype == np.int32 and m.certainty.dtype == np.float32
        assert m.target.shape == m.certainty.shape == (len(ms.sites[i]),)
        assert np.all((m.target >= -1) & (m.target < len(ms.sites[j])))
        assert np.all(m.certainty[m.target < 0] == 0)
        assert np.all((m.certainty >= 0) & (m.certainty <= 1))
        if inverse:
            back = ms.pairs[(j, i)].target
            src = np.nonzero(m.target >= 0)[0]
            np.testing.assert_array_equal(back[m.target[src]], src)
            assert (back >= 0).sum() == len(src)


def homography_accuracy(ms, h_true):
    m = ms.pairs[(0, 1)]
    src = np.nonzero(m.target >= 0)[0]
    err = np.linalg.norm(apply_h(h_true, ms.sites[0][src]) - ms.sites[1][m.target[src]], axis=1)
    return len(src), float(np.mean(err < 2.0)), err


def test_registry_lists_backends_and_rejects_unknown_names():
    assert available_matchers() == ["sift", "asift", "xfeat-lighterglue", "xfeat-star", "roma"]
    with pytest.raises(InputError) as info:
        create_matcher("superglue")
    for name in available_matchers():
        assert name in str(info.value)
    with pytest.raises(InputError, match="ratio_threshold"):
        create_matcher("sift", ratio=0.7)


def test_sift_does_not_import_torch():
    code = ("import sys, numpy as np\n"
            "from densecalib_ros.core.method.matching import create_matcher\n"
            "rng = np.random.default_rng(0)\n"
            "img = (rng.random((120, 160)) * 255).astype(np.uint8)\n"
            "ms = create_matcher('sift').match([img, img[10:, 5:]])\n"
            "assert len(ms.pairs) == 2\n"
            "print('torch' in sys.modules)\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip().splitlines()[-1] == "False"


def test_sift_matches_follow_the_homography(image_pair):
    matcher = create_matcher("sift")
    matcher.load()
    ms = matcher.match(list(image_pair))
    check_invariants(ms, image_pair, inverse=True)
    n, inliers, err = homography_accuracy(ms, H_TRUE)
    assert n >= 80
    assert inliers >= 0.9
    assert np.median(err) < 0.6  # sub-pixel: the +0.5 pixel-centre shift is applied


def test_asift_matches_a_surface_seen_at_a_grazing_angle():
    """A plane foreshortened 3.5x along one axis (seen ~73 deg off its normal) and rotated: asift
    finds several times the correct matches sift does, and its site tables keep the invariants."""
    image = textured_image(480, 360, seed=2)
    angle = np.radians(30)
    rotation = np.array([[np.cos(angle), -np.sin(angle), 0], [np.sin(angle), np.cos(angle), 0],
                         [0, 0, 1]])
    h = np.array([[1 / 3.5, 0, 260], [0, 1, 30], [0, 0, 1.0]]) @ rotation
    h[2, :2] = [2e-4, 0]  # some perspective
    pair = [image, warp_colmap(image, h, (480, 360))]
    correct = {}
    for name in ("sift", "asift"):
        ms = create_matcher(name, max_image_side_px=None).match(pair)
        check_invariants(ms, pair, inverse=True)
        _, _, err = homography_accuracy(ms, h)
        correct[name] = int(np.sum(err < 2.0))
    assert correct["asift"] >= 100 and correct["asift"] >= 3 * correct["sift"], correct


def test_sift_compares_rootsift_descriptors(image_pair):
    """root_sift=True: sqrt of the L1-normalised SIFT descriptor (unit L2 norm) at the same sites
    as the default raw descriptors."""
    root = create_matcher("sift", root_sift=True)._features(image_pair[0])
    raw = create_matcher("sift")._features(image_pair[0])
    np.testing.assert_array_equal(root[0], raw[0])
    np.testing.assert_allclose(np.linalg.norm(root[2], axis=1), 1.0, atol=1e-5)
    np.testing.assert_allclose(root[2], np.sqrt(raw[2] / raw[2].sum(axis=1, keepdims=True)),
                               atol=1e-6)
    assert np.abs(np.linalg.norm(raw[2], axis=1) - 1.0).max() > 0.1  # the default stays raw


def _reference_nearest_sites(desc_r, site_r, n_r, desc_c, site_c, n_c):
    """The definition, in float64: site distance = smallest keypoint distance."""
    d2 = ((desc_r[:, None, :].astype(np.float64) - desc_c[None, :, :]) ** 2).sum(axis=2)
    sites = np.full((n_r, n_c), np.inf)
    np.minimum.at(sites, (site_r[:, None], site_c[None, :]), d2)
    best = np.argmin(sites, axis=1)
    ordered = np.sort(sites, axis=1)
    return best, np.sqrt(ordered[:, 0] / ordered[:, 1])


def _keypoints_at_sites(rng, n_sites, integer_range=None):
    """Shuffled keypoints of n_sites sites, some sites holding several (up to four orientations
    at one location): float32 descriptors (random, or integers below integer_range, which makes
    ties), int64 sites."""
    site = np.concatenate([np.arange(n_sites), rng.integers(0, n_sites, n_sites // 2),
                           np.repeat(rng.integers(0, n_sites, 2), 2)])
    site = rng.permutation(site)
    desc = (rng.random((len(site), 128)) * 100 if integer_range is None
            else rng.integers(0, integer_range, (len(site), 128)))
    return desc.astype(np.float32), site.astype(np.int64)


@pytest.mark.parametrize("block_sites, tile_columns", [(7, 5), (7, 4096), (1024, 5),
                                                       (1024, 4096)])
def test_sift_site_distances_are_the_smallest_over_each_sites_keypoints(monkeypatch, block_sites,
                                                                        tile_columns):
    """Sites holding several keypoints, in shuffled order, across block and tile boundaries (a
    site's further keypoints sit in other tiles than its first): the nearest site and the
    distance ratio as defined."""
    import densecalib_ros.core.method.matching.sift as sift

    monkeypatch.setattr(sift, "BLOCK_SITES", block_sites)
    monkeypatch.setattr(sift, "TILE_COLUMNS", tile_columns)
    rng = np.random.default_rng(3)
    desc_a, site_a = _keypoints_at_sites(rng, 40)
    desc_b, site_b = _keypoints_at_sites(rng, 55)
    assert np.bincount(site_a).max() >= 3 and np.bincount(site_b).max() >= 3
    # Both directions from one matrix: the same definition both ways.
    both = nearest_sites_both_ways(desc_a, site_a, 40, desc_b, site_b, 55)
    for (best, ratio), args in zip([both[:2], both[2:]],
                                   [(desc_a, site_a, 40, desc_b, site_b, 55),
                                    (desc_b, site_b, 55, desc_a, site_a, 40)]):
        ref_best, ref_ratio = _reference_nearest_sites(*args)
        np.testing.assert_array_equal(best, ref_best)
        np.testing.assert_allclose(ratio, ref_ratio, rtol=1e-4)


def test_sift_nearest_sites_do_not_depend_on_the_tiles_ties_included(monkeypatch):
    """Integer descriptors from a small range make equal distances common: the running merge
    over tiles gives the nearest sites and ratios of one whole-matrix pass, ties resolved
    alike."""
    import densecalib_ros.core.method.matching.sift as sift

    rng = np.random.default_rng(5)
    desc_a, site_a = _keypoints_at_sites(rng, 60, integer_range=3)
    desc_b, site_b = _keypoints_at_sites(rng, 70, integer_range=3)
    args = (desc_a, site_a, 60, desc_b, site_b, 70)
    monkeypatch.setattr(sift, "BLOCK_SITES", 1024)
    monkeypatch.setattr(sift, "TILE_COLUMNS", 4096)
    whole = nearest_sites_both_ways(*args)
    ratios = np.concatenate([whole[1], whole[3]])
    assert np.mean(ratios == 1.0) > 0.05  # ties between sites do occur
    for block_sites, tile_columns in [(7, 5), (3, 11), (1024, 2)]:
        monkeypatch.setattr(sift, "BLOCK_SITES", block_sites)
        monkeypatch.setattr(sift, "TILE_COLUMNS", tile_columns)
        for got, want in zip(nearest_sites_both_ways(*args), whole):
            np.testing.assert_array_equal(got, want)


def test_sift_nearest_sites_on_ties_are_the_lowest_column_and_the_lowest_row_site():
    """The one-pass tile reduction where equal distances are everywhere: a site of a takes the b
    site of the lowest column (b's keypoints: every site's first, then the others) at its
    nearest distance; a site of b the lowest a site at its first keypoint at its nearest
    distance; the next distance is the nearest to any other site, equal to the nearest on a
    tie. Checked against the whole matrix by brute force."""
    import densecalib_ros.core.method.matching.sift as sift

    rng = np.random.default_rng(7)
    desc_a, site_a = _keypoints_at_sites(rng, 30, integer_range=2)
    desc_b, site_b = _keypoints_at_sites(rng, 35, integer_range=2)
    best_ab, ratio_ab, best_ba, ratio_ba = nearest_sites_both_ways(desc_a, site_a, 30, desc_b,
                                                                   site_b, 35)
    cols, col_site, _ = sift._columns(desc_b, site_b, 35)
    d = ((desc_a[:, None, :].astype(np.int64) - cols[None, :, :-6]) ** 2).sum(axis=2)
    want_ab, want_ratio_ab = [], []
    for s in range(30):
        row = d[site_a == s].min(axis=0)  # over the site's keypoints
        col = int(np.argmin(row))  # the lowest column at the nearest distance
        other = row[col_site != col_site[col]].min()
        want_ab.append(col_site[col])
        want_ratio_ab.append(np.sqrt(row[col] / other))
    np.testing.assert_array_equal(best_ab, want_ab)
    np.testing.assert_allclose(ratio_ab, want_ratio_ab, rtol=1e-6)
    by_site = np.stack([d[site_a == s].min(axis=0) for s in range(30)])  # (a sites, columns)
    want_ba, want_ratio_ba = [], []
    for s in range(35):
        mine = by_site[:, col_site == s]  # its keypoints' columns, first keypoint first
        nearest = mine.min()
        column = int(np.flatnonzero((mine == nearest).any(axis=0))[0])  # its first at it
        a_site = int(np.argmin(mine[:, column]))  # the lowest a site there
        other = np.delete(mine, a_site, axis=0).min()
        want_ba.append(a_site)
        want_ratio_ba.append(np.sqrt(nearest / other))
    np.testing.assert_array_equal(best_ba, want_ba)
    np.testing.assert_allclose(ratio_ba, want_ratio_ba, rtol=1e-6)
    assert np.mean(np.r_[ratio_ab, ratio_ba] == 1.0) > 0.2  # ties decided these


def _sift_sites(image, nfeatures):
    """OpenCV SIFT's (descriptors float32, int64 sites, number of sites) of an image."""
    keypoints, desc = cv2.SIFT_create(nfeatures).detectAndCompute(
        cv2.cvtColor(image, cv2.COLOR_RGB2GRAY), None)
    _, site = np.unique(np.array([k.pt for k in keypoints]), axis=0, return_inverse=True)
    return desc.astype(np.float32), site.reshape(-1).astype(np.int64), int(site.max()) + 1


def test_onednn_products_give_numpys_matches_to_the_bit(image_pair, monkeypatch):
    """OpenCV SIFT's integer descriptors, and norms cut into parts bfloat16 holds exactly: oneDNN's
    products (which may compute in bfloat16) give the exact distances, so numpy's nearest sites
    and ratios; RootSIFT's descriptors are not taken there."""
    import torch

    import densecalib_ros.core.method.matching.sift as sift
    from densecalib_ros.core.method.matching import descriptor_products as dp

    monkeypatch.setattr(sift, "BLOCK_SITES", 300)  # several blocks and tiles
    monkeypatch.setattr(sift, "TILE_COLUMNS", 700)
    a, b = _sift_sites(image_pair[0], 3000), _sift_sites(image_pair[1], 3000)
    assert dp.integer_descriptors(a[0]) and dp.integer_descriptors(b[0])
    assert not dp.integer_descriptors(np.sqrt(a[0]))
    norms = np.einsum("ij,ij->i", a[0], a[0])
    parts = dp.norm_parts(norms)
    np.testing.assert_array_equal(parts.sum(axis=1, dtype=np.float64), norms)
    np.testing.assert_array_equal(torch.from_numpy(parts).bfloat16().float().numpy(), parts)
    want = nearest_sites_both_ways(*a, *b)
    rows = np.c_[-2 * a[0], parts, np.ones((len(norms), 3))].astype(np.float32)
    cols = np.c_[b[0], np.ones((len(b[0]), 3)),
                 dp.norm_parts(np.einsum("ij,ij->i", b[0], b[0]))].astype(np.float32)
    a64, b64 = a[0].astype(np.float64), b[0].astype(np.float64)  # integers: exact in float64
    exact = (a64 ** 2).sum(axis=1)[:, None] + (b64 ** 2).sum(axis=1) - 2 * a64 @ b64.T
    with dp.onednn_products(1) as torch_there:
        assert torch_there and torch.backends.mkldnn.matmul.fp32_precision == "bf16"
        got = nearest_sites_both_ways(*a, *b, dp.onednn_product)
        out = np.empty((len(rows), len(cols)), np.float32)
        dp.onednn_product(cols).fill(rows, 0, len(cols), out)
        np.testing.assert_array_equal(out, exact)
    assert torch.backends.mkldnn.matmul.fp32_precision != "bf16"  # put back
    for got_k, want_k in zip(got, want):
        np.testing.assert_array_equal(got_k, want_k)


def test_int8_products_give_numpys_matches_to_the_bit(image_pair, monkeypatch):
    """torch's 8-bit integer products (descriptors less 128, each distance that product times -2
    plus the row's and the column's own terms) give the exact distances, so numpy's nearest sites
    and ratios, on tiles that are not whole blocks; and are chosen where the CPU's int8 sums are
    exact."""
    import densecalib_ros.core.method.matching.sift as sift
    from densecalib_ros.core.method.matching import descriptor_products as dp

    import torch

    if torch.cpu._is_amx_tile_supported():  # where it was measured: oneDNN's AMX kernel is exact
        assert dp.int8_exact_here()
    elif not dp.int8_exact_here():  # the float products run here, as the check decided
        pytest.skip("this CPU has no 8-bit integer kernel (AMX or VNNI) whose sums check exact")
    monkeypatch.setattr(sift, "BLOCK_SITES", 300)
    monkeypatch.setattr(sift, "TILE_COLUMNS", 700)
    a, b = _sift_sites(image_pair[0], 3000), _sift_sites(image_pair[1], 3000)
    assert dp.int8_exact(a[0]) and dp.int8_exact(b[0])
    assert dp.onednn_product_for([a[0], b[0]]) is dp.int8_product
    assert not dp.int8_exact(a[0][:, :64])  # 128 values a descriptor
    want = nearest_sites_both_ways(*a, *b)
    with dp.onednn_products(1):
        got = nearest_sites_both_ways(*a, *b, dp.int8_product)
    for got_k, want_k in zip(got, want):
        np.testing.assert_array_equal(got_k, want_k)


def test_asift_matches_with_numpys_products_where_torch_refuses_onednns(monkeypatch):
    """A torch that refuses the bfloat16 setting (another build or version): the products are
    numpy's, with the same matches, and the setting is left as it was."""
    import torch

    from densecalib_ros.core.method.matching import descriptor_products as dp

    def refuse(*args):
        raise RuntimeError("not on this build")
    before = torch.backends.mkldnn.matmul.fp32_precision
    monkeypatch.setattr(torch._C, "_set_fp32_precision_setter", refuse)
    with dp.onednn_products(1) as torch_there:
        assert torch_there is None
    assert torch.backends.mkldnn.matmul.fp32_precision == before
    image = textured_image(200, 150, seed=4)
    matches = create_matcher("asift").match([image, image[10:, 8:]])
    monkeypatch.undo()
    np.testing.assert_array_equal(matches.pairs[(0, 1)].target,
                                  create_matcher("asift").match(
                                      [image, image[10:, 8:]]).pairs[(0, 1)].target)


def test_resized_matching_maps_back_to_original_pixels(image_pair):
    gray = [cv2.cvtColor(im, cv2.COLOR_RGB2GRAY) for im in image_pair]
    ms = create_matcher("sift", max_image_side_px=200).match(gray)
    check_invariants(ms, gray, inverse=True)
    n, inliers, err = homography_accuracy(ms, H_TRUE)
    assert n >= 40 and inliers >= 0.8
    # A wrong scale or pixel-centre convention shows up as a systematic offset.
    assert np.all(np.abs(np.median(apply_h(H_TRUE, ms.sites[0][ms.pairs[(0, 1)].target >= 0])
                                   - ms.sites[1][ms.pairs[(0, 1)].target[ms.pairs[(0, 1)].target >= 0]],
                                   axis=0)) < 0.5)


def _no_network(monkeypatch):
    """Any attempt to open a connection (a weights download) fails the test."""
    import socket

    def refuse(*args, **kwargs):
        raise AssertionError("network access attempted")
    monkeypatch.setattr(socket.socket, "connect", refuse)
    monkeypatch.setattr(socket, "create_connection", refuse)


def test_xfeat_lighterglue_matches_follow_the_homography(image_pair, monkeypatch):
    _no_network(monkeypatch)
    matcher = create_matcher("xfeat-lighterglue", device="cpu", max_keypoints=1024)
    matcher.load()
    matcher.load()  # idempotent
    images = [image_pair[0], image_pair[1], image_pair[0][20:220, 10:300]]
    ms = matcher.match(images)
    check_invariants(ms, images, inverse=True)
    n, inliers, _ = homography_accuracy(ms, H_TRUE)
    assert n >= 150 and inliers >= 0.6


def test_xfeat_star_sites_are_one_keypoint_table_per_camera(image_pair, monkeypatch):
    _no_network(monkeypatch)
    matcher = create_matcher("xfeat-star", device="cpu", max_keypoints=2000)
    images = [image_pair[0], image_pair[1], image_pair[0][20:220, 10:300]]
    ms = matcher.match(images)
    check_invariants(ms, images, inverse=True)
    # A camera's table is its image's coarse keypoints, whatever the other images: every pair of
    # camera c indexes the same sites, so cycles compose by index.
    alone = matcher.match([images[0], images[2]])
    np.testing.assert_array_equal(alone.sites[0], ms.sites[0])
    np.testing.assert_array_equal(alone.sites[1], ms.sites[2])
    for (i, j), m in ms.pairs.items():  # refined positions exactly where matched
        assert m.target_xy_px.shape == (len(ms.sites[i]), 2)
        np.testing.assert_array_equal(np.isfinite(m.target_xy_px).all(axis=1), m.target >= 0)
    n, inliers, coarse_err = homography_accuracy(ms, H_TRUE)
    assert n >= 150 and inliers >= 0.3
    m = ms.pairs[(0, 1)]
    src = np.nonzero(m.target >= 0)[0]
    refined_err = np.linalg.norm(apply_h(H_TRUE, ms.sites[0][src]) - m.target_xy_px[src], axis=1)
    assert np.median(refined_err) < np.median(coarse_err)
    assert np.mean(refined_err < 2.0) > inliers


def test_xfeat_star_closes_cycles_and_refines_on_a_generated_rig(monkeypatch):
    """Three rendered pinhole views: 3-cycles close on the shared keypoint tables, and the refined
    target positions are nearer the true correspondence (rig.transfer) than the target sites."""
    _no_network(monkeypatch)
    rig = generate_rig(RigSpec(lenses="ideal", num_cameras=3, camera_model="RADIAL", width=640, height=480, seed=0))
    ms = create_matcher("xfeat-star", device="cpu", max_keypoints=4000).match(rig.images[0])
    check_invariants(ms, rig.images[0], inverse=True)
    cycles = close_cycles(ms, 3)
    assert sum(len(cs) for cs in cycles[3]) >= 30
    coarse, refined = [], []
    for (i, j), m in ms.pairs.items():
        src = np.flatnonzero(m.target >= 0)
        true_xy, visible = rig.transfer(0, i, j, ms.sites[i][src])
        coarse.append(np.linalg.norm(ms.sites[j][m.target[src]] - true_xy, axis=1)[visible])
        refined.append(np.linalg.norm(m.target_xy_px[src] - true_xy, axis=1)[visible])
    coarse, refined = np.concatenate(coarse), np.concatenate(refined)
    assert len(refined) > 1000
    assert np.median(refined) < 0.8 * np.median(coarse)
    assert np.mean(refined < 2.0) > np.mean(coarse < 2.0) + 0.1


def test_mutual_pair_maps_keep_the_most_certain_candidate_per_site():
    fwd, bwd = mutual_pair_maps(np.array([0, 0, 1, 2]), np.array([3, 1, 1, 0]),
                                np.array([0.2, 0.9, 0.5, 0.7]), 3, 4)
    np.testing.assert_array_equal(fwd.target, [1, -1, 0])  # site 1 loses target 1 to site 0
    np.testing.assert_array_equal(bwd.target, [2, 0, -1, -1])
    np.testing.assert_allclose(fwd.certainty, [0.9, 0.0, 0.7])


def test_roma_missing_weights_name_the_file_and_option(tmp_path, monkeypatch):
    monkeypatch.delenv("DENSECALIB_ROMA_WEIGHTS", raising=False)
    monkeypatch.delenv("DENSECALIB_DINOV2_WEIGHTS", raising=False)
    with pytest.raises(ModelWeightsError, match="weights_path.*DENSECALIB_ROMA_WEIGHTS"):
        create_matcher("roma").load()
    missing = tmp_path / "roma_outdoor.pth"
    with pytest.raises(ModelWeightsError, match=str(missing)):
        create_matcher("roma", weights_path=str(missing)).load()
    roma = tmp_path / "roma.pth"
    roma.write_bytes(b"x")
    monkeypatch.setenv("DENSECALIB_DINOV2_WEIGHTS", str(tmp_path / "dinov2_vitl14.pth"))
    with pytest.raises(ModelWeightsError, match="dinov2_vitl14.pth"):
        create_matcher("roma", weights_path=str(roma)).load()


def test_roma_without_romatch_says_why(tmp_path, monkeypatch):
    monkeypatch.setitem(sys.modules, "romatch", None)  # as if romatch were not installed
    for name in ("roma.pth", "dinov2.pth"):
        (tmp_path / name).write_bytes(b"x")
    matcher = create_matcher("roma", weights_path=str(tmp_path / "roma.pth"),
                             dinov2_weights_path=str(tmp_path / "dinov2.pth"))
    with pytest.raises(InputError, match="romatch"):
        matcher.load()


def test_roma_warp_becomes_grid_site_matches():
    """RoMa's output format (normalised warp + certainty on a square grid) for a known homography,
    both directions, images of different sizes: targets are the nearest grid sites."""
    (wa, ha), (wb, hb), g = (320, 240), (288, 224), 48
    sites_a, sites_b = grid_sites(wa, ha, g, g), grid_sites(wb, hb, g, g)
    rng = np.random.default_rng(0)
    pairs = {}
    for (i, j), h, (ws, hs), (wt, ht), sites in (((0, 1), H_TRUE, (wa, ha), (wb, hb), sites_a),
                                                  ((1, 0), np.linalg.inv(H_TRUE), (wb, hb), (wa, ha), sites_b)):
        xy = apply_h(h, sites)
        norm = np.stack([2 * xy[:, 0] / wt - 1, 2 * xy[:, 1] / ht - 1], axis=1).reshape(g, g, 2)
        certainty = rng.uniform(0.0, 1.0, (g, g)).astype(np.float32)
        outside = (np.abs(norm) > 1).any(axis=2)
        certainty[outside] = 0.0  # as RoMa does
        pairs[(i, j)] = warp_to_site_matches(norm, certainty, min_certainty=0.1,
                                             target_size=(wt, ht))
        low = (certainty <= 0.1).ravel()
        assert np.all(pairs[(i, j)].target[low] == -1)
        ok = pairs[(i, j)].target >= 0
        assert ok.sum() > 0.6 * g * g
        target_xy = (sites_b if j == 1 else sites_a)[pairs[(i, j)].target[ok]]
        half_cell = 0.5 * np.array([wt / g, ht / g]) + 1e-9
        assert np.all(np.abs(target_xy - xy[ok]) <= half_cell)
        # The continuous warp coordinate is kept in original pixels.
        np.testing.assert_allclose(pairs[(i, j)].target_xy_px[ok], xy[ok], atol=1e-9)
        assert np.all(np.isnan(pairs[(i, j)].target_xy_px[~ok]))
    ms = SiteMatchSet([sites_a, sites_b], pairs, [(wa, ha), (wb, hb)])
    check_invariants(ms, [np.zeros((ha, wa)), np.zeros((hb, wb))], inverse=False)
    # Both directions are predicted independently; a 2-cycle closes when they agree on the grid.
    fwd, bwd = pairs[(0, 1)].target, pairs[(1, 0)].target
    both = np.nonzero(fwd >= 0)[0]
    both = both[bwd[fwd[both]] >= 0]
    assert np.mean(bwd[fwd[both]] == both) > 0.5
