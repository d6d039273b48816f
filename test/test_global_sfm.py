"""Global SfM (core/method/global_sfm.py) on tracks made from ground truth (exact projections +
noise + outliers): real pycolmap rotation averaging, global positioning, triangulation and BA."""
import os
from dataclasses import replace

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np
import pytest

from densecalib_ros.core.config import make_config
from densecalib_ros.core.errors import DisconnectedViewGraphError, InputError
from densecalib_ros.core.method.global_sfm import (CENTRE_GRID, gauge_scores,
                                                   rotation_averaging_poses, run_global,
                                                   snapped_centres, staged_bundle_adjustment,
                                                   to_gauge_frame, triangulate_tracks)
from densecalib_ros.core.method.incremental import initial_intrinsics
from densecalib_ros.core.metrics import evaluate_calibration, relative_pose_errors
from densecalib_ros.core.calibration_result import rig_from_state
from densecalib_ros.core import calibrate_from_tracks
from densecalib_ros.core.method.reconstruction import SfMState, reprojection_errors
from densecalib_ros.core.types import CameraIntrinsics, RigCalibration, RigCamera

from sfm_fixtures import gt_calibration, gt_rig, gt_tracks

NAMES = ["front", "left", "right", "top", "back"]


def rotation(axis, deg):
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    a = np.radians(deg)
    return np.eye(3) + np.sin(a) * K + (1 - np.cos(a)) * K @ K


def perturbed(cams, poses, rot_deg=2.0, move_frac=0.05, focal_frac=0.05, seed=1):
    """Cameras turned by rot_deg, centres moved by move_frac of the mean distance between camera
    centres, focal lengths scaled by 1 +- focal_frac, distortion zeroed (a bumped, refocused
    rig)."""
    rng = np.random.default_rng(seed)
    centres = np.array([-T[:3, :3].T @ T[:3, 3] for T in poses])
    spread = np.mean(np.linalg.norm(centres[:, None] - centres[None], axis=2)[np.triu_indices(len(poses), 1)])
    out_cams, out_poses = [], []
    for cam, T in zip(cams, poses):
        R = rotation(rng.normal(size=3), rot_deg) @ T[:3, :3]
        move = rng.normal(size=3)
        centre = -T[:3, :3].T @ T[:3, 3] + move_frac * spread * move / np.linalg.norm(move)
        P = np.eye(4)
        P[:3, :3], P[:3, 3] = R, -R @ centre
        out_poses.append(P)
        p = np.array(cam.params, float)
        scale = 1 + focal_frac * rng.choice([-1, 1])
        if cam.model == "RADIAL":
            p[0] *= scale
            p[3:] = 0.0
        else:
            p[:2] *= scale
            p[4:] = 0.0
        out_cams.append(CameraIntrinsics(cam.model, cam.width, cam.height, p))
    return out_cams, out_poses


def sfm_config(preset, **stages):
    cfg = make_config(preset, "global", sfm__num_threads=1).sfm
    return replace(cfg, global_stage_iterations={**cfg.global_stage_iterations, **stages})


def test_rotation_averaging_recovers_truth_from_exact_tracks():
    cams, poses = gt_rig(seed=3)
    tracks = gt_tracks(cams, poses, noise_px=0.0, outlier_frac=0.0, seed=3)
    est = rotation_averaging_poses(tracks, cams, NAMES)
    errors = relative_pose_errors(dict(zip(NAMES, est)), dict(zip(NAMES, poses)))
    assert max(e.rot_err_deg for e in errors) < 0.05
    assert max(e.trans_dir_err_deg for e in errors) < 0.5


def _centres(poses):
    return np.array([-T[:3, :3].T @ T[:3, 3] for T in poses])


