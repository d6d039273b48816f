"""Initial focals (paper eq. 2) from F's of a synthetic pinhole rig with known K, R, t."""
import numpy as np
import pytest

from densecalib_ros.core.errors import FocalInitError
from densecalib_ros.core.method.focal import (calibration_matrix, essential_residual,
                                              estimate_initial_focals)
from densecalib_ros.core.method.twoview import estimate_fundamental, pair_weights


def rotation(axis, angle_deg):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    a = np.radians(angle_deg)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(a) * k + (1 - np.cos(a)) * k @ k


def make_rig(seed=0, num_cams=6, noise_px=0.0):
    """Cameras on an arc looking at a box of points, with jittered orientations (so that the
    optical axes do not all meet in one point: the focal-from-F degeneracy). Returns true focals,
    image sizes and per ordered pair estimated F's and match counts."""
    rng = np.random.default_rng(seed)
    sizes = [(640, 480)] * num_cams
    focals = rng.uniform(450, 900, num_cams)
    X = rng.uniform([-3, -2, 6], [3, 2, 10], size=(400, 3))
    cams = []
    for c in range(num_cams):
        yaw = -30 + 60 * c / max(num_cams - 1, 1)
        centre = np.array([8 * np.sin(np.radians(yaw)), rng.uniform(-0.5, 0.5),
                           8 - 8 * np.cos(np.radians(yaw))])
        z = np.array([0, 0, 8.0]) - centre + rng.normal(scale=0.6, size=3)  # jittered look-at
        z /= np.linalg.norm(z)
        x = np.cross([0, 1.0, 0], z)
        x /= np.linalg.norm(x)
        R = np.stack([x, np.cross(z, x), z]) @ rotation(rng.normal(size=3), rng.uniform(2, 5))
        cams.append((R, -R @ centre))
    xy, ok = [], []
    for c, (R, t) in enumerate(cams):
        K = calibration_matrix(focals[c], (sizes[c][0] / 2, sizes[c][1] / 2))
        Xc = X @ R.T + t
        uv = Xc @ K.T
        p = uv[:, :2] / uv[:, 2:3] + rng.normal(scale=noise_px, size=(len(X), 2))
        xy.append(p)
        ok.append((Xc[:, 2] > 0) & (p[:, 0] > 0) & (p[:, 0] < 640) & (p[:, 1] > 0)
                  & (p[:, 1] < 480))
    F, counts = {}, {}
    for i in range(num_cams):
        for j in range(i + 1, num_cams):
            m = ok[i] & ok[j]
            geo = estimate_fundamental(xy[i][m], xy[j][m], threshold_px=1.0, seed=0)
            F[(i, j)], counts[(i, j)] = geo.F_ji, geo.num_inliers
    return focals, sizes, F, counts


def test_essential_residual_zero_at_true_focals_and_s3_negligible():
    focals, sizes, F, _ = make_rig(seed=1)
    K = [calibration_matrix(f, (w / 2, h / 2)) for f, (w, h) in zip(focals, sizes)]
    for (i, j), F_ji in F.items():
        assert essential_residual(F_ji, K[i], K[j]) < 1e-4
        s = np.linalg.svd(K[j].T @ F_ji @ K[i], compute_uv=False)
        assert s[2] / s[0] < 1e-6  # rank-2 F: the s3 term never drives the solution
    K_wrong = [calibration_matrix(1.5 * f, (w / 2, h / 2)) for f, (w, h) in zip(focals, sizes)]
    assert max(essential_residual(F_ji, K_wrong[i], K_wrong[j]) for (i, j), F_ji in F.items()) > 0.02


@pytest.mark.parametrize("seed", [0, 1])
def test_focals_recovered_from_noisy_fundamentals(seed):
    focals, sizes, F, counts = make_rig(seed=seed, noise_px=0.5)
    est = estimate_initial_focals(F, pair_weights(counts), sizes)
    assert est.shape == (6,)
    np.testing.assert_allclose(est, focals, rtol=0.03)


