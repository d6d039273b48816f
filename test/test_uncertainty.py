"""Standard deviations from the bundle adjustment's information matrix (core.method.uncertainty), on
tracks made from ground truth with independent Gaussian pixel noise: there the predicted sigma
must match the actual errors."""
import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np
import pytest

from densecalib_ros.core.config import make_config
from densecalib_ros.core.method.incremental import initial_intrinsics
from densecalib_ros.core.method.multistart import run_incremental
from densecalib_ros.core.metrics import projection_map_error
from densecalib_ros.core.method.reconstruction import build_reconstruction
from densecalib_ros.core.types import CameraIntrinsics
from densecalib_ros.core.method.uncertainty import (CameraUncertainty, calibration_uncertainty,
                                                   with_runs_spread)

from sfm_fixtures import gt_rig, gt_tracks

NAMES = ["a", "b", "c", "d", "e"]


def _solved(seed, pp_jitter_px=0.0):
    """pp_jitter_px 0: the principal point the calibration holds at the centre is right."""
    cams, poses = gt_rig(5, seed=seed, pp_jitter_px=pp_jitter_px)
    tracks = gt_tracks(cams, poses, num_points=1500, noise_px=0.5, outlier_frac=0.0, seed=seed)
    cfg = make_config("regular", sfm__num_threads=1).sfm
    init = initial_intrinsics([(c.width, c.height) for c in cams],
                              [c.params[0] * 1.03 for c in cams], "RADIAL")
    result = run_incremental(tracks, init, NAMES, cfg)
    assert result.failed == []
    rec, _ = build_reconstruction(result.state, NAMES)
    return cams, rec


def test_sigmas_match_the_actual_errors_under_independent_noise():
    focal, projection = [], []
    for seed in (1, 2):
        cams, rec = _solved(seed)
        sigmas = calibration_uncertainty(rec, "a", noise_px=0.5, held_pp_std_fraction=0.0)
        assert set(sigmas) == set(NAMES)
        for name, cam in zip(NAMES, cams):
            s = sigmas[name]
            assert s.focal_std_px > 0 and s.principal_point_std_px is None  # pp held
            image = next(i for i in rec.images.values() if i.name == name)
            estimate = CameraIntrinsics.from_pycolmap(rec.cameras[image.camera_id])
            focal.append(abs(estimate.params[0] - cam.params[0]) / s.focal_std_px)
            projection.append(projection_map_error(cam, estimate)["mean_px"]
                              / s.projection_std_px)
    # |error| / sigma of a well-predicted Gaussian: median ~0.67, rarely above 3.
    print("focal |error| / sigma:", np.round(focal, 2))
    print("projection error / sigma:", np.round(projection, 2))
    for ratios in (focal, projection):
        assert 0.2 < np.median(ratios) < 2.0 and max(ratios) < 4.0, ratios


def _ratios(cams, rec, sigmas):
    focal, projection = [], []
    for name, cam in zip(NAMES, cams):
        s = sigmas[name]
        image = next(i for i in rec.images.values() if i.name == name)
        estimate = CameraIntrinsics.from_pycolmap(rec.cameras[image.camera_id])
        focal.append(abs(estimate.params[0] - cam.params[0]) / s.focal_std_px)
        projection.append(projection_map_error(cam, estimate)["mean_px"] / s.projection_std_px)
    return focal, projection


