"""Incremental SfM on tracks made from ground truth (exact projections + noise + outliers), so the
SfM stage is tested on its own: real pycolmap BA / absolute pose, no mocks."""
import os
from functools import partial

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np
import pytest

from densecalib_ros.core.config import make_config
from densecalib_ros.core.errors import NotEnoughCamerasError, NotEnoughOverlapError
from densecalib_ros.core.method.incremental import initial_intrinsics
from densecalib_ros.core.method.multistart import run_incremental
from densecalib_ros.core.metrics import evaluate_calibration
from densecalib_ros.core.calibration_result import rig_from_state
from densecalib_ros.core.method.reconstruction import (BAStage, SfMState, bundle_adjust,
                                                       build_reconstruction,
                                                       camera_reprojection_errors,
                                                       reprojection_errors, triangulate)
from densecalib_ros.core.types import CameraIntrinsics, Tracks
from densecalib_ros.core.method.view_order import view_order

import sfm_fixtures
from sfm_fixtures import gt_calibration


# This file's rigs have larger principal-point offsets and distortion, and its tracks more points,
# more outliers and unit scores, than test_global_sfm's; its thresholds were set on them.
gt_rig = partial(sfm_fixtures.gt_rig, pp_jitter_px=5.0, k1_range=(-0.1, 0.05), k2_max=0.02,
                 fisheye_draws_focal=True)
gt_tracks = partial(sfm_fixtures.gt_tracks, num_points=3000, outlier_frac=0.05,
                    random_scores=False)


def noisy_focals(cams, rel=0.05, seed=1):
    rng = np.random.default_rng(seed)
    return np.array([c.params[0] * (1 + rng.uniform(-rel, rel)) for c in cams])


def test_view_order_starts_with_best_triplet():
    obs = np.full((6, 4, 2), np.nan)
    obs[:3, [1, 2, 3]] = 1.0  # three tracks in triplet (1, 2, 3)
    obs[3:, [0, 1]] = 1.0  # pair-only camera 0
    tracks = Tracks(obs, np.array([3, 3, 3, 2, 2, 2], np.int32), np.ones(6), np.zeros(6, np.int32))
    order = view_order(tracks)
    assert sorted(order[:3]) == [1, 2, 3]
    assert order[3] == 0


def test_bundle_adjust_recovers_focal_from_perturbed_start():
    cams, poses = gt_rig(4, seed=3)
    tracks = gt_tracks(cams, poses, outlier_frac=0.0, seed=3)
    start = [CameraIntrinsics(c.model, c.width, c.height, np.r_[c.params[:3] * [1.03, 1, 1], 0, 0])
             for c in cams]
    state = SfMState.create(tracks, start)
    for c, T in enumerate(poses):
        state.cam_from_world[c] = T
    triangulate(state, np.arange(tracks.num_tracks), max_error_px=50.0)
    bundle_adjust(state, list("abcd"), BAStage(100), num_threads=1)
    for c, cam in enumerate(cams):
        assert abs(state.camera(c).params[0] / cam.params[0] - 1) < 0.005
    err = reprojection_errors(state)
    assert np.nanmedian(err) < 0.5
    rec, _ = build_reconstruction(state, list("abcd"))
    assert rec.num_reg_images() == 4 and rec.num_points3D() == int(state.point_mask().sum())


def test_one_cameras_reprojection_errors_are_the_column_of_every_cameras():
    """camera_reprojection_errors (what a pair registration judges its candidates on) gives
    reprojection_errors' column bit for bit: NaN for observations switched off, points not
    triangulated and a camera not registered, inf behind a camera."""
    cams, poses = gt_rig(4, seed=5)
    tracks = gt_tracks(cams, poses, num_points=400, outlier_frac=0.1, seed=5)
    state = SfMState.create(tracks, cams)
    for c, pose in enumerate(poses[:3]):  # camera 3 not registered
        state.cam_from_world[c] = pose
    triangulate(state, np.arange(tracks.num_tracks), max_error_px=50.0)
    state.active[::7, 1] = False
    state.points_xyz[5] = -2.0 * state.points_xyz[5]  # behind some camera: inf there
    err = reprojection_errors(state)
    assert np.isinf(err).any() and np.isnan(err[:, 3]).all()
    for c in range(4):
        np.testing.assert_array_equal(camera_reprojection_errors(state, c), err[:, c])


