"""Issue 82: each camera's rotation sigma relative to the reference camera
(core.method.rotation_spread), on exact projections of a point cloud (sfm_fixtures) with
independent noise, and with a decentering the adjusted lens model lacks."""
import numpy as np
import pytest
from sfm_fixtures import gt_calibration, gt_rig, pose
from test_decentering import _adjusted

from densecalib_ros.core.method.decentering import lens_model_choice, other_lens_model
from densecalib_ros.core.method.image_folds import track_regions
from densecalib_ros.core.method.refinement_uncertainty import (camera_uncertainty,
                                                              posterior_covariances,
                                                              rotation_sigmas,
                                                              with_lens_model_choice)
from densecalib_ros.core.method.rotation_spread import (covariance_rotation_std_deg,
                                                        fold_rotation_std_deg)
from densecalib_ros.core.method.uncertainty import rotation_error_sigma_ratios
from densecalib_ros.core.metrics import rotation_angle_deg
from densecalib_ros.core.types import CameraQuality


def _rotation_errors_deg(state, poses) -> dict:
    ref = state.registered()[0]
    out = {}
    for c in state.registered()[1:]:
        est = state.cam_from_world[c][:3, :3] @ state.cam_from_world[ref][:3, :3].T
        true = poses[c][:3, :3] @ poses[ref][:3, :3].T
        out[c] = rotation_angle_deg(est @ true.T)
    return out


def _z(p1p2, seed):
    """Per camera |rotation error| / sigma, the sigma without and with the lens model's part,
    for a 5-camera rig whose lenses carry the decentering p1p2, adjusted without one."""
    state, blocks, priors, noise_px, _, _ = _adjusted(p1p2, seed=seed)
    _, poses = gt_rig(5, seed=seed, pp_jitter_px=0.0)
    covariances = posterior_covariances(state, blocks, priors, noise_px, track_regions(state))
    of_block = {b: camera_uncertainty(state, b, covariances.of_block(b), {}, None) for b in blocks}
    folds = fold_rotation_std_deg(state, blocks, priors, noise_px)
    model = lens_model_choice(state, blocks, other_lens_model(priors, blocks, []),
                              noise_px).rotation_deg
    statistical = rotation_sigmas(state, covariances, of_block, folds, {})
    full = rotation_sigmas(state, covariances, of_block, folds, model)
    errors = _rotation_errors_deg(state, poses)
    assert sorted(full) == sorted(errors) == [1, 2, 3, 4]  # the reference camera has none
    return (np.array([errors[c] / statistical[c] for c in errors]),
            np.array([errors[c] / full[c] for c in errors]))


def test_with_independent_noise_the_rotation_sigmas_fit_the_errors():
    z = np.concatenate([_z((0.0, 0.0), seed)[1] for seed in (5, 6)])
    assert 0.5 < np.median(z) < 1.5 and z.max() < 2.0, z


def test_a_decentering_the_model_lacks_is_covered_by_the_lens_models_part():
    """The principal points and the cameras' yaw and pitch take up the decentering alike in
    every fold: the covariance and the folds leave the errors at about 3 sigma; the rotations'
    move under the other lens model brings them within 2."""
    statistical, full = _z((8e-4, -6e-4), 5)
    assert statistical.max() > 2.5, statistical
    assert full.max() < 2.0, full


def test_the_lens_models_part_covers_the_principal_points_it_moves():
    """The decentering the model lacks moves the principal points as it turns the cameras:
    their statistical sigmas leave the errors at over 3 sigma, the other model's move in
    quadrature brings them within 2; without a decentering the part only widens sigmas that
    already fit. The focal sigmas are left as they are."""
    for p1p2, before in (((8e-4, -6e-4), 3.0), ((0.0, 0.0), 0.0)):
        state, blocks, priors, noise_px, _, true = _adjusted(p1p2, seed=5)
        covariances = posterior_covariances(state, blocks, priors, noise_px,
                                            track_regions(state))
        moved = lens_model_choice(state, blocks, other_lens_model(priors, blocks, []),
                                  noise_px).intrinsics_px
        z = []
        for b in blocks:
            sigma = camera_uncertainty(state, b, covariances.of_block(b), {}, None)
            wider = with_lens_model_choice(sigma, moved[b])
            assert wider.focal_std_px == sigma.focal_std_px
            assert wider.projection_std_px >= sigma.projection_std_px
            error = np.abs(np.subtract(state.intrinsics[b].params[2:4], true[b].params[2:4]))
            z.append([error.max() / s.principal_point_std_px for s in (sigma, wider)])
        z = np.array(z)  # per camera: statistical, with the lens model's part
        assert z[:, 0].max() > before and z[:, 1].max() < 2.0, z
        assert np.all(z[:, 1] <= z[:, 0])


def test_widening_the_intrinsics_adds_what_the_rotation_regresses_on_them():
    """A rotation that follows a principal point (r = 0.01 pp + its own noise): widening the
    principal point's sigma by 3 adds (9 - 1) * 0.01^2 * var(pp) to the rotation's variance."""
    var_pp, own = 4.0, 1e-6
    cov = np.zeros((4, 4))
    cov[3, 3] = var_pp
    cov[0, 3] = cov[3, 0] = 0.01 * var_pp
    cov[0, 0] = 0.01 ** 2 * var_pp + own
    cov[1, 1] = cov[2, 2] = own
    plain = covariance_rotation_std_deg(cov, [0, 1, 2], [3], np.array([1.0]))
    assert plain == pytest.approx(np.degrees(np.sqrt(0.01 ** 2 * var_pp + 3 * own)))
    wider = covariance_rotation_std_deg(cov, [0, 1, 2], [3], np.array([3.0]))
    assert wider == pytest.approx(np.degrees(np.sqrt(9 * 0.01 ** 2 * var_pp + 3 * own)))


def test_the_bench_compares_each_rotation_with_the_truth_relative_to_the_reference():
    cams, poses = gt_rig(3, seed=1)
    names = ["a", "b", "c"]
    truth = gt_calibration(names, cams, poses)
    turned = [poses[0], pose((0.0, 0.2, 0.0), [0, 0, 0]) @ poses[1], poses[2]]
    rig = gt_calibration(names, cams, turned)
    for name, sigma in zip(names, (None, 0.1, 0.05)):
        rig.cameras[name].quality = CameraQuality(0.3, 100, 0.5, rotation_std_deg=sigma)
    assert rotation_error_sigma_ratios(rig, truth) == pytest.approx([2.0, 0.0], abs=1e-3)
    # the truth in another frame (its reference another camera) compares the same
    other = gt_calibration(names[::-1], cams[::-1], poses[::-1])
    assert rotation_error_sigma_ratios(rig, other) == pytest.approx([2.0, 0.0], abs=1e-3)
