"""core.method.image_folds: the view jackknife of intrinsics several views share, and what it
does to the image refinement's verdict on the principal point (determined_by_images), on exact
projections of a point cloud (sfm_fixtures) seen by one camera from six places."""
import numpy as np
from sfm_fixtures import gt_rig, gt_tracks

from densecalib_ros.core.method import image_folds
from densecalib_ros.core.method.image_folds import (JACKKNIFE_MIN_VIEWS, determined_by_folds,
                                                    determined_by_images, one_camera_jackknife,
                                                    view_jackknife)
from densecalib_ros.core.method.prior_adjustment import Priors
from densecalib_ros.core.method.reconstruction import SfMState, triangulate_tracks
from densecalib_ros.core.types import CameraIntrinsics

NUM_VIEWS = 6
PP_PRIOR_PX = 6.4  # 1 % of the long side


def test_the_jackknife_spreads_the_estimates_left_one_view_out():
    values = {0: 10.0, 1: 12.0, 2: 9.0, 3: 11.0, 4: 13.0}
    spread = view_jackknife({0: list(values)},
                            lambda c: {0: (values[c], 0.0, 0.0, 500.0 + c, 0.0, 0.0)})
    v = np.array(list(values.values()))
    expected = np.sqrt((len(v) - 1) / len(v) * ((v - v.mean()) ** 2).sum())
    assert np.isclose(spread[0][0], expected)
    assert spread[0][1] == 0.0 and np.isclose(spread[0][3], expected)


def test_no_jackknife_for_few_views_or_where_more_than_one_adjustment_failed():
    few = list(range(JACKKNIFE_MIN_VIEWS - 1))
    assert view_jackknife({0: few}, lambda c: {0: (float(c),) * 6}) == {}
    views = list(range(JACKKNIFE_MIN_VIEWS + 1))
    assert view_jackknife({0: views}, lambda c: None if c < 2 else {0: (float(c),) * 6}) == {}
    assert 0 in view_jackknife({0: views}, lambda c: None if c < 1 else {0: (float(c),) * 6})


def test_a_floor_holds_a_point_the_folds_agree_on():
    priors = Priors({0: PP_PRIOR_PX}, {0: 0.003})
    folds = [{0: (320.0 + d, 240.0 - d, 0.0, 500.0, 0.0, 0.0, 0.0, 0.0)}
             for d in (0.1, -0.1, 0.2, 0.0)]
    determined, sigmas = determined_by_folds(folds, [0], priors)
    assert "principal point" in determined[0]
    floor = np.array([0.5, 4.0, 0.0, 2.0, 0.0, 0.0, 0.0, 0.0])
    determined, sigmas = determined_by_folds(folds, [0], priors, {0: floor})
    assert "principal point" not in determined[0]
    assert sigmas[0]["principal_point_axes_px"][1] == 4.0 and sigmas[0]["focal_px"] == 2.0


def _one_camera(biased_view_px: float, share: bool = True) -> SfMState:
    """Six views of one 640x480 camera (one intrinsics block) at their true poses, 0.2 px of
    noise; one view's observations shifted up by biased_view_px (what a camera path that trades
    the principal point against the views' pitch leaves in one of them); principal point at the
    image centre, points triangulated: what the pipeline hands the image refinement. share:
    one block for the six (one camera); else a block each (separate cameras)."""
    cams, poses = gt_rig(NUM_VIEWS, seed=4, pp_jitter_px=0.0)
    true = [cams[0]] * NUM_VIEWS
    tracks = gt_tracks(true, poses, num_points=2000, noise_px=0.2, outlier_frac=0.0, seed=4)
    tracks.xy_px[:, 2, 1] -= biased_view_px
    state = SfMState.create(tracks, [CameraIntrinsics("RADIAL", 640, 480, cams[0].params)] *
                            NUM_VIEWS, share_intrinsics=share)
    state.cam_from_world = [T.copy() for T in poses]
    triangulate_tracks(state, max_error_px=50.0)
    return state


def test_a_view_that_moves_the_shared_point_widens_its_sigma_and_holds_it(monkeypatch):
    priors = Priors({0: PP_PRIOR_PX}, {0: 0.003})
    state = _one_camera(16.0)
    determined, sigmas = determined_by_images(state, [0], priors)
    assert "principal point" not in determined[0]
    widened = max(sigmas[0]["principal_point_axes_px"])
    # the spatial folds alone: every fold shares the biased view, and they agree
    monkeypatch.setattr(image_folds, "JACKKNIFE_MIN_VIEWS", NUM_VIEWS + 1)
    determined, sigmas = determined_by_images(state, [0], priors)
    assert "principal point" in determined[0]
    assert widened > 3 * max(sigmas[0]["principal_point_axes_px"])


def test_views_that_agree_keep_the_point_determined():
    state = _one_camera(0.0)
    determined, _ = determined_by_images(state, [0],
                                         Priors({0: PP_PRIOR_PX}, {0: 0.003}))
    assert "principal point" in determined[0]


def test_separate_cameras_tied_as_one_are_resampled_over_their_views():
    """The six views as six cameras that the one-camera test ties as one (every intrinsic
    held to the others as a shared one would be): the jackknife over their views is the shared
    block's, which sees the biased view."""
    members = list(range(NUM_VIEWS))
    # f, cx, cy (px), k1, k2, aspect: a hundredth of their standard errors, as rig_pooling ties
    ties = [(i, dict.fromkeys(members, sigma))
            for i, sigma in enumerate((0.01, 0.01, 0.01, 1e-5, 1e-5, 1e-6))]
    spreads = {}
    for bias_px in (0.0, 16.0):
        tied = one_camera_jackknife(_one_camera(bias_px, share=False), members, members, ties)
        shared = view_jackknife({0: members}, lambda c: image_folds._free_estimate(
            image_folds._without_view(_one_camera(bias_px), c), [0]))[0]
        assert np.allclose(tied, shared, rtol=0.05), (tied, shared)
        spreads[bias_px] = tied
    assert spreads[16.0][1] > 4 * spreads[0.0][1], spreads  # cy
    assert spreads[16.0][3] > 4 * spreads[0.0][3], spreads  # focal length