def test_global_positioning_gives_the_same_poses_every_run():
    """pycolmap's positioning runs Ceres on every core, whose sums come out in varying order;
    the poses it hands on are the same from run to run all the same (snapped_centres)."""
    cams, poses = gt_rig(seed=3)
    tracks = gt_tracks(cams, poses, noise_px=0.5, outlier_frac=0.05, seed=3)
    runs = [rotation_averaging_poses(tracks, cams, NAMES) for _ in range(4)]
    for run in runs[1:]:
        for T, T0 in zip(run, runs[0]):
            np.testing.assert_array_equal(T, T0)


def test_snapped_centres_absorb_noise_far_below_the_grid_and_keep_the_rig():
    cams, poses = gt_rig(seed=3)
    rng = np.random.default_rng(0)
    centres = _centres(poses)
    size = np.median(np.linalg.norm(centres[1:] - centres[0], axis=1))
    snapped = snapped_centres(poses)
    moved = []
    for T in poses:  # each centre moved by ~1e-9 of the rig's size, as a thread reordering does
        P = T.copy()
        P[:3, 3] -= P[:3, :3] @ (1e-9 * size * rng.normal(size=3))
        moved.append(P)
    for T, T_moved, T_orig in zip(snapped, snapped_centres(moved), poses):
        np.testing.assert_array_equal(T, T_moved)
        np.testing.assert_array_equal(T[:3, :3], T_orig[:3, :3])  # rotations untouched
    got = _centres(snapped)
    assert np.all(got[0] == 0.0)  # camera 0 at the origin
    assert np.abs(got - (centres - centres[0])).max() <= 2 * CENTRE_GRID * size


def test_gauge_frame_is_the_gauge_camera_and_keeps_residuals():
    cams, poses = gt_rig(seed=4)
    tracks = gt_tracks(cams, poses, seed=4)
    state = SfMState.create(tracks, cams)
    state.cam_from_world = [T.copy() for T in poses]
    triangulate_tracks(state)
    before = reprojection_errors(state)
    to_gauge_frame(state, 2)
    np.testing.assert_allclose(state.cam_from_world[2], np.eye(4), atol=1e-12)
    centres = [np.linalg.inv(T)[:3, 3] for c, T in enumerate(state.cam_from_world) if c != 2]
    assert np.median(np.linalg.norm(centres, axis=1)) == pytest.approx(1.0)
    np.testing.assert_allclose(reprojection_errors(state), before, atol=1e-6)


def test_staged_bundle_adjustment_converges_from_perturbed_start():
    cams, poses = gt_rig(seed=5)
    tracks = gt_tracks(cams, poses, seed=5)
    gt = gt_calibration(NAMES, cams, poses)
    start_cams, start_poses = perturbed(cams, poses)
    state = SfMState.create(tracks, start_cams)
    state.cam_from_world = [T.copy() for T in start_poses]
    before = evaluate_calibration(rig_from_state(state, NAMES, []), gt)
    assert before["auc3"] < 40  # a 2 deg / 5 % bump is far outside the AUC@3 thresholds
    triangulate_tracks(state)
    gauge = int(np.argmax(gauge_scores(tracks)))
    to_gauge_frame(state, gauge)
    start_poses = [T.copy() for T in state.cam_from_world]
    pose_before = state.cam_from_world[gauge].copy()
    rms = staged_bundle_adjustment(state, NAMES, sfm_config("regular", distortion=200), gauge)
    assert list(rms) == ["extrinsics", "focal", "distortion"]
    # 0.3 px noise per axis; extrinsics alone cannot absorb a 5 % focal error.
    assert rms["distortion"]["median_px"] < 0.3 < rms["extrinsics"]["median_px"]
    np.testing.assert_allclose(state.cam_from_world[gauge], pose_before, atol=1e-12)
    # The scale is held too (COLMAP's gauge on one translation component of another camera).
    spread = [sum(np.linalg.norm(np.linalg.inv(T)[:3, 3] - np.linalg.inv(poses_[gauge])[:3, 3])
                  for T in poses_) for poses_ in (start_poses, state.cam_from_world)]
    assert 0.9 < spread[1] / spread[0] < 1.1
    after = evaluate_calibration(rig_from_state(state, NAMES, []), gt)
    assert after["auc3"] > 90
    assert after["median_focal_err"] < 0.005


