"""Consensus over differently seeded calibrations: the disagreement measure and the medoid (the
pipeline's use of it is tested in test_pipeline.py)."""
import numpy as np
import pytest

from densecalib_ros.core.config import make_config
from densecalib_ros.core.metrics import projection_map_error
from densecalib_ros.core.method.multistart import (AGREEMENT_DEG, MAX_AGREEMENT_DEG,
                                                   agreement_deg)
from densecalib_ros.core.robust.consensus import (UNREGISTERED_PAIR_DEG, WARN_DISAGREEMENT_DEG,
                                                  choose_run, disagreement_warning,
                                                  least_determined_pairs, medoid,
                                                  pair_disagreement_deg, rig_disagreement_deg)
from densecalib_ros.core.robust.consensus_runs import runs_intrinsics_spread
from densecalib_ros.core.types import CameraIntrinsics, RigCalibration, RigCamera

NAMES = ["a", "b", "c"]


def _rotation_z(deg):
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1.0]])


def _rig(c_yaw_deg=0.0, c_shift=(0.0, 0.0, 0.0), names=NAMES):
    cam = CameraIntrinsics("RADIAL", 640, 480, np.array([500.0, 320, 240, 0, 0]))
    poses = {"a": np.eye(4), "b": np.eye(4), "c": np.eye(4)}
    poses["b"][:3, 3] = [-1.0, 0, 0]
    poses["c"][:3, :3] = _rotation_z(c_yaw_deg)
    poses["c"][:3, 3] = np.array([-2.0, 0, 0]) + c_shift
    return RigCalibration("a", {n: RigCamera(n, cam, poses[n]) for n in names})


def test_disagreement_measures_rotation_and_translation_direction():
    assert rig_disagreement_deg(_rig(), _rig(), NAMES) == pytest.approx(0.0, abs=1e-6)
    # c turned by 10 deg: the pairs (a, c) and (b, c) differ by 10 deg in rotation.
    assert pair_disagreement_deg(_rig(), _rig(10.0), "a", "c") == pytest.approx(10.0)
    assert pair_disagreement_deg(_rig(), _rig(10.0), "a", "b") == pytest.approx(0.0, abs=1e-6)
    assert rig_disagreement_deg(_rig(), _rig(10.0), NAMES) == pytest.approx(20.0 / 3)
    # c moved sideways by 2 * tan(5 deg): the direction a -> c turns by 5 deg.
    moved = _rig(c_shift=(0.0, 2.0 * np.tan(np.radians(5.0)), 0.0))
    assert pair_disagreement_deg(_rig(), moved, "a", "c") == pytest.approx(5.0)
    # Scale does not matter (reconstructions have none).
    scaled = _rig(c_shift=(-2.0, 0.0, 0.0))
    assert pair_disagreement_deg(_rig(), scaled, "a", "c") == pytest.approx(0.0, abs=1e-6)
    # A camera one run did not register counts as far apart.
    assert pair_disagreement_deg(_rig(), _rig(names=["a", "b"]), "a", "c") == \
        UNREGISTERED_PAIR_DEG


def test_runs_that_leave_the_same_camera_out_disagree_only_on_the_cameras_they_placed():
    """Two runs without camera c say the same about it: the pairs with c are left out of their
    disagreement, which is that of (a, b), not a mean with 180 deg for each pair with c."""
    without_c = ["a", "b"]
    assert pair_disagreement_deg(_rig(names=without_c), _rig(names=without_c), "a", "c") is None
    assert rig_disagreement_deg(_rig(names=without_c), _rig(names=without_c), NAMES) == \
        pytest.approx(0.0, abs=1e-6)
    turned = _rig(names=without_c)
    turned.cameras["b"].cam_from_rig[:3, :3] = _rotation_z(2.0)
    assert rig_disagreement_deg(_rig(names=without_c), turned, NAMES) == pytest.approx(2.0)
    # A run that placed c still disagrees with one that did not on c's two pairs ...
    assert rig_disagreement_deg(_rig(), _rig(names=without_c), NAMES) == \
        pytest.approx(2 * UNREGISTERED_PAIR_DEG / 3)
    # ... and runs that left out different cameras on every pair either placed ((b, c): neither).
    assert rig_disagreement_deg(_rig(names=without_c), _rig(names=["a", "c"]), NAMES) == \
        pytest.approx(UNREGISTERED_PAIR_DEG)
    rigs = [_rig(names=without_c), _rig(names=without_c), _rig(names=without_c)]
    best, D = medoid(rigs, NAMES)
    assert D.max() == pytest.approx(0.0, abs=1e-6)


