"""Two-view geometry on exact projections of random 3D points with known K, R, t (no renderer)."""
import numpy as np
import pytest

from densecalib_ros.core.method.twoview import (TwoViewGeometry, estimate_fundamental, pair_weights,
                                                pixels_to_rays, relative_pose_from_essential,
                                                symmetric_epipolar_distance_px,
                                                triangulation_angles_deg)


def rotation(axis, angle_deg):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    a = np.radians(angle_deg)
    k = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(a) * k + (1 - np.cos(a)) * k @ k


def project(K, R, t, X):
    Xc = X @ R.T + t
    uv = Xc @ K.T
    return uv[:, :2] / uv[:, 2:3], Xc[:, 2] > 0


@pytest.fixture
def pair():
    rng = np.random.default_rng(3)
    X = rng.uniform([-2, -1.5, 4], [2, 1.5, 8], size=(300, 3))  # world = camera i
    K_i = np.array([[800.0, 0, 320], [0, 800, 240], [0, 0, 1]])
    K_j = np.array([[650.0, 0, 330], [0, 650, 235], [0, 0, 1]])
    R = rotation([0.1, 1, 0.05], -20)
    t = -R @ np.array([1.5, 0.1, 0.2])  # camera j centre at (1.5, 0.1, 0.2) in frame i
    xy_i, _ = project(K_i, np.eye(3), np.zeros(3), X)
    xy_j, _ = project(K_j, R, t, X)
    return dict(X=X, K_i=K_i, K_j=K_j, R=R, t=t, xy_i=xy_i, xy_j=xy_j)


def test_fundamental_from_exact_correspondences_satisfies_epipolar_constraint(pair):
    geo = estimate_fundamental(pair["xy_i"], pair["xy_j"], threshold_px=1.0, seed=0)
    assert isinstance(geo, TwoViewGeometry) and geo.F_ji is not None
    assert geo.num_inliers == len(pair["xy_i"])
    d = symmetric_epipolar_distance_px(geo.F_ji, pair["xy_i"], pair["xy_j"])
    assert d.max() < 1e-2
    # A point moved by 5 px across its epipolar line is at ~5 px.
    moved = pair["xy_j"].copy()
    line = np.array([*pair["xy_i"][0], 1.0]) @ geo.F_ji.T
    moved[0] += 5.0 * line[:2] / np.linalg.norm(line[:2])
    assert symmetric_epipolar_distance_px(geo.F_ji, pair["xy_i"], moved)[0] == pytest.approx(
        5.0, rel=0.35)


def test_fundamental_rejects_outliers_and_is_deterministic(pair):
    rng = np.random.default_rng(0)
    xy_j = pair["xy_j"].copy()
    bad = rng.choice(len(xy_j), 60, replace=False)
    xy_j[bad] = rng.uniform([0, 0], [640, 480], size=(60, 2))
    geo = estimate_fundamental(pair["xy_i"], xy_j, seed=1)
    geo2 = estimate_fundamental(pair["xy_i"], xy_j, seed=1)
    good = np.ones(len(xy_j), bool)
    good[bad] = False
    truly_bad = symmetric_epipolar_distance_px(geo.F_ji, pair["xy_i"], xy_j)[bad] > 2
    assert geo.inlier_mask[good].all()
    assert not geo.inlier_mask[bad][truly_bad].any()
    np.testing.assert_array_equal(geo.inlier_mask, geo2.inlier_mask)
    np.testing.assert_allclose(geo.F_ji, geo2.F_ji)


def test_too_few_points_gives_no_estimate():
    geo = estimate_fundamental(np.zeros((5, 2)), np.zeros((5, 2)))
    assert geo.F_ji is None and geo.num_inliers == 0 and geo.inlier_mask.shape == (5,)


def test_relative_pose_and_triangulation_angles(pair):
    geo = estimate_fundamental(pair["xy_i"], pair["xy_j"])
    R, t, front = relative_pose_from_essential(geo.F_ji, pair["K_i"], pair["K_j"], pair["xy_i"],
                                               pair["xy_j"])
    t_true = pair["t"] / np.linalg.norm(pair["t"])
    assert np.degrees(np.arccos(np.clip((np.trace(R.T @ pair["R"]) - 1) / 2, -1, 1))) < 0.05
    assert np.dot(t, t_true) > 0.9999
    assert front.all()
    rays_i = pixels_to_rays(pair["xy_i"], pair["K_i"])
    rays_j = pixels_to_rays(pair["xy_j"], pair["K_j"])
    angles = triangulation_angles_deg(R, t, rays_i, rays_j)
    c_j = -pair["R"].T @ pair["t"]
    v_i, v_j = pair["X"], pair["X"] - c_j
    true = np.degrees(np.arccos(np.einsum("nk,nk->n", v_i, v_j)
                                / np.linalg.norm(v_i, axis=1) / np.linalg.norm(v_j, axis=1)))
    np.testing.assert_allclose(angles, true, atol=0.05)
    # A point behind camera j (its ray flipped) has no angle.
    flipped = triangulation_angles_deg(R, t, rays_i[:3], -rays_j[:3])
    assert np.isnan(flipped).all()


def test_pair_weights():
    w = pair_weights({(0, 1): 100, (1, 2): 50, (0, 2): 0})
    assert w == {(0, 1): 1.0, (1, 2): 0.5, (0, 2): 0.0}
    assert pair_weights({}) == {}