@pytest.mark.parametrize("model,preset", [("RADIAL", "regular"), ("OPENCV_FISHEYE", "fisheye")])
def test_incremental_recovers_ground_truth(model, preset):
    names = ["cam_a", "cam_b", "cam_c", "cam_d", "cam_e"]
    cams, poses = gt_rig(5, model=model, seed=7)
    tracks = gt_tracks(cams, poses, seed=7)
    cfg = make_config(preset, sfm__num_threads=1).sfm
    init = initial_intrinsics([(c.width, c.height) for c in cams], noisy_focals(cams),
                              cfg.camera_model)
    result = run_incremental(tracks, init, names, cfg)
    assert result.failed == []
    rig = rig_from_state(result.state, names, result.failed)
    metrics = evaluate_calibration(rig, gt_calibration(names, cams, poses))
    assert metrics["auc3"] > 85.0
    assert metrics["median_focal_err"] < 0.01
    assert rig.cameras["cam_a"].intrinsics.model == model
    # 5 % outliers stay in the reconstruction up to B_err (Cauchy loss), so the median (not the
    # RMS) of the reprojection errors shows the fit.
    assert np.nanmedian(reprojection_errors(result.state)) < 0.6
    for cam in rig.cameras.values():
        assert cam.quality.num_observations > 300
        # gt_tracks are seen by 2-5 cameras: most observations, not all, are multi-view ones.
        assert 0.5 * cam.quality.num_observations < cam.quality.num_multiview_observations \
            < cam.quality.num_observations
        assert cam.quality.coverage > 0.1


def test_multistart_on_a_subsample_is_finished_on_every_track(monkeypatch):
    """Rigs with more tracks than trial_max_tracks run the focal multi-start on a subsample;
    the winning trial's cameras are then finished on all tracks (not re-run from scratch)."""
    import densecalib_ros.core.method.multistart as multistart
    monkeypatch.setattr(multistart, "TRIAL_TRACKS_PER_CAMERA", 160)
    names = ["a", "b", "c", "d", "e"]
    cams, poses = gt_rig(5, seed=7)
    tracks = gt_tracks(cams, poses, seed=7)
    assert tracks.num_tracks > 2000
    cfg = make_config("regular", sfm__num_threads=1).sfm
    init = initial_intrinsics([(c.width, c.height) for c in cams], noisy_focals(cams), "RADIAL")
    messages = []
    result = run_incremental(tracks, init, names, cfg, progress=messages.append)
    assert result.failed == [] and result.state.tracks is tracks
    assert any(f"finished on all {tracks.num_tracks} tracks" in m for m in messages)
    # Points from (nearly) every inlier track, not only the subsample's 800 (5 % are outliers).
    assert result.state.point_mask().sum() > 0.85 * tracks.num_tracks
    rig = rig_from_state(result.state, names, result.failed)
    metrics = evaluate_calibration(rig, gt_calibration(names, cams, poses))
    assert metrics["auc3"] > 85.0 and metrics["median_focal_err"] < 0.01
    # An easy rig: the starts that fit about as well all end in this rig (settled), and a run
    # restricted to its two best starts tries only those.
    assert len(result.settled_starts) == multistart.SETTLED_STARTS
    messages = []
    again = run_incremental(tracks, init, names, cfg, seed=1, progress=messages.append,
                            only_starts=result.settled_starts)
    said = next(m for m in messages if m.startswith("focal multi-start:"))
    tried = said[said.index("(") + 1:].split(": ")[1:]
    assert len(tried) == 2 and again.settled_starts is None and again.failed == []