@pytest.mark.parametrize("model,preset", [("RADIAL", "regular"), ("OPENCV_FISHEYE", "fisheye")])
def test_global_from_rotation_averaging_recovers_truth(model, preset):
    cams, poses = gt_rig(model=model, seed=7)
    tracks = gt_tracks(cams, poses, seed=7)
    focal = np.array([c.params[0] for c in cams]) * np.array([1.04, 0.97, 1.05, 0.96, 1.02])
    cfg = sfm_config(preset, distortion=200)
    cfg = replace(cfg, global_multistart=False)  # the rotation-averaging start on its own
    init = initial_intrinsics([(c.width, c.height) for c in cams], focal, cfg.camera_model)
    result = run_global(tracks, init, NAMES, cfg)
    assert result.failed == []
    assert result.quality.global_init == "rotation_averaging"
    stages = result.quality.stage_residuals
    assert list(stages)[:2] == ["triangulation", "extrinsics"]
    assert ("model" in stages) == (preset == "fisheye")
    # The 3 % outlier observations take part in BA (robust loss) but are left out of the result.
    assert result.quality.num_outlier_observations > 0
    rig = rig_from_state(result.state, NAMES, result.failed)
    assert rig.quality.reprojection_rms_px < 0.6
    assert rig.cameras["front"].intrinsics.model == model
    metrics = evaluate_calibration(rig, gt_calibration(NAMES, cams, poses))
    assert metrics["auc3"] > 90
    assert metrics["median_focal_err"] < 0.01


def test_recalibration_from_previous_matches_from_scratch():
    cams, poses = gt_rig(seed=11)
    tracks = gt_tracks(cams, poses, seed=11)
    gt = gt_calibration(NAMES, cams, poses)
    previous = gt_calibration(NAMES, *perturbed(cams, poses, seed=2))
    cfg = sfm_config("regular", distortion=200)
    cfg = replace(cfg, global_init="previous")
    init = initial_intrinsics([(c.width, c.height) for c in cams],
                              [c.params[0] * 1.05 for c in cams], cfg.camera_model)
    recal = run_global(tracks, init, NAMES, cfg, previous=previous)
    assert recal.quality.global_init == "previous"
    cfg = replace(cfg, global_init="rotation_averaging")
    scratch = run_global(tracks, init, NAMES, cfg)
    m_recal = evaluate_calibration(rig_from_state(recal.state, NAMES, []), gt)
    m_scratch = evaluate_calibration(rig_from_state(scratch.state, NAMES, []), gt)
    assert m_recal["auc3"] > 90
    assert m_recal["auc3"] >= m_scratch["auc3"] - 1.0
    # The previous calibration must cover every camera.
    del previous.cameras["top"]
    cfg = replace(cfg, global_init="previous")
    with pytest.raises(InputError, match="top"):
        run_global(tracks, init, NAMES, cfg, previous=previous)
    with pytest.raises(InputError, match="no previous calibration"):
        run_global(tracks, init, NAMES, cfg)


def test_disconnected_view_graph_names_the_camera_groups():
    cams, poses = gt_rig(4, seed=13)
    names = ["north", "east", "south", "west"]
    tracks = gt_tracks(cams, poses, num_points=800, seed=13, groups=[[0, 1], [2, 3]])
    init = initial_intrinsics([(c.width, c.height) for c in cams],
                              [c.params[0] for c in cams], "RADIAL")
    with pytest.raises(DisconnectedViewGraphError) as info:
        run_global(tracks, init, names, sfm_config("regular"))
    assert "{north, east}" in str(info.value) and "{south, west}" in str(info.value)