def test_cameras_not_registered_are_named_with_their_best_partner_and_what_would_place_them():
    from densecalib_ros.core.stages.record import unregistered_warning
    from densecalib_ros.core.types import RigQuality

    assert unregistered_warning(_rig()) is None
    rig = _rig(names=["a", "b"])
    rig.failed_cameras = ["c", "d"]
    rig.quality = RigQuality(unregistered_best_partner={"c": ["b", 23], "d": ["a", 4]})
    message = unregistered_warning(rig)
    assert message.startswith("c and d could not be registered: they share at most 23 (c, with "
                              "b) and 4 (d, with a) keypoint matches with another camera. The "
                              "other 2 cameras are calibrated without them.")
    assert "--intrinsics NAME=FILE" in message and "asift" not in message
    rig.quality = RigQuality()  # a dense matcher: no keypoint matches to count
    assert unregistered_warning(rig, perspective_on_sift=True).startswith(
        "c and d could not be registered. The other 2")
    assert "--matcher asift" in unregistered_warning(rig, perspective_on_sift=True)


def test_medoid_is_the_majority_answer():
    rigs = [_rig(30.0), _rig(0.2), _rig(0.0), _rig(-0.1), _rig(names=["a", "b"])]
    best, D = medoid(rigs, NAMES)
    assert best == 2 and D.shape == (5, 5) and np.allclose(D, D.T)
    assert D[0, 2] == pytest.approx(20.0) and np.all(np.diag(D) == 0)


def test_users_are_warned_when_runs_disagree_beyond_auc3_threshold():
    assert WARN_DISAGREEMENT_DEG == 3.0
    assert disagreement_warning(0.4, 3) is None and disagreement_warning(3.0, 5) is None
    message = disagreement_warning(12.5, 5)
    assert "5 calibration runs disagree" in message and "12.5 deg" in message
    assert "frame sets" in message and "share-intrinsics" in message
    assert "asift" not in message  # only where the rig is few perspective cameras
    assert "--matcher asift" in disagreement_warning(12.5, 5, perspective_on_sift=True)
    # Not suggested where the cameras were calibrated as units of one model already (the runs
    # stood apart that way too: robust.one_model), or share their intrinsics.
    tried = disagreement_warning(12.5, 5, units_apart_deg=71.4)
    assert "share-intrinsics" not in tried
    assert "(as units of one model, which they could be, the runs stood 71 deg apart too)." in tried
    shared = disagreement_warning(12.5, 5, units_shared=True)
    assert "share-intrinsics" not in shared and "units of one model" not in shared
    assert "more overlap between cameras." in shared


def test_the_warning_names_the_pairs_the_runs_disagree_about_and_the_camera_in_each():
    """Camera c is placed 2 deg off by one run and 25-30 deg off by two: the pairs (a, c) and
    (b, c) are named, with their shared matches, and c as the camera the images do not place;
    (a, b), on which the runs agree, is not named."""
    kept, others = _rig(), [_rig(2.0), _rig(25.0), _rig(-30.0)]
    pairs = least_determined_pairs(kept, others, NAMES)
    assert [(a, b) for a, b, _ in pairs] == [("a", "c"), ("b", "c")]
    assert pairs[0][2] == pytest.approx(25.0)
    assert least_determined_pairs(kept, [_rig(2.0)], NAMES) == []
    message = disagreement_warning(8.0, 4, pairs=pairs, shared_matches={("a", "c"): 41},
                                   num_cameras=3)
    assert "a/c (25 deg; 41 shared matches), b/c (25 deg)" in message
    assert "c is in each" in message and "--intrinsics c=FILE" in message
    # Every pair undetermined: the whole rig is, and no camera is blamed.
    whole = disagreement_warning(60.0, 3, pairs=[("a", "b", 50.0), ("a", "c", 70.0),
                                                 ("b", "c", 60.0)], num_cameras=3)
    assert "every pair of the cameras calibrated" in whole and "is in each" not in whole
    assert "(most about a/b (50 deg), a/c (70 deg), b/c (60 deg))" in whole
    # A camera the kept run did not register is failed, not undetermined: its pairs are not named.
    assert least_determined_pairs(_rig(names=["a", "b"]), others, NAMES) == []