def test_the_multistart_settled_only_where_every_start_that_fits_as_well_ends_in_one_rig():
    """settled_starts: two or more trials register as many cameras as the best and fit within
    WORSE_FIT_RATIO of it, and all agree with it within AGREEMENT_DEG (mean over pairs)."""
    from densecalib_ros.core.method.multistart import (AGREEMENT_DEG, WORSE_FIT_RATIO,
                                                       settled_starts, states_disagreement_deg)

    cams, poses = gt_rig(4, seed=3)
    tracks = gt_tracks(cams, poses, seed=3)

    def state(turn_deg=0.0, registered=4):
        st = SfMState.create(tracks, cams)
        for c in range(registered):
            st.cam_from_world[c] = poses[c].copy()
        c, s = np.cos(np.radians(turn_deg)), np.sin(np.radians(turn_deg))
        turn = np.eye(4)  # about camera 1's own centre
        turn[:3, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
        st.cam_from_world[1] = turn @ st.cam_from_world[1]
        return st

    # Turning one camera of four by 3 deg changes 3 of 6 pairs by 3 deg: 1.5 deg on the mean.
    assert states_disagreement_deg(state(), state(3.0)) == pytest.approx(1.5)
    assert states_disagreement_deg(state(), state(registered=3)) == pytest.approx(90.0)
    same = {"x1.00": state(), "x1.30": state(0.1), "prior 1.2": state(0.2)}
    costs = {"x1.00": (-4, 0.80), "x1.30": (-4, 0.79), "prior 1.2": (-4, 0.81)}
    assert settled_starts(costs, same) == ["x1.30", "x1.00"]
    # A start that fits about as well but ends elsewhere: the focal lengths are in doubt.
    other = {**same, "prior 2.4": state(4.0)}
    assert AGREEMENT_DEG < 2.0
    assert settled_starts({**costs, "prior 2.4": (-4, 0.9)}, other) is None
    # ... unless it fits clearly worse, or registered fewer cameras: a wrong rig, not a doubt.
    assert settled_starts({**costs, "prior 2.4": (-4, 0.79 * WORSE_FIT_RATIO + 0.01)},
                          other) == ["x1.30", "x1.00"]
    assert settled_starts({**costs, "prior 2.4": (-3, 0.5)}, other) == ["x1.30", "x1.00"]
    # A lone winner (no second start reached it) is not settled.
    assert settled_starts({"x1.00": (-4, 0.8), "prior 2.4": (-4, 2.0)}, other) is None


def test_focal_starts_are_eq2_scales_and_generic_priors_for_perspective_models():
    """Perspective models start from eq. 2 scaled and from every generic prior (ratio x the long
    side, for every camera alike, even where that is close to a scaled start); fisheye models,
    whose initial focal is a lens-model prior already, only from the scales."""
    from densecalib_ros.core.method.multistart import focal_starts

    sizes = [(1024, 768), (1024, 768), (800, 600)]
    starts = focal_starts(initial_intrinsics(sizes, np.array([1200.0, 1150.0, 1300.0]), "RADIAL"))
    assert set(starts) == {"x1.00", "x1.30", "x0.80", "x1.69", "prior 1.2", "prior 0.85",
                           "prior 0.6", "prior 1.7", "prior 2.4"}
    assert [c.params[0] for c in starts["prior 0.85"]] == pytest.approx([870.4, 870.4, 680.0])
    assert [c.params[0] for c in starts["x1.30"]] == pytest.approx([1560.0, 1495.0, 1690.0])
    fisheye = focal_starts(initial_intrinsics(sizes, np.full(3, 300.0), "OPENCV_FISHEYE"))
    assert set(fisheye) == {"x1.00", "x1.30", "x0.80"}


def test_identical_cameras_share_one_intrinsics_block():
    names = ["a", "b", "c", "d"]
    cams, poses = gt_rig(4, seed=11)
    cams = [cams[0]] * 4  # identical units
    tracks = gt_tracks(cams, poses, seed=11)
    cfg = make_config("regular", sfm__share_intrinsics=True, sfm__num_threads=1).sfm
    init = initial_intrinsics([(c.width, c.height) for c in cams], noisy_focals(cams), "RADIAL")
    result = run_incremental(tracks, init, names, cfg)
    assert result.failed == [] and len(result.state.intrinsics) == 1
    rig = rig_from_state(result.state, names, result.failed)
    for cam in rig.cameras.values():
        np.testing.assert_array_equal(cam.intrinsics.params, rig.cameras["a"].intrinsics.params)
    assert abs(rig.cameras["a"].intrinsics.params[0] / cams[0].params[0] - 1) < 0.005
    assert evaluate_calibration(rig, gt_calibration(names, cams, poses))["auc3"] > 85.0


def test_shared_intrinsics_in_a_rig_mixing_lenses_stay_within_one_lens():
    """Three identical pinhole units and a fisheye of the same image size: share_intrinsics gives
    the pinhole cameras one block and the fisheye its own, refined to its lens's model."""
    from densecalib_ros.core.config import resolve_camera_lenses

    names = ["a", "b", "c", "d"]
    pinhole, poses = gt_rig(4, seed=11)
    fisheye, _ = gt_rig(4, model="OPENCV_FISHEYE", seed=11)
    cams = [pinhole[0]] * 3 + [fisheye[3]]
    tracks = gt_tracks(cams, poses, seed=11)
    cfg = resolve_camera_lenses(make_config("regular", cameras__lens={"d": "fisheye"},
                                            sfm__share_intrinsics=True, sfm__num_threads=1),
                                names).sfm
    init = initial_intrinsics([(c.width, c.height) for c in cams], noisy_focals(cams),
                              cfg.models(4))
    result = run_incremental(tracks, init, names, cfg)
    assert result.failed == [] and len(result.state.intrinsics) == 2
    rig = rig_from_state(result.state, names, result.failed)
    assert [rig.cameras[n].intrinsics.model for n in names] == ["RADIAL"] * 3 + ["OPENCV_FISHEYE"]
    for n in "bc":
        np.testing.assert_array_equal(rig.cameras[n].intrinsics.params,
                                      rig.cameras["a"].intrinsics.params)
    for n, cam in zip(names, cams):
        assert abs(rig.cameras[n].intrinsics.params[0] / cam.params[0] - 1) < 0.01, n
    assert evaluate_calibration(rig, gt_calibration(names, cams, poses))["auc3"] > 85.0


def test_two_cameras_without_shared_tracks_is_not_enough_overlap():
    cams, poses = gt_rig(3, seed=2)
    tracks = gt_tracks(cams, poses, seed=2)
    obs = tracks.xy_px.copy()
    obs[:, 1:] = np.nan  # only camera 0 observes anything
    tracks = Tracks(obs, tracks.cycle_order, tracks.score, tracks.time_index)
    cfg = make_config("regular").sfm
    init = initial_intrinsics([(c.width, c.height) for c in cams], noisy_focals(cams), "RADIAL")
    with pytest.raises(NotEnoughOverlapError):
        run_incremental(tracks, init, ["a", "b", "c"], cfg)


def test_camera_without_overlap_is_named_as_failed():
    names = ["a", "b", "c", "d"]
    cams, poses = gt_rig(4, seed=4)
    tracks = gt_tracks(cams, poses, seed=4)
    obs = tracks.xy_px.copy()
    obs[:, 3] = np.nan
    keep = (~np.isnan(obs[..., 0])).sum(axis=1) >= 2
    tracks = Tracks(obs[keep], tracks.cycle_order[keep], tracks.score[keep],
                    tracks.time_index[keep])
    cfg = make_config("regular", sfm__num_threads=1).sfm
    init = initial_intrinsics([(c.width, c.height) for c in cams], noisy_focals(cams), "RADIAL")
    result = run_incremental(tracks, init, names, cfg)
    rig = rig_from_state(result.state, names, result.failed)
    assert rig.failed_cameras == ["d"]
    assert set(rig.cameras) == {"a", "b", "c"}
    assert rig.reference_camera == "a"
    np.testing.assert_allclose(rig.cameras["a"].cam_from_rig, np.eye(4), atol=1e-12)


def test_too_few_tracks_for_a_relative_pose_is_not_enough_overlap():
    cams, poses = gt_rig(2, seed=5)
    tracks = gt_tracks(cams, poses, num_points=10, seed=5)  # too few for any relative pose
    cfg = make_config("regular").sfm
    init = initial_intrinsics([(c.width, c.height) for c in cams], noisy_focals(cams), "RADIAL")
    with pytest.raises(NotEnoughOverlapError):
        run_incremental(tracks, init, ["a", "b"], cfg)


def test_rig_from_one_registered_camera_is_an_error():
    cams, poses = gt_rig(3, seed=6)
    state = SfMState.create(gt_tracks(cams, poses, seed=6), cams)
    state.cam_from_world[1] = poses[1]
    with pytest.raises(NotEnoughCamerasError, match="b"):
        rig_from_state(state, ["a", "b", "c"], failed=[0, 2])


def two_view_only(tracks, camera):
    """Tracks where `camera` is only ever seen together with one other camera (2-cycle tracks), as
    on wide-baseline rigs where few 3-cycles close: it cannot register from 3D points."""
    xy = tracks.xy_px.copy()
    obs = ~np.isnan(xy[:, :, 0])
    for t in np.flatnonzero(obs[:, camera] & (obs.sum(axis=1) > 2)):
        others = np.flatnonzero(obs[t])
        partner = others[others != camera][t % (len(others) - 1)]
        xy[t, [c for c in others if c not in (camera, partner)]] = np.nan
    order = (~np.isnan(xy[:, :, 0])).sum(axis=1).astype(np.int32)
    return Tracks(xy, order, tracks.score, tracks.time_index)


def test_pair_registration_picks_the_focal_that_fits_the_two_view_tracks():
    """A camera seen in 2-view tracks only is placed from its relative poses; its focal is still
    the (here 40 % low) initial estimate, so registration tries focal candidates and keeps the one
    that reprojects best: it must land near the true focal, and the pose near the truth."""
    from densecalib_ros.core.method.incremental import register_from_pairs
    from densecalib_ros.core.method.reconstruction import triangulate

    cams, poses = gt_rig(5, seed=11)
    tracks = two_view_only(gt_tracks(cams, poses, num_points=1500, outlier_frac=0.02, seed=11), 4)
    init = [CameraIntrinsics(c.model, c.width, c.height, c.params.copy()) for c in cams]
    init[4].params[0] *= 0.6
    state = SfMState.create(tracks, init)
    for c in range(4):
        state.cam_from_world[c] = poses[c].copy()
    rows = np.flatnonzero(state.registered_active().sum(axis=1) >= 2)
    triangulate(state, rows, 20.0)
    assert register_from_pairs(state, 4, list("abcde"), seed=0, max_error_px=20.0, num_threads=1)
    focal = state.camera(4).params[0]
    assert abs(focal / cams[4].params[0] - 1) < 0.1
    R_err = state.cam_from_world[4][:3, :3] @ poses[4][:3, :3].T
    assert np.degrees(np.arccos(np.clip((np.trace(R_err) - 1) / 2, -1, 1))) < 2.0


def test_pair_registration_tries_each_partner_orientation_not_only_the_best_supported():
    """A camera seen in 2-view tracks only, whose best-supported partner's matches are consistent
    but wrong (as for cameras facing each other across a ring): those tracks alone say the camera
    is rolled 120 deg. The orientation the other partners agree on fits more of the camera's
    tracks and must win over the partner with the most tracks."""
    from densecalib_ros.core.method.incremental import register_from_pairs

    cams, poses = gt_rig(5, seed=11)
    tracks = two_view_only(gt_tracks(cams, poses, num_points=1500, outlier_frac=0.02, seed=11), 4)
    obs = ~np.isnan(tracks.xy_px[:, :, 0])
    partner_of = {t: int(np.flatnonzero(obs[t])[np.flatnonzero(obs[t]) != 4][0])
                  for t in np.flatnonzero(obs[:, 4])}
    counts = np.bincount(list(partner_of.values()), minlength=4)
    wrong = int(np.argmax(counts))
    assert counts[wrong] < counts.sum() / 2  # the truth keeps the majority of the camera's tracks
    rows = [t for t, p in partner_of.items() if p == wrong]
    roll = np.radians(120.0)
    ghost_from_cam = np.array([[np.cos(roll), -np.sin(roll), 0.0],
                               [np.sin(roll), np.cos(roll), 0.0], [0.0, 0.0, 1.0]])
    camera = cams[4].to_pycolmap()
    xy = tracks.xy_px.copy()
    rays = np.column_stack([camera.cam_from_img(xy[rows, 4]), np.ones(len(rows))])
    xy[rows, 4] = camera.img_from_cam(rays @ ghost_from_cam.T)
    tracks = Tracks(xy, tracks.cycle_order, tracks.score, tracks.time_index)

    state = SfMState.create(tracks, cams)
    for c in range(4):
        state.cam_from_world[c] = poses[c].copy()
    triangulate(state, np.flatnonzero(state.registered_active().sum(axis=1) >= 2), 20.0)
    assert register_from_pairs(state, 4, list("abcde"), seed=0, max_error_px=20.0, num_threads=1)
    R_err = state.cam_from_world[4][:3, :3] @ poses[4][:3, :3].T
    assert np.degrees(np.arccos(np.clip((np.trace(R_err) - 1) / 2, -1, 1))) < 2.0


def test_held_out_cost_counts_raw_matches_at_the_inlier_scale_not_b_err():
    """Raw keypoint matches are judged at HELD_OUT_TRUNCATION_PX whatever B_err: a wrong match
    costs that much, not 20 px, so many wrong matches (repetitive texture) cannot outweigh how
    well a rig fits the right ones; a camera turned by 0.3 deg still costs more."""
    from densecalib_ros.core.method.multistart import HELD_OUT_TRUNCATION_PX, held_out_cost
    from scipy.spatial.transform import Rotation

    cams, poses = gt_rig(4, seed=5)
    raw = gt_tracks(cams, poses, num_points=1500, outlier_frac=0.4, seed=5)
    state = SfMState.create(raw, cams)
    for c, T in enumerate(poses):
        state.cam_from_world[c] = T
    right = held_out_cost(state, raw, truncation_px=20.0, seed=0)
    assert right == pytest.approx(held_out_cost(state, raw, HELD_OUT_TRUNCATION_PX, seed=0))
    # ~40 % of the tracks hold one wrong observation of 2-4: at 20 px they cost 3.9 px.
    assert 0.3 < right < 2.0
    turned = state.on_tracks(raw)
    turned.cam_from_world[2] = turned.cam_from_world[2].copy()
    turned.cam_from_world[2][:3, :3] = Rotation.from_euler("y", 0.3, degrees=True).as_matrix() \
        @ turned.cam_from_world[2][:3, :3]
    assert held_out_cost(turned, raw, 20.0, seed=0) > right + 0.05


def test_truncated_cost_per_camera_truncation():
    """A rig mixing lenses truncates each camera's errors at its own B_err (pinhole 20 px,
    fisheye 100 px): the cost equals the hand-computed mean, and one value for all cameras
    is the same as that value per camera."""
    from densecalib_ros.core.config import resolve_camera_lenses
    from densecalib_ros.core.method.multistart import cost_truncation_px, truncated_cost
    from densecalib_ros.core.method.reconstruction import reprojection_errors, triangulate_tracks

    cams, poses = gt_rig(4, seed=2)
    tracks = gt_tracks(cams, poses, num_points=600, outlier_frac=0.2, seed=2)
    state = SfMState.create(tracks, cams)
    for c, pose in enumerate(poses):
        state.cam_from_world[c] = pose
    triangulate_tracks(state, max_error_px=100.0)
    names = ["a", "b", "c", "d"]
    cfg = resolve_camera_lenses(make_config("regular", cameras__lens={"b": "fisheye"}), names).sfm
    trunc = cost_truncation_px(cfg, 4)
    assert list(trunc) == [20.0, 100.0, 20.0, 20.0]
    err = reprojection_errors(state)
    obs = tracks.observed() & (tracks.observed().sum(1) >= 2)[:, None]
    expect = np.where(np.isfinite(err), np.minimum(err, trunc[None, :]), trunc[None, :])[obs].mean()
    assert truncated_cost(state, trunc) == pytest.approx(expect)
    assert truncated_cost(state, 20.0) == pytest.approx(truncated_cost(state, np.full(4, 20.0)))
    assert truncated_cost(state, 20.0) < truncated_cost(state, trunc)  # outliers count more at 100
    assert cost_truncation_px(make_config("regular").sfm, 4) == 20.0  # one lens: one value


def test_first_pair_starts_are_the_pairs_sharing_most_tracks():
    """With every camera's intrinsics given the multi-start runs from first pairs instead of
    focals: those sharing at least MIN_PAIR_CORRESPONDENCES tracks, most first, at most
    MAX_FIRST_PAIR_STARTS."""
    from densecalib_ros.core.method.incremental import MIN_PAIR_CORRESPONDENCES
    from densecalib_ros.core.method.multistart import MAX_FIRST_PAIR_STARTS, first_pair_starts

    counts = {(0, 1): 40, (0, 2): MIN_PAIR_CORRESPONDENCES, (1, 2): 60,
              (2, 3): MIN_PAIR_CORRESPONDENCES - 1}
    rows = []
    for (i, j), n in counts.items():
        for _ in range(n):
            xy = np.full((4, 2), np.nan)
            xy[[i, j]] = 1.0
            rows.append(xy)
    T = len(rows)
    tracks = Tracks(np.array(rows), np.full(T, 2, np.int32), np.zeros(T), np.zeros(T, np.int32))
    assert first_pair_starts(tracks) == [(1, 2), (0, 1), (0, 2)]
    many = Tracks(np.zeros((20, 10, 2)), np.full(20, 2, np.int32), np.zeros(20),
                  np.zeros(20, np.int32))  # every camera sees every track
    assert len(first_pair_starts(many)) == MAX_FIRST_PAIR_STARTS


def test_camera_no_point_of_the_final_fit_observes_is_left_out():
    """A camera whose observations the refinement's gates all took (keypoints far noisier than
    the gates) keeps whatever pose and intrinsics the last step left: it must not be published
    as calibrated (a 4-camera rig from keypoints alone came out with f 930 % off and k2 7e4,
    no point in the fit and no warning)."""
    from densecalib_ros.core.method.reconstruction import triangulate_tracks
    from densecalib_ros.core.stages.runs import unsupported_cameras

    cams, poses = gt_rig(3, seed=7)
    state = SfMState.create(gt_tracks(cams, poses, seed=7), cams)
    state.cam_from_world = [T.copy() for T in poses]
    triangulate_tracks(state)
    messages = []
    assert unsupported_cameras(state, ["a", "b", "c"], messages.append) == []
    state.active[:, 2] = False  # every observation of c gated out
    assert unsupported_cameras(state, ["a", "b", "c"], messages.append) == [2]
    assert state.registered() == [0, 1]
    assert messages and messages[0].startswith("c left out: 0 points")
    rig = rig_from_state(state, ["a", "b", "c"], failed=[2])
    assert sorted(rig.cameras) == ["a", "b"] and rig.failed_cameras == ["c"]