def test_a_held_principal_point_off_the_centre_is_in_the_sigmas():
    """Real principal points lie off the image centre where the regular preset holds them (by
    about 1 % of the long side): the sigmas that take the held point as right are then several
    times too small, those with its offset's spread in them (HELD_PP_STD_FRACTION) are not, and
    the held point's own sigma is that spread."""
    as_right, with_offset, point = ([], []), ([], []), []
    for seed in (1, 2):
        # uniform +-J has a standard deviation of J / sqrt(3): 1 % of the 640 px long side
        cams, rec = _solved(seed, pp_jitter_px=0.01 * 640 * np.sqrt(3.0))
        for out, fraction in ((as_right, 0.0), (with_offset, 0.01)):
            sigmas = calibration_uncertainty(rec, "a", noise_px=0.5,
                                             held_pp_std_fraction=fraction)
            ratios = _ratios(cams, rec, sigmas)
            out[0].extend(ratios[0]), out[1].extend(ratios[1])
            assert all(sigmas[n].principal_point_held for n in NAMES)
        assert all(sigmas[n].principal_point_std_px == pytest.approx(6.4) for n in NAMES)
        point += [np.abs(cam.params[1:3] - 0.5 * np.array([640, 480])).max() / 6.4 for cam in cams]
    print("held point |error| / its sigma:", np.round(point, 2))
    assert 0.2 < np.median(point) < 2.0 and max(point) < 4.0, point
    print("taken as right: focal", np.round(as_right[0], 2), "projection",
          np.round(as_right[1], 2))
    print("with its offset: focal", np.round(with_offset[0], 2), "projection",
          np.round(with_offset[1], 2))
    for ratios in as_right:
        assert np.median(ratios) > 2.0, ratios
    for ratios in with_offset:
        assert 0.2 < np.median(ratios) < 2.0 and max(ratios) < 4.0, ratios


def test_a_free_principal_point_makes_the_focal_less_certain():
    _, rec = _solved(1)
    held = calibration_uncertainty(rec, "a", noise_px=0.5, held_pp_std_fraction=0.0)
    free = calibration_uncertainty(rec, "a", noise_px=0.5, pp_refined=NAMES)
    for name in NAMES:
        assert free[name].principal_point_std_px > 0
        assert free[name].focal_std_px > held[name].focal_std_px
    # A rig mixing lenses: the principal points of some cameras are refined with the others'
    # intrinsics held (incremental.final_adjustment); the others keep the held-point sigmas.
    mixed = calibration_uncertainty(rec, "a", noise_px=0.5, pp_refined=NAMES[:2],
                                    held_pp_std_fraction=0.0)
    for name in NAMES[:2]:
        assert mixed[name].principal_point_std_px > 0
    for name in NAMES[2:]:
        assert mixed[name].principal_point_std_px is None
        assert mixed[name].focal_std_px == pytest.approx(held[name].focal_std_px, rel=1e-9)


def test_runs_that_disagree_widen_the_sigmas_by_their_spread_in_quadrature():
    sigmas = {"a": CameraUncertainty(3.0, 1.5, 0.4, 0.06), "b": CameraUncertainty(2.0, None, None),
              "g": CameraUncertainty(None, None, None)}  # given intrinsics: no sigmas
    widened = with_runs_spread(sigmas, {"a": (4.0, 0.3, 0.08, 2.0),
                                        "b": (0.0, float("nan"), 1.0, 3.0),
                                        "g": (5.0, 1.0, 1.0, 1.0)})
    assert widened["a"] == CameraUncertainty(5.0, 2.5, pytest.approx(0.5), pytest.approx(0.1))
    # b's point held (no sigma of its own): nothing to widen; a spread of 0 leaves a sigma
    assert widened["b"] == CameraUncertainty(2.0, None, None)
    held = with_runs_spread(sigmas, {"a": (0.0, 0.0, 0.0, 0.0)})
    assert held["a"] == sigmas["a"]
    assert widened["g"] == sigmas["g"]
    assert sigmas["a"].focal_std_px == 3.0  # the caller's are left as they were


