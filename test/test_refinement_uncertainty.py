"""core.method.refinement_uncertainty: the image refinement's sigmas, the posterior covariance
beside the cluster-robust one over image regions, on exact projections of a point cloud
(sfm_fixtures) with noise that is independent, or shared within each image region."""
import numpy as np
import pytest
from sfm_fixtures import centred_state, gt_rig

from densecalib_ros.core.method.image_folds import track_regions
from densecalib_ros.core.method.prior_adjustment import Priors, adjust_with_priors
from densecalib_ros.core.method.reconstruction import triangulate_tracks
from densecalib_ros.core.method.refinement_uncertainty import (MIN_FRAME_SET_CLUSTERS,
                                                               camera_uncertainty,
                                                               held_point_std_px,
                                                               posterior_covariances)
from densecalib_ros.core.types import CameraIntrinsics

NUM_CAMERAS = 5


def _refined(shared_px: float, seed: int = 2, frame_sets: int = 1):
    """A 5-camera rig's tracks with 0.3 px of independent noise, plus shared_px of an offset
    each image region (track_regions) has in each camera, the tracks dealt out at random into
    `frame_sets` frame sets, adjusted with a principal point prior; and the true cameras."""
    cams, poses = gt_rig(NUM_CAMERAS, seed=seed, pp_jitter_px=0.0)
    true = [CameraIntrinsics("OPENCV", c.width, c.height,
                             np.r_[c.params[0], c.params[0], c.params[1:], 0.0, 0.0])
            for c in cams]
    state = centred_state(true, poses, 0.3, seed=seed)
    state.tracks.time_index[:] = np.random.default_rng(seed + 1).integers(
        0, frame_sets, state.tracks.num_tracks)
    if shared_px:
        region = track_regions(state)
        offset = np.random.default_rng(seed).normal(
            0.0, shared_px, (region.max() + 1, NUM_CAMERAS, 2))
        t, c = np.nonzero(state.tracks.observed())
        state.tracks.xy_px[t, c] += offset[region[t], c]
        triangulate_tracks(state, max_error_px=50.0)
    blocks = list(range(NUM_CAMERAS))
    priors = Priors({b: 10.0 for b in blocks}, {b: None for b in blocks})
    adjustment = adjust_with_priors(state, blocks, priors)
    return state, blocks, priors, adjustment.noise_px


def _focal_and_pp_stds(covariance: dict) -> np.ndarray:
    return np.array([[np.sqrt(c[0, 0]), np.sqrt(c[1, 1])] for c in covariance.values()])


def test_with_independent_errors_the_regions_agree_with_the_posterior():
    state, blocks, priors, noise_px = _refined(0.0)
    posterior, clustered = posterior_covariances(state, blocks, priors, noise_px,
                                                 track_regions(state)).marginals
    ratio = _focal_and_pp_stds(clustered) / _focal_and_pp_stds(posterior)
    assert np.all((ratio > 0.7) & (ratio < 1.4)), ratio
    assert 0.85 < np.median(ratio) < 1.15, ratio


def test_errors_shared_within_regions_widen_the_clustered_sigmas():
    state, blocks, priors, noise_px = _refined(0.3)
    posterior, clustered = posterior_covariances(state, blocks, priors, noise_px,
                                                 track_regions(state)).marginals
    ratio = _focal_and_pp_stds(clustered) / _focal_and_pp_stds(posterior)
    assert np.median(ratio) > 1.3, ratio


def test_a_refinement_over_frame_sets_adds_a_sandwich_clustered_by_frame_set():
    """Correspondences of one frame set share what that instant did to them (what moved, and how
    far the cameras' clocks and shutters stood apart meanwhile), which the sandwich over image
    regions, each region spanning every frame set, cannot see: a third covariance clusters the
    gradients by frame set, where there are at least MIN_FRAME_SET_CLUSTERS. Frame sets that
    coincide with the regions give the regions' sandwich; with independent errors it is about
    the posterior."""
    state, blocks, priors, noise_px = _refined(0.0, frame_sets=8)
    posterior, regions, frame_sets = posterior_covariances(
        state, blocks, priors, noise_px, track_regions(state)).marginals
    ratio = _focal_and_pp_stds(frame_sets) / _focal_and_pp_stds(posterior)
    assert 0.6 < np.median(ratio) < 1.6, ratio
    state.tracks.time_index[:] = track_regions(state)
    _, regions, frame_sets = posterior_covariances(state, blocks, priors, noise_px,
                                                   track_regions(state)).marginals
    for b in blocks:
        np.testing.assert_allclose(frame_sets[b], regions[b], rtol=1e-9, atol=1e-12)
    state.tracks.time_index[:] = np.arange(state.tracks.num_tracks) % (MIN_FRAME_SET_CLUSTERS - 1)
    assert len(posterior_covariances(state, blocks, priors, noise_px,
                                     track_regions(state)).marginals) == 2