def test_runs_that_fit_the_common_tracks_clearly_worse_are_not_kept_even_as_majority():
    """Three of five runs put camera c 4 deg off with a 12 % focal error (they agree with each
    other, so the medoid alone would keep one of them); on the common tracks, triangulated from
    each run's cameras, they cost far more than the right runs, which are kept."""
    import sfm_fixtures
    from densecalib_ros.core.robust.consensus import (COMMON_TRACKS_MAX, WORSE_FIT_RATIO,
                                                      choose_run, common_track_costs,
                                                      well_fitting_runs)

    names = ["a", "b", "c", "d"]
    cams, poses = sfm_fixtures.gt_rig(4, seed=5)
    right = sfm_fixtures.gt_calibration(names, cams, poses)
    c_cam = right.cameras["c"]
    wrong_pose = c_cam.cam_from_rig.copy()
    wrong_pose[:3, :3] = _rotation_z(4.0) @ wrong_pose[:3, :3]
    wrong_intrinsics = CameraIntrinsics(c_cam.intrinsics.model, c_cam.intrinsics.width,
                                        c_cam.intrinsics.height,
                                        c_cam.intrinsics.params * [1.12, 1, 1, 1, 1])
    wrong = RigCalibration("a", {**right.cameras, "c": RigCamera("c", wrong_intrinsics,
                                                                 wrong_pose)})
    rigs = [wrong, right, wrong, wrong, right]
    runs_tracks = [sfm_fixtures.gt_tracks(cams, poses, num_points=1000, seed=s) for s in range(5)]
    assert sum(t.num_tracks for t in runs_tracks) > COMMON_TRACKS_MAX  # the sample is used
    costs = common_track_costs(rigs, runs_tracks, names, truncation_px=20.0)
    assert costs[1] == pytest.approx(costs[4]) and costs[0] == pytest.approx(costs[2])
    assert costs[0] > 2 * WORSE_FIT_RATIO * costs[1]
    assert well_fitting_runs(costs) == [1, 4]
    assert medoid(rigs, names)[0] in (0, 2, 3)  # the majority is wrong
    choice = choose_run(rigs, runs_tracks, names, truncation_px=20.0)
    assert choice.best == 1 and choice.worse_fit == [0, 2, 3]
    np.testing.assert_allclose(choice.costs_px, costs)
    # Runs that agree need no cost: the medoid is kept.
    agreeing = choose_run([right, right, right], runs_tracks[:3], names, truncation_px=20.0)
    assert agreeing.best == 0 and agreeing.worse_fit == [] and np.isnan(agreeing.costs_px).all()
    # Costs that could not be computed (fewer than two shared cameras) keep every run.
    assert well_fitting_runs(np.full(3, np.nan)) == [0, 1, 2]


def test_a_run_that_left_out_a_camera_is_kept_when_the_full_runs_fit_clearly_worse():
    """Every run is scored on the cameras all runs registered. Four runs register all four
    cameras but put b, c and d 4 deg off with 12 % focal errors; one run left out d and is
    right. On the shared cameras (a, b, c) the full runs fit far worse, so the partial run is
    kept although it registered fewer cameras (real fox, 8 frames, global pipeline: the two
    runs that dropped one frame were right, AUC@3 44, and the three that posed all 8 wrong)."""
    import sfm_fixtures
    from densecalib_ros.core.robust.consensus import choose_run, common_track_costs

    names = ["a", "b", "c", "d"]
    cams, poses = sfm_fixtures.gt_rig(4, seed=5)
    right = sfm_fixtures.gt_calibration(names, cams, poses)
    wrong_cameras = dict(right.cameras)
    for n in ["b", "c", "d"]:
        cam = right.cameras[n]
        pose = cam.cam_from_rig.copy()
        pose[:3, :3] = _rotation_z(4.0) @ pose[:3, :3]
        wrong_cameras[n] = RigCamera(n, CameraIntrinsics(
            cam.intrinsics.model, cam.intrinsics.width, cam.intrinsics.height,
            cam.intrinsics.params * [1.12, 1, 1, 1, 1]), pose)
    wrong = RigCalibration("a", wrong_cameras)
    partial = RigCalibration("a", {n: right.cameras[n] for n in ["a", "b", "c"]})
    rigs = [wrong, partial, wrong, wrong, wrong]
    runs_tracks = [sfm_fixtures.gt_tracks(cams, poses, num_points=300, seed=s) for s in range(5)]
    costs = common_track_costs(rigs, runs_tracks, names, truncation_px=20.0)
    assert costs[0] > 2 * costs[1]
    choice = choose_run(rigs, runs_tracks, names, truncation_px=20.0)
    assert choice.best == 1 and choice.worse_fit == [0, 2, 3, 4]
    # Fewer than two cameras shared by all runs: no costs, the vote alone decides.
    lone = RigCalibration("a", {n: right.cameras[n] for n in ["a", "d"]})
    only_b = RigCalibration("b", {n: right.cameras[n] for n in ["b", "c"]})
    assert np.isnan(common_track_costs([lone, only_b], runs_tracks[:2], names, 20.0)).all()