@pytest.mark.parametrize("num_cameras", [2, 3, 5])
def test_the_residuals_of_a_fit_scaled_by_the_points_dof_give_the_pixel_noise(num_cameras):
    """camera_sigmas' noise: the points take 3 of each track's coordinates, so the residuals of
    points triangulated from the true cameras are smaller than the noise (a 2-view point's by
    half) and points_dof_factor scales them back."""
    from densecalib_ros.core.method.prior_adjustment import points_dof_factor
    from densecalib_ros.core.method.reconstruction import (SfMState, reprojection_errors,
                                                           triangulate_tracks)
    cams, poses = gt_rig(num_cameras, seed=1)
    tracks = gt_tracks(cams, poses, num_points=3000, noise_px=0.5, outlier_frac=0.0, seed=1)
    state = SfMState.create(tracks, cams)
    state.cam_from_world = [T.copy() for T in poses]
    triangulate_tracks(state, max_error_px=50.0)
    errors = reprojection_errors(state)
    errors = errors[np.isfinite(errors)]
    residual_px = float(np.sqrt(np.mean(errors ** 2) / 2.0))
    assert residual_px < 0.45  # short of the noise by what the points took
    noise_px = residual_px * points_dof_factor(len(errors), int(state.point_mask().sum()))
    assert noise_px == pytest.approx(0.5, rel=0.05)


def test_units_of_one_model_sharing_an_estimated_principal_point_get_each_units_spread():
    """Units of one model are estimated with one principal point (a fisheye rig's, refined by
    the SfM); each unit's own sits where its assembly put it, HELD_PP_STD_FRACTION of the long
    side per axis about theirs, which the shared block's covariance cannot show (a generated
    rig of three fisheye units: their points 3.4-14.1 px from the shared one, sigma 2.9 px)."""
    from densecalib_ros.core.calibration_result import rig_from_state
    from densecalib_ros.core.method.uncertainty import (HELD_PP_STD_FRACTION, camera_sigmas,
                                                       with_units_spread)

    sigmas = {"a": CameraUncertainty(3.0, 2.0, 1.0), "b": CameraUncertainty(2.0, None, 0.5),
              "c": CameraUncertainty(2.0, 2.0, 1.0)}
    widened = with_units_spread(sigmas, {"a": (1280, 960, "RADIAL"), "b": (1280, 960, "RADIAL")})
    unit_px = HELD_PP_STD_FRACTION * 1280
    assert widened["a"] == CameraUncertainty(3.0, pytest.approx(np.hypot(2.0, unit_px)),
                                             pytest.approx(np.hypot(1.0, np.sqrt(2) * unit_px)))
    assert widened["b"] == sigmas["b"]  # a held point has its offset in already
    assert widened["c"] == sigmas["c"]  # not a unit
    # camera_sigmas widens the units whose shared point was refined, and only those.
    cams, poses = gt_rig(4, seed=3)
    tracks = gt_tracks(cams, poses, num_points=800, noise_px=0.5, outlier_frac=0.0, seed=3)
    cfg = make_config("regular", sfm__num_threads=1, sfm__refine_principal_point=True)
    init = initial_intrinsics([(c.width, c.height) for c in cams],
                              [c.params[0] for c in cams], "RADIAL")
    result = run_incremental(tracks, init, NAMES[:4], cfg.sfm)
    rig = rig_from_state(result.state, NAMES[:4], [])
    rec, _ = build_reconstruction(result.state, NAMES[:4])
    units = cfg.with_options(cameras__identical_units=((("a", "b"), "the user's word"),))
    plain, _ = camera_sigmas(rig, rec, NAMES[:4], cfg)
    as_units, _ = camera_sigmas(rig, rec, NAMES[:4], units)
    side = max(cams[0].width, cams[0].height)
    for name in ("a", "b"):
        assert as_units[name].principal_point_std_px == pytest.approx(
            np.hypot(plain[name].principal_point_std_px, HELD_PP_STD_FRACTION * side))
    # (the covariance's threads round the last digits differently from call to call)
    for field in ("focal_std_px", "principal_point_std_px", "projection_std_px"):
        assert getattr(as_units["c"], field) == pytest.approx(getattr(plain["c"], field))
    assert as_units["a"].focal_std_px == pytest.approx(plain["a"].focal_std_px)