def test_pipeline_global_dispatch_reports_stages():
    cams, poses = gt_rig(4, seed=17)
    names = NAMES[:4]
    tracks = gt_tracks(cams, poses, num_points=1500, seed=17)
    config = make_config("regular", "global", sfm__num_threads=1)
    result = calibrate_from_tracks(tracks, [(c.width, c.height) for c in cams], names, config,
                                   focal_px=np.array([c.params[0] * 1.03 for c in cams]))
    quality = result.rig.quality
    assert quality.pipeline == "global"
    assert quality.gauge_camera in names
    assert set(quality.stage_residuals) == {"triangulation", "extrinsics", "focal", "distortion"}
    assert quality.reprojection_rms_px < 0.6  # 0.3 px noise; F_err removed the outlier tracks
    assert result.reconstruction.num_reg_images() == 4
    assert evaluate_calibration(result.rig, gt_calibration(names, cams, poses))["auc30"] > 90


def test_multistart_keeps_the_start_with_the_lower_truncated_cost():
    """Default global run: rotation averaging and the incremental result are both refined; the
    kept one has the lowest truncated reprojection cost of the two (checked by rerunning each)."""
    from densecalib_ros.core.method.multistart import cost_truncation_px, truncated_cost

    cams, poses = gt_rig(seed=7)
    tracks = gt_tracks(cams, poses, seed=7)
    cfg = sfm_config("regular", distortion=200)
    init = initial_intrinsics([(c.width, c.height) for c in cams],
                              [c.params[0] * 1.03 for c in cams], cfg.camera_model)
    both = run_global(tracks, init, NAMES, cfg)
    assert both.quality.global_init in ("rotation_averaging", "incremental")
    costs = {}
    for start in ("rotation_averaging", "incremental"):
        single = replace(sfm_config("regular", distortion=200), global_init=start,
                         global_multistart=False)
        run = run_global(tracks, init, NAMES, single)
        costs[start] = truncated_cost(run.state, cost_truncation_px(single, tracks.num_cameras))
    kept = both.quality.global_init
    assert costs[kept] <= min(costs.values()) + 1e-6
    metrics = evaluate_calibration(rig_from_state(both.state, NAMES, both.failed),
                                   gt_calibration(NAMES, cams, poses))
    assert metrics["auc3"] > 90


def test_previous_cameras_of_another_model_are_re_expressed_in_the_preset_model():
    """A previous calibration from another tool (PINHOLE fx != fy) starts RADIAL with the mean
    focal and the same principal point; fisheye terms are not carried into a pinhole model."""
    from densecalib_ros.core.method.previous_start import convert_intrinsics, poses_from_previous
    from densecalib_ros.core.types import CameraIntrinsics, RigCalibration, RigCamera

    pinhole = CameraIntrinsics("PINHOLE", 640, 480, np.array([500.0, 510.0, 321.0, 242.0]))
    radial = convert_intrinsics(pinhole, "RADIAL")
    assert radial.model == "RADIAL"
    np.testing.assert_allclose(radial.params, [505.0, 321.0, 242.0, 0.0, 0.0])
    fisheye = CameraIntrinsics("OPENCV_FISHEYE", 640, 480,
                               np.array([300.0, 300.0, 320.0, 240.0, 0.1, 0.02, 0.0, 0.0]))
    np.testing.assert_allclose(convert_intrinsics(fisheye, "RADIAL_FISHEYE").params,
                               [300.0, 320.0, 240.0, 0.1, 0.02])
    np.testing.assert_allclose(convert_intrinsics(fisheye, "RADIAL").params[3:], [0.0, 0.0])
    previous = RigCalibration("a", {"a": RigCamera("a", pinhole, np.eye(4)),
                                    "b": RigCamera("b", fisheye, np.eye(4))})
    intr, _ = poses_from_previous(previous, ["a", "b"], [(640, 480)] * 2,
                                  [("RADIAL_FISHEYE", "OPENCV_FISHEYE")] * 2)
    assert [c.model for c in intr] == ["RADIAL_FISHEYE", "OPENCV_FISHEYE"]  # the latter is kept