def test_runs_refined_on_the_same_tracks_are_judged_by_their_fit_to_them_not_by_vote():
    """Every run was refined last on the same keypoint-match tracks: the one that fits them best
    is kept even where most runs agree on another rig, as long as it registered as many cameras;
    a run that fits best only by leaving a camera out is not kept. Without such tracks the vote
    among the runs that fit the common tracks about equally decides."""
    import sfm_fixtures
    from densecalib_ros.core.robust.consensus import WORSE_FIT_RATIO, choose_run

    names = ["a", "b", "c", "d"]
    cams, poses = sfm_fixtures.gt_rig(4, seed=5)
    right = sfm_fixtures.gt_calibration(names, cams, poses)
    nearly = _turned(right, "c", 3.0)
    partial = RigCalibration("a", {n: right.cameras[n] for n in ["a", "b", "c"]})
    matches = sfm_fixtures.gt_tracks(cams, poses, num_points=1500, seed=11)
    runs_tracks = [sfm_fixtures.gt_tracks(cams, poses, num_points=300, seed=s) for s in range(4)]

    rigs = [nearly, right, nearly, nearly]
    choice = choose_run(rigs, runs_tracks, names, truncation_px=20.0, refined_on=matches)
    assert choice.by_fit and choice.best == 1
    assert choice.costs_px[1] < choice.costs_px[0] < WORSE_FIT_RATIO * 20.0
    vote = choose_run(rigs, runs_tracks, names, truncation_px=20.0)
    assert not vote.by_fit
    if 0 not in vote.worse_fit:  # 3 deg may or may not count as clearly worse on 4 cameras
        assert vote.best in (0, 2, 3)

    # The run without d fits a, b and c best; the full runs, with b turned by 0.1 deg, about as
    # well: a full run is kept.
    turned = _turned(right, "b", 0.1)
    with_partial = choose_run([turned, partial, turned], runs_tracks[:3], names,
                              truncation_px=20.0, refined_on=matches)
    assert with_partial.costs_px[1] < with_partial.costs_px[0] < \
        WORSE_FIT_RATIO * with_partial.costs_px[1]
    assert with_partial.best in (0, 2) and with_partial.by_fit


def test_two_agreeing_runs_keep_the_better_fit_unless_the_first_searched_more():
    """Two runs that agree are a tie for the medoid. Where both searched every focal start, the
    one that fits the keypoint-match tracks better is kept (agreeing runs still differ by up to
    the agreement, which the image refinement need not close); where the first run's multi-start
    settled and the second tried only its best starts, the first is kept."""
    import sfm_fixtures
    from densecalib_ros.core.robust.consensus import choose_run

    names = ["a", "b", "c", "d"]
    cams, poses = sfm_fixtures.gt_rig(4, seed=5)
    right = sfm_fixtures.gt_calibration(names, cams, poses)
    nearly = _turned(right, "c", 0.5)  # within the 1 deg agreement
    matches = sfm_fixtures.gt_tracks(cams, poses, num_points=1500, seed=11)
    runs_tracks = [sfm_fixtures.gt_tracks(cams, poses, num_points=300, seed=s) for s in range(2)]
    fit = choose_run([nearly, right], runs_tracks, names, truncation_px=20.0, refined_on=matches)
    assert fit.best == 1 and fit.by_fit and fit.worse_fit == []
    assert fit.costs_px[1] < fit.costs_px[0]
    first = choose_run([nearly, right], runs_tracks, names, truncation_px=20.0,
                       refined_on=matches, first_searched_more=True)
    assert first.best == 0 and not first.by_fit and np.isnan(first.costs_px).all()
    # Without tracks every run was refined on (a dense matcher) the first is kept as before.
    assert choose_run([nearly, right], runs_tracks, names, truncation_px=20.0).best == 0


