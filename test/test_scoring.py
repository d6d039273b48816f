"""Triangulation-angle score (eq. 1), top-k sums and ray helpers."""
import numpy as np
import pytest

from densecalib_ros.core.method.scoring import (angle_score, equidistant_rays, pair_poses_from_rig,
                                                rays_from_intrinsics, top_k_sum)
from densecalib_ros.core.types import CameraIntrinsics


@pytest.mark.parametrize("p", [1.0, 2.5])
def test_score_peaks_with_value_p_and_vanishes_at_the_ends(p):
    theta = np.linspace(0, 180, 18001)
    f = angle_score(theta, 30.0, 20.0, p)
    k = int(np.argmax(f))
    assert f[k] == pytest.approx(p, rel=1e-6)
    # Default boundary sharpness: the peak stays near alpha, as the paper states.
    assert theta[k] == pytest.approx(30.0, abs=3.0)
    assert 0.3 * p < f[1000] < 0.8 * p and 0.3 * p < f[5000] < 0.8 * p  # covers ~10-50 deg
    assert np.all(np.diff(f[: k + 1]) >= 0) and np.all(np.diff(f[k:]) <= 0)  # unimodal
    assert f[0] == 0.0 and f[-1] == 0.0
    assert angle_score(1.0, p=p) < 0.01 * p and angle_score(179.0, p=p) < 1e-6 * p
    # eps = 1 is eq. 1 as printed: its boundary term pulls the peak to 52.1 deg.
    printed = angle_score(theta, 30.0, 20.0, p, boundary_eps=1.0)
    assert theta[int(np.argmax(printed))] == pytest.approx(52.1, abs=0.1)
    assert printed.max() == pytest.approx(p, rel=1e-6)
    # A flat Gaussian leaves the boundary term's own peak (90 deg).
    wide = angle_score(theta, 30.0, 1000.0, p, boundary_eps=1.0)
    assert theta[int(np.argmax(wide))] == pytest.approx(90.0, abs=0.5)


def test_score_of_invalid_angles_is_zero():
    np.testing.assert_array_equal(angle_score(np.array([np.nan, -5.0, 200.0])), [0.0, 0.0, 0.0])


def test_top_k_sum():
    s = np.array([[0.1, 0.9, 0.5, 0.3], [0.0, 0.2, 0.0, 0.0]])
    np.testing.assert_allclose(top_k_sum(s, 1), [0.9, 0.2])
    np.testing.assert_allclose(top_k_sum(s, 3), [1.7, 0.2])
    np.testing.assert_allclose(top_k_sum(s, 10), [1.8, 0.2])
    np.testing.assert_array_equal(top_k_sum(s, 0), [0.0, 0.0])


def test_pair_poses_from_rig():
    rng = np.random.default_rng(0)
    poses = []
    for _ in range(3):
        q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        T = np.eye(4)
        T[:3, :3] = q * np.sign(np.linalg.det(q))
        T[:3, 3] = rng.normal(size=3)
        poses.append(T)
    rel = pair_poses_from_rig(poses)
    assert set(rel) == {(0, 1), (0, 2), (1, 2)}
    X_rig = rng.normal(size=3)
    R, t = rel[(0, 2)]
    x0 = poses[0][:3, :3] @ X_rig + poses[0][:3, 3]
    x2 = poses[2][:3, :3] @ X_rig + poses[2][:3, 3]
    np.testing.assert_allclose(R @ x0 + t, x2, atol=1e-12)


def test_ray_helpers_invert_projection():
    f, size = 300.0, (1000, 800)
    theta = np.radians([0.0, 30.0, 80.0, 100.0])
    phi = np.radians([0.0, 45.0, 170.0, -60.0])
    xy = np.stack([500 + f * theta * np.cos(phi), 400 + f * theta * np.sin(phi)], axis=1)
    rays = equidistant_rays(xy, size, f)
    np.testing.assert_allclose(np.arccos(rays[:, 2]), theta, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(rays, axis=1), 1.0)
    cam = CameraIntrinsics("RADIAL", 640, 480, np.array([500.0, 320.0, 240.0, 0.05, -0.01]))
    X = np.array([[0.3, -0.2, 1.0], [-0.5, 0.4, 2.0]])
    xy = cam.to_pycolmap().img_from_cam(X)
    r = rays_from_intrinsics(cam, xy)
    np.testing.assert_allclose(r, X / np.linalg.norm(X, axis=1, keepdims=True), atol=1e-6)