def test_a_camera_reports_the_largest_sigma_each_source_gives():
    state, blocks, priors, noise_px = _refined(0.0)
    posterior, clustered = posterior_covariances(state, blocks, priors, noise_px,
                                                 track_regions(state)).marginals
    pair = (posterior[0], clustered[0])
    own = camera_uncertainty(state, 0, pair, {}, None)
    focal, pp = _focal_and_pp_stds({0: posterior[0], 1: clustered[0]}).max(axis=0)
    assert own.focal_std_px == pytest.approx(focal, rel=1e-6)
    assert own.principal_point_std_px == pytest.approx(
        max(np.sqrt(posterior[0][2, 2]), np.sqrt(clustered[0][2, 2]), pp), rel=1e-6)
    folds = dict(focal_px=3.0 * focal, principal_point_axes_px=(0.1, 4.0 * pp))
    wider = camera_uncertainty(state, 0, pair, folds, None)
    assert wider.focal_std_px == pytest.approx(3.0 * focal)
    assert wider.principal_point_std_px == pytest.approx(4.0 * pp)
    held = camera_uncertainty(state, 0, pair, folds, 6.4).principal_point_std_px
    assert held == pytest.approx(6.4)


def test_a_held_principal_points_sigma_weighs_the_folds_with_the_prior():
    """Held where the images' estimate and the prior weighed by their spreads put it, the point
    is as uncertain as that precision-weighted mean, per axis (the larger reported): the folds'
    6.4 px against a prior of 12.8 px gives 5.72 px; an axis the folds place to 0.85 px adds
    nothing beside it; folds that gave no sigma leave the prior's."""
    cam = CameraIntrinsics("RADIAL", 1280, 960, np.array([426.0, 640.0, 480.0, 0.0, 0.0]))
    folds = dict(principal_point_axes_px=(6.4, 0.85))
    assert held_point_std_px(cam, folds, 0.01) == pytest.approx(
        1.0 / np.sqrt(6.4 ** -2 + 12.8 ** -2))
    assert held_point_std_px(cam, dict(principal_point_axes_px=(np.inf, np.nan)), 0.01) == \
        pytest.approx(12.8)
    assert held_point_std_px(cam, {}, 0.01) == pytest.approx(12.8)


def test_a_video_frames_short_axis_has_the_wider_spread():
    """A 16:9 video frame is a window its firmware placed on a taller sensor, so its principal
    point's short-axis coordinate spreads wider than a lens centres it (real video cameras: 0.4-4.8
    % of the short side off): a point held there is that uncertain on that axis, though the prior
    that placed it stays 1 % of the long side; a still camera's 3:2 or 4:3 frame keeps 1 % of its
    long side on both, as a fisheye lens's frame does (no real one measured)."""
    from densecalib_ros.core.method.uncertainty import (CROPPED_FRAME_PP_STD_FRACTION,
                                                       principal_point_spread_px)
    assert principal_point_spread_px(1280, 960, "RADIAL") == pytest.approx((12.8, 12.8))
    assert principal_point_spread_px(1536, 1024, "OPENCV") == pytest.approx((15.36, 15.36))
    short = CROPPED_FRAME_PP_STD_FRACTION * 720
    assert principal_point_spread_px(1280, 720, "RADIAL") == pytest.approx((12.8, short))
    assert principal_point_spread_px(1088, 1920, "OPENCV") == pytest.approx(
        (CROPPED_FRAME_PP_STD_FRACTION * 1088, 19.2))
    assert principal_point_spread_px(1280, 720, "OPENCV_FISHEYE") == pytest.approx((12.8, 12.8))
    assert principal_point_spread_px(1280, 720, "RADIAL", 0.0) == (0.0, 0.0)
    video = CameraIntrinsics("RADIAL", 1280, 720, np.array([426.0, 640.0, 360.0, 0.0, 0.0]))
    assert held_point_std_px(video, {}, 0.01) == pytest.approx(short)
    # the folds place cy to 20 px: the held point takes 29 % of their estimate (against the
    # prior's 12.8 px), whose error adds to the 71 % of the truth's offset left out
    weight = 12.8 ** 2 / (12.8 ** 2 + 20.0 ** 2)
    assert held_point_std_px(video, dict(principal_point_axes_px=(6.4, 20.0)), 0.01) == \
        pytest.approx(np.hypot((1 - weight) * short, weight * 20.0))
    fisheye = CameraIntrinsics("OPENCV_FISHEYE", 1280, 720, np.r_[426.0, 426.0, 640.0, 360.0,
                                                                 np.zeros(4)])
    assert held_point_std_px(fisheye, dict(principal_point_axes_px=(6.4, 20.0)), 0.01) == \
        pytest.approx(1.0 / np.sqrt(20.0 ** -2 + 12.8 ** -2))


def test_the_projection_sigma_is_no_smaller_than_its_parts_reported():
    """Where the folds (or a held principal point's prior) widen the focal length's and the
    principal point's sigmas beyond the covariance's, the projection's widens with them: a
    principal point off by sigma moves every image point by about that much."""
    state, blocks, priors, noise_px = _refined(0.0)
    posterior, clustered = posterior_covariances(state, blocks, priors, noise_px,
                                                 track_regions(state)).marginals
    pair = (posterior[0], clustered[0])
    own = camera_uncertainty(state, 0, pair, {}, None)
    assert own.projection_std_px < own.principal_point_std_px * 4.0
    folds = dict(focal_px=3.0 * own.focal_std_px,
                 principal_point_axes_px=(0.1, 4.0 * own.principal_point_std_px))
    wider = camera_uncertainty(state, 0, pair, folds, None)
    assert wider.projection_std_px >= wider.principal_point_std_px > own.projection_std_px
    held = camera_uncertainty(state, 0, pair, folds, 6.4)
    assert held.projection_std_px >= held.principal_point_std_px