def _turned(rig, name, deg):
    """rig with camera `name` turned by deg about its z axis (intrinsics kept)."""
    cam = rig.cameras[name]
    pose = cam.cam_from_rig.copy()
    pose[:3, :3] = _rotation_z(deg) @ pose[:3, :3]
    return RigCalibration(rig.reference_camera,
                          {**rig.cameras, name: RigCamera(name, cam.intrinsics, pose)})


def test_runs_agree_within_the_turn_a_held_principal_point_leaves():
    """Where the SfM holds the principal point at the image centre (the regular preset), a real
    lens's offset of up to 2 % of the long side turns every run alike by about offset / focal:
    runs closer than that are one answer. Long lenses keep AGREEMENT_DEG, and so does the fisheye
    preset, which refines the principal point; never more than AUC@3's threshold."""
    def cameras(focal_px, n=3):
        return [CameraIntrinsics("RADIAL", 1024, 768, np.array([focal_px, 512, 384, 0, 0]))] * n

    regular, fisheye = make_config("regular").sfm, make_config("fisheye").sfm
    assert agreement_deg(cameras(2000.0), regular) == AGREEMENT_DEG
    wide_deg = np.degrees(0.02 * 1024 / 512.0)
    assert agreement_deg(cameras(512.0), regular) == pytest.approx(wide_deg)
    assert agreement_deg(cameras(512.0), fisheye) == AGREEMENT_DEG
    assert agreement_deg(cameras(250.0), regular) == MAX_AGREEMENT_DEG == WARN_DISAGREEMENT_DEG
    # Cameras a run did not register do not count.
    assert agreement_deg([None, None] + cameras(512.0, 1), regular) == pytest.approx(wide_deg)
    assert agreement_deg([None] * 3, regular) == AGREEMENT_DEG
    # Runs 1.3 deg apart: one answer for wide lenses held at the centre (the medoid, no costs).
    rigs = [_rig(), _rig(2.0), _rig()]
    assert 1.0 < medoid(rigs, NAMES)[1].max() < wide_deg
    choice = choose_run(rigs, [], NAMES, truncation_px=20.0, agree_deg=wide_deg)
    assert choice.best == 0 and np.isnan(choice.costs_px).all()


def test_a_camera_placed_by_one_pair_alone_is_warned_of():
    """Observations of points a third camera sees are what checks a pair's geometry; a rig of
    three or more cameras where a camera has fewer than 30 of them is warned of, naming it (a
    real 4-camera ring with given intrinsics came out over 120 deg wrong on 2-view points alone,
    the runs agreeing and nothing warned)."""
    from densecalib_ros.core.stages.record import pairwise_only_warning
    from densecalib_ros.core.types import CameraQuality

    def rig(multiview: list, sfm: tuple = ()) -> RigCalibration:
        sfm = sfm or (None,) * len(multiview)
        cams = {f"c{i}": RigCamera(f"c{i}", CameraIntrinsics("RADIAL", 640, 480, np.array(
            [500.0, 320, 240, 0, 0])), np.eye(4), CameraQuality(0.5, 500, 0.5, m,
                                                                sfm_multiview_observations=s))
            for i, (m, s) in enumerate(zip(multiview, sfm))}
        return RigCalibration("c0", cams)

    assert pairwise_only_warning(rig([400, 400, 400])) is None
    assert pairwise_only_warning(rig([0, 0])) is None  # a pair has no third camera to ask
    assert pairwise_only_warning(rig([400, None, 400])) is None  # files without the count
    warning = pairwise_only_warning(rig([400, 29, 0, 400]))
    assert warning.startswith("cameras placed by camera pairs alone: c1 (29), c2 (0)")
    assert "--keypoints" in warning
    # the image refinement re-measures the rig on dense correspondences, often 2-view: the SfM's
    # points that placed the camera, seen by three, checked it
    assert pairwise_only_warning(rig([400, 12, 400], (400, 900, 400))) is None