def test_focals_survive_one_corrupted_pair():
    focals, sizes, F, counts = make_rig(seed=2, noise_px=0.3)
    rng = np.random.default_rng(5)
    u, _, vt = np.linalg.svd(rng.normal(size=(3, 3)))
    F[(0, 3)] = u @ np.diag([1.0, 0.4, 0.0]) @ vt  # a rank-2 F unrelated to the geometry
    counts[(0, 3)] = max(counts.values())
    est = estimate_initial_focals(F, pair_weights(counts), sizes)
    np.testing.assert_allclose(est, focals, rtol=0.03)


def test_missing_camera_raises():
    focals, sizes, F, counts = make_rig(seed=0, num_cams=4)
    for key in list(F):
        if 3 in key:
            F[key] = None
    with pytest.raises(FocalInitError, match=r"camera\(s\) \[3\]"):
        estimate_initial_focals(F, pair_weights(counts), sizes)


def test_degenerate_fundamentals_raise():
    sizes = [(640, 480)] * 3
    F = {(0, 1): np.zeros((3, 3)), (1, 2): np.ones((3, 3)), (0, 2): np.eye(3) * [1, 0, 0]}
    with pytest.raises(FocalInitError):
        estimate_initial_focals(F, {k: 1.0 for k in F}, sizes)


def _corrupt(F, counts, pairs, count, seed=5):
    rng = np.random.default_rng(seed)
    for k in pairs:
        u, _, vt = np.linalg.svd(rng.normal(size=(3, 3)))
        F[k] = u @ np.diag([1.0, rng.uniform(0.2, 0.6), 0.0]) @ vt  # rank 2, unrelated to the rig
        counts[k] = count


def test_wrong_weak_pairs_outnumbering_strong_ones_are_tolerated():
    """A ring of cameras where only neighbours overlap well: the 10 non-neighbour pairs carry few
    matches and a wrong F, the 5 neighbour pairs are right. The fit is judged by its median
    weighted like the solve, so the focals come back instead of an error (the unweighted median
    is a wrong pair's residual)."""
    focals, sizes, F, counts = make_rig(seed=0, num_cams=6, noise_px=0.3)
    weak = [(i, j) for i, j in F if j - i > 1]
    _corrupt(F, counts, weak, count=max(counts.values()) // 6)
    est = estimate_initial_focals(F, pair_weights(counts), sizes)
    np.testing.assert_allclose(est, focals, rtol=0.05)


def test_wrong_strong_pairs_raise():
    focals, sizes, F, counts = make_rig(seed=0, num_cams=6, noise_px=0.3)
    _corrupt(F, counts, [(i, j) for i, j in F if j - i > 1], count=max(counts.values()))
    with pytest.raises(FocalInitError, match="weighted median residual"):
        estimate_initial_focals(F, pair_weights(counts), sizes)


def test_known_focals_are_held_and_set_the_scale_of_the_others():
    focals, sizes, F, counts = make_rig(seed=0, noise_px=0.5)
    known = np.full(6, np.nan)
    known[[0, 2]] = focals[[0, 2]]
    est = estimate_initial_focals(F, pair_weights(counts), sizes, known_px=known)
    assert est[0] == focals[0] and est[2] == focals[2]
    np.testing.assert_allclose(est, focals, rtol=0.03)
    # Known focals 20 % long pull the free cameras along with them (one scale for the rig).
    est_long = estimate_initial_focals(F, pair_weights(counts), sizes, known_px=1.2 * known)
    assert np.median(est_long[[1, 3, 4, 5]] / focals[[1, 3, 4, 5]]) > 1.05
    # A camera without a usable pair is no error when its focal is known.
    lonely = {k: (None if 5 in k else v) for k, v in F.items()}
    with pytest.raises(FocalInitError, match=r"camera\(s\) \[5\]"):
        estimate_initial_focals(lonely, pair_weights(counts), sizes)
    known[5] = focals[5]
    est = estimate_initial_focals(lonely, pair_weights(counts), sizes, known_px=known)
    assert est[5] == focals[5]
    np.testing.assert_allclose(est, focals, rtol=0.03)