def test_cameras_the_refinement_places_loosely_are_warned_of_once():
    """A camera whose rotation sigma (the image refinement's, relative to the reference camera)
    is above 1.5 deg may well be 3 deg off: warned, naming the cameras loosest first; not where
    the runs' disagreement or groups the dense points leave apart widened the sigmas (their own
    warnings say why). The walker's keypoints beside bench --few's fisheye room s816 came out
    1.9 deg off with sigmas of 2.2-2.8 deg and no warning."""
    from densecalib_ros.core.stages.record import LOOSE_ROTATION_STD_DEG, loose_rotation_warning
    from densecalib_ros.core.types import CameraQuality

    def rig(sigmas: list, **quality) -> RigCalibration:
        cams = {f"c{i}": RigCamera(f"c{i}", CameraIntrinsics("RADIAL", 640, 480, np.array(
            [500.0, 320, 240, 0, 0])), np.eye(4), CameraQuality(0.5, 500, 0.5, 400,
                                                                rotation_std_deg=s))
            for i, s in enumerate(sigmas)}
        out = RigCalibration("c0", cams)
        out.quality.update(**quality)
        return out

    assert LOOSE_ROTATION_STD_DEG == 1.5
    assert loose_rotation_warning(rig([None, 0.3, 1.4])) is None
    assert loose_rotation_warning(rig([None, None, None])) is None  # not refined: no sigmas
    warning = loose_rotation_warning(rig([None, 2.24, 2.82, 2.42, 0.8]))
    assert warning.startswith("cameras placed loosely: the calibration's own rotation sigmas "
                              "are c2 2.8 deg, c3 2.4 deg and c1 2.2 deg (relative to c0), so a "
                              "pair may be 3 deg or more off")
    assert "c4" not in warning and "--intrinsics" in warning
    assert loose_rotation_warning(rig([None, 2.5], sigmas_runs_spread=5)) is None
    assert loose_rotation_warning(
        rig([None, 3457.0], image_refinement_groups_apart=[["c0"], ["c1"]])) is None


def test_the_runs_spread_of_a_cameras_intrinsics_is_their_sample_deviation():
    def rig(focal_c, names=NAMES, cy_c=240.0):
        out = _rig(names=names)
        for name, cam in out.cameras.items():
            params = cam.intrinsics.params.copy()
            params[0] = focal_c if name == "c" else 500.0
            params[2] = cy_c if name == "c" else 240.0
            cam.intrinsics = CameraIntrinsics("RADIAL", 640, 480, params)
        return out

    spread = runs_intrinsics_spread([rig(490.0), rig(500.0), rig(510.0, names=["a", "c"])],
                                    NAMES)
    assert spread["a"] == pytest.approx((0.0, 0.0, 0.0, 0.0), abs=1e-9)
    focal_px, projection_px, _, point_px = spread["c"]
    assert focal_px == pytest.approx(10.0)  # 490, 500, 510: sample deviation 10
    assert point_px == pytest.approx(0.0, abs=1e-9)
    # a 2 % focal step moves the mean pixel by about 2 % of its distance from the centre; the
    # pairs (10, 10, 20 px of focal) give sqrt(mean square / 2) = sqrt(((1 + 1 + 4) / 3) / 2) = 1
    # such step
    one_step = projection_map_error(rig(500.0).cameras["c"].intrinsics,
                                    rig(510.0).cameras["c"].intrinsics)["mean_px"]
    assert projection_px == pytest.approx(one_step, rel=0.02)
    assert spread["b"] == pytest.approx((0.0, 0.0, 0.0, 0.0), abs=1e-9)  # two runs placed it
    assert "b" not in runs_intrinsics_spread([rig(500.0), rig(500.0, names=["a", "c"])], NAMES)
    # c's principal point 230, 240 and 256 px in y (x the same): the larger axis's sample
    # deviation, 13.1 px
    moved = runs_intrinsics_spread([rig(500.0, cy_c=230.0), rig(500.0), rig(500.0, cy_c=256.0)],
                                   NAMES)
    assert moved["c"][3] == pytest.approx(np.std([230.0, 240.0, 256.0], ddof=1))
    assert moved["b"][3] == pytest.approx(0.0, abs=1e-9)


def test_the_runs_spread_of_a_cameras_rotation_is_their_sample_deviation():
    """c turned by 0, 2 and 4 deg in three runs: the pairs' angles 2, 2 and 4 deg give
    sqrt(mean square / 2) = 2 deg, the sample deviation of the three turns."""
    spread = runs_intrinsics_spread([_rig(0.0), _rig(2.0), _rig(4.0)], NAMES)
    assert spread["c"][2] == pytest.approx(2.0)
    assert spread["b"][2] == pytest.approx(0.0, abs=1e-6)
    # no camera that every run placed: no common reference, no rotation spread
    apart = runs_intrinsics_spread([_rig(names=["a", "c"]), _rig(2.0, names=["b", "c"]),
                                    _rig(names=["a", "b"])], NAMES)
    assert np.isnan(apart["c"][2])
