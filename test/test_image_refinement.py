"""The last stage of a pinhole calibration (core.method.dense_matches, core.method.image_refinement)
on generated rigs with intrinsics as real lenses have them: principal points off-centre, fy !=
fx."""
import cv2
import numpy as np
import pytest

from densecalib_ros.core.config import make_config
from densecalib_ros.core.method.dense_matches import (align_patches, keypoint_px_scale,
                                                      local_affine, reference_points)
from densecalib_ros.core.method import image_folds
from densecalib_ros.core.method.patch_alignment import sample_bicubic
from densecalib_ros.core.metrics import evaluate_calibration
from densecalib_ros.core import run_calibration
from densecalib_ros.core.synthetic import RigSpec, generate_rig


@pytest.fixture(scope="module")
def real_rig():
    """5 cameras 30 deg apart, 1024x768, principal points up to 2 % off-centre."""
    return generate_rig(RigSpec(num_cameras=5, gap_deg=30.0, max_arc_deg=360.0, seed=31))


def test_the_alignment_samples_images_as_opencv_remap_does():
    """The compiled alignment's bicubic samples are cv2.remap's (INTER_CUBIC, BORDER_REPLICATE)
    to float32 rounding, inside the image, at its rim and beyond it; positions far outside (or
    NaN) give the edge's samples."""
    rng = np.random.default_rng(3)
    image = cv2.GaussianBlur((rng.random((60, 90, 3)) * 255).astype(np.float32), (5, 5), 1.0)
    xy = np.stack([rng.uniform(-4, 94, 5000), rng.uniform(-4, 64, 5000)], 1).astype(np.float32)
    xy[:4] = [[0, 0], [89, 59], [10.5, 20.25], [-3.75, 61.5]]
    expected = cv2.remap(image, xy[None, :, 0].copy(), xy[None, :, 1].copy(), cv2.INTER_CUBIC,
                         borderMode=cv2.BORDER_REPLICATE)[0]
    np.testing.assert_allclose(sample_bicubic(image, xy), expected, rtol=1e-6, atol=1e-4)
    # a diverged patch's positions sample the edge, as remap's border would
    far = np.array([[np.nan, 5], [1e30, -1e30], [-50, 30]], np.float32)
    np.testing.assert_allclose(sample_bicubic(image, far),
                               image[[5, 0, 30], [0, 89, 0]], rtol=1e-6)


def test_local_affine_predicts_an_affine_map_exactly():
    rng = np.random.default_rng(0)
    A, t = np.array([[1.1, 0.2], [-0.1, 0.9]]), np.array([5.0, -3.0])
    src = rng.uniform(0, 200, (200, 2))
    query = rng.uniform(50, 150, (20, 2))
    pred, jac, valid = local_affine(query, src, src @ A.T + t)
    assert valid.all()
    np.testing.assert_allclose(pred, query @ A.T + t, atol=1e-6)
    np.testing.assert_allclose(jac, np.broadcast_to(A, jac.shape), atol=1e-6)
    far = local_affine(np.array([[1000.0, 1000.0]]), src, src @ A.T + t)[2]
    assert not far.any()  # no neighbour within reach: no prediction


def test_keypoint_thresholds_scale_with_the_size_the_keypoints_were_matched_at():
    """A camera matched downscaled (its long side over max_image_side_px) has its keypoint-based
    thresholds in its own pixels scaled by that factor; one matched whole keeps them."""
    np.testing.assert_allclose(keypoint_px_scale([(3072, 2048), (1280, 720), (640, 480)], 1024),
                               [3.0, 1.25, 1.0])
    np.testing.assert_allclose(keypoint_px_scale([(3072, 2048)], None), [1.0])
    rng = np.random.default_rng(0)
    A, t = np.array([[1.1, 0.2], [-0.1, 0.9]]), np.array([5.0, -3.0])
    src = rng.uniform(0, 600, (40, 2)) * 3  # keypoints 3x as far apart as at the matched size
    query = rng.uniform(600, 1200, (30, 2))
    near = local_affine(query, src, src @ A.T + t)[2]
    scaled_pred, _, scaled = local_affine(query, src, src @ A.T + t, px_scale=3.0)
    assert scaled.sum() > 2 * near.sum()
    np.testing.assert_allclose(scaled_pred[scaled], query[scaled] @ A.T + t, atol=1e-6)


@pytest.mark.slow
def test_large_images_matched_downscaled_are_refined_as_well_as_small_ones():
    """2048x1536 images, matched at 1024: the dense correspondences' predictions and checks in
    the images' own pixels allow for the keypoints' doubled errors and spacing, so the
    refinement keeps its correspondences (in the thresholds of 1024 px images it kept 1432,
    0.029 deg) and the rig is as accurate as at 1024 (Strecha entry-P10 at 3072 px went from
    0.47 to 0.08 deg with this)."""
    big = generate_rig(RigSpec(num_cameras=5, gap_deg=30.0, max_arc_deg=360.0, seed=31,
                               width=2048, height=1536))
    config = make_config("regular", "incremental", consensus_runs=1, sfm__num_threads=1)
    result = run_calibration(big.images, big.names, config)
    metrics = evaluate_calibration(result.rig, big.ground_truth())
    assert metrics["num_registered"] == 5
    assert result.rig.quality.image_refinement_tracks > 2000
    assert metrics["median_rot_err_deg"] < 0.1, metrics["median_rot_err_deg"]


def test_a_recalibration_centres_its_priors_on_the_points_determined_before():
    """The previous calibration's principal points that its images determined (and only those)
    centre a recalibration's priors, with the image size they belong to."""
    from densecalib_ros.core.method.uncertainty import estimated_principal_points
    from densecalib_ros.core.types import (CameraIntrinsics, CameraQuality, RigCalibration,
                                           RigCamera)

    def camera(name, params, estimated):
        model = "OPENCV" if len(params) == 8 else "RADIAL"
        return RigCamera(name, CameraIntrinsics(model, 640, 480, np.array(params, float)),
                         np.eye(4), CameraQuality(0.3, 500, 0.8, estimated_intrinsics=estimated))
    rig = RigCalibration("a", {
        "a": camera("a", [800, 805, 326.1, 231.2, 0.01, 0, 0, 0], ["f", "cx", "cy", "aspect"]),
        "b": camera("b", [800, 330.0, 250.0, 0.01, 0], ["f", "cx", "cy"]),
        "c": camera("c", [800, 805, 320.0, 240.0, 0, 0, 0, 0], ["f", "aspect"]),  # held
        "d": camera("d", [800, 805, 300.0, 200.0, 0, 0, 0, 0], None)})  # not judged
    assert estimated_principal_points(rig) == {"a": (326.1, 231.2, 640, 480),
                                               "b": (330.0, 250.0, 640, 480)}
    assert estimated_principal_points(None) == {}


def test_patch_alignment_is_subpixel_against_the_truth(real_rig):
    """Corners of cam0 aligned in cam1 from their true positions moved by up to 2 px land within a
    fraction of a pixel of the truth."""
    rng = np.random.default_rng(1)
    gray = [np.asarray(im, np.float32).mean(axis=2).astype(np.float32) for im in real_rig.images[0]]
    xy_a = reference_points(gray[0], max_points=400)
    xy_b, visible = real_rig.transfer(0, 0, 1, xy_a)
    xy_a, xy_b = xy_a[visible], xy_b[visible]
    # The local map from the truth itself (finite differences of the transfer).
    jac = np.zeros((len(xy_a), 2, 2))
    for k in range(2):
        step = np.zeros(2)
        step[k] = 1.0
        moved, ok = real_rig.transfer(0, 0, 1, xy_a + step)
        jac[:, :, k] = np.where(ok[:, None], moved - xy_b, step)
    start = xy_b + rng.uniform(-2, 2, xy_b.shape)
    refined, ncc, _ = align_patches(gray[0], gray[1], xy_a, start, jac)
    good = (ncc > 0.85) & (np.linalg.norm(refined - start, axis=1) < 4.0)  # as dense_tracks
    assert good.sum() > 100
    error = np.linalg.norm(refined[good] - xy_b[good], axis=1)
    # (corners on an occluding edge belong to two surfaces: a few land on the other one)
    assert np.median(error) < 0.15 and np.percentile(error, 75) < 0.3


@pytest.mark.slow
def test_real_lenses_calibrate_to_a_tenth_of_a_degree(real_rig):
    """End to end: off-centre principal points estimated, the rig within 0.15 deg (holding the
    point at the image centre, as the calibration did before this stage, it was ~1 deg)."""
    config = make_config("regular", "incremental", consensus_runs=1, sfm__num_threads=1)
    result = run_calibration(real_rig.images, real_rig.names, config)
    metrics = evaluate_calibration(result.rig, real_rig.ground_truth())
    assert metrics["num_registered"] == 5
    assert metrics["median_rot_err_deg"] < 0.15, metrics["median_rot_err_deg"]
    assert metrics["median_pp_err_px"] < 3.0
    assert metrics["median_focal_err"] < 0.005
    for cam in result.rig.cameras.values():
        assert "cx" in cam.quality.estimated_intrinsics
        assert cam.quality.principal_point_std_px < 5.0
    assert result.rig.quality.image_refinement_tracks > 1000
    held = make_config("regular", "incremental", consensus_runs=1, refine_on_images=False,
                       sfm__num_threads=1)
    before = evaluate_calibration(run_calibration(real_rig.images, real_rig.names, held).rig,
                                  real_rig.ground_truth())
    assert before["median_rot_err_deg"] > 2 * metrics["median_rot_err_deg"]


def _same_tracks(a, b):
    return a.num_tracks == b.num_tracks and np.array_equal(a.xy_px, b.xy_px, equal_nan=True) \
        and np.array_equal(a.time_index, b.time_index)


def test_dense_tracks_found_ahead_are_those_found_after(real_rig):
    """A calibration finds the dense correspondences while it still searches the rig
    (DenseAhead): for the rig it was told to expect they are dense_tracks' bit for bit, and for
    any other rig (moved, or with a camera left out) they are found for that rig, not taken from
    the expected one; another calibration of the same matches takes the first pass over."""
    from densecalib_ros.core.method.all_matches import keypoint_tracks
    from densecalib_ros.core.method.dense_ahead import DenseAhead
    from densecalib_ros.core.method.dense_matches import dense_tracks
    from densecalib_ros.core.method.reconstruction import SfMState
    from densecalib_ros.core import match_frame_sets

    images, C = real_rig.images, len(real_rig.names)
    seeds = keypoint_tracks(match_frame_sets(images, make_config("regular")), C)
    truth = real_rig.ground_truth()
    state = SfMState.create(seeds, [truth.cameras[n].intrinsics for n in real_rig.names])
    state.cam_from_world = [truth.cameras[n].cam_from_rig.copy() for n in real_rig.names]
    moved = state.copy()  # camera 1 turned by 0.5 deg: another rig, other epipolar lines
    moved.cam_from_world[1][:3, :3] = cv2.Rodrigues(np.array([0.0, np.radians(0.5), 0.0]))[0] \
        @ moved.cam_from_world[1][:3, :3]
    fewer = state.copy()
    fewer.cam_from_world[4] = None

    ahead = DenseAhead(images, C, seeds)
    ahead.expect(state)
    found = ahead.tracks(state)
    assert found.num_tracks > 1000
    # what a calibration would still wait for: nothing for the rig found ahead, a pass among
    # the cameras for a moved one (its rest was not run ahead)
    assert ahead.seconds_left(state) == 0.0 and ahead.seconds_left(moved) > 0.0
    assert _same_tracks(found, dense_tracks(images, state, seeds))
    for other in (moved, fewer):
        after = dense_tracks(images, other, seeds)
        assert not _same_tracks(after, found)
        assert _same_tracks(ahead.tracks(other), after)
    # Another calibration of the same matches (the rig as one model) takes the first pass over:
    # only the rest is left to it, and its tracks are the same.
    again = DenseAhead(images, C, seeds, first_of=ahead)
    assert again.seconds_left(state) == ahead.seconds_left(moved) > 0.0
    assert _same_tracks(again.tracks(state), found)
    ahead.cancel()


def test_runs_apart_on_the_keypoint_matches_are_judged_again_refined_on_the_images(real_rig):
    """Where the consensus runs disagree, the runner-up is refined on the dense correspondences as
    the kept rig was (stages.refinement.RefinedRuns): a runner-up in the same valley of the
    keypoint matches' fit (here: the rig adjusted on them with every focal held 8 % long, 2.3 deg
    from the kept one, more than the runs' early stop allows) comes out at the kept rig, so the
    disagreement no longer stands and no more runs are needed (ConsensusRuns' early stop); one
    the images do not support (two cameras' poses exchanged) leaves both standing."""
    from dataclasses import replace

    from densecalib_ros.core.calibration_result import result_with_state
    from densecalib_ros.core.method.multistart import AGREEMENT_DEG
    from densecalib_ros.core.method.reconstruction import BAStage, bundle_adjust
    from densecalib_ros.core.progress import Progress
    from densecalib_ros.core.robust.consensus import WARN_DISAGREEMENT_DEG, rig_disagreement_deg
    from densecalib_ros.core.robust.consensus_runs import ConsensusRuns
    from densecalib_ros.core.stages.attempt import Calibrator
    from densecalib_ros.core.stages.inputs import prepare
    from densecalib_ros.core.stages.matching import match_rig
    from densecalib_ros.core.stages.refinement import RefinedRuns

    names = real_rig.names
    config = make_config("regular", "incremental", consensus_runs=1, refine_on_images=False,
                         sfm__num_threads=1)
    images = prepare(real_rig.images, names, config)
    matched = match_rig(images, images.config, Progress())
    found = Calibrator(images, matched, images.config, Progress()).calibrate().result
    found = replace(found, settled_starts=None)  # the runs below are judged on their rigs alone
    refined_runs = RefinedRuns(images, matched, images.config, None, None)
    kept, record = refined_runs.refine(found, Progress())
    assert record is not None and record.num_tracks > 0

    long = found.state.copy()
    for camera in long.intrinsics:
        camera.params[:2 if camera.model.startswith(("OPENCV", "PINHOLE")) else 1] *= 1.08
    bundle_adjust(long, names, BAStage(refine_focal=False, refine_extra=False), 1)
    swapped = found.state.copy()
    swapped.cam_from_world[1], swapped.cam_from_world[3] = \
        swapped.cam_from_world[3], swapped.cam_from_world[1]
    five = images.config.with_options(consensus_runs=5)
    for other, meets in ((long, True), (swapped, False)):
        runner_up = result_with_state(found, other, names)
        apart = rig_disagreement_deg(kept.rig, runner_up.rig, names)
        refined = rig_disagreement_deg(kept.rig, refined_runs.rig(runner_up), names) \
            if refined_runs.rig(runner_up) is not None else None
        if meets:
            assert apart > 0.3 and refined < 0.05, (apart, refined)
        else:
            assert refined is None or refined > WARN_DISAGREEMENT_DEG, (apart, refined)
        # The consensus's early stop judges runs apart the same way: where they meet refined,
        # no more runs, with their disagreement refined; where they do not, all five are made.
        runs = ConsensusRuns(lambda seed, starts, progress: (found, runner_up)[seed % 2], five,
                             names, Progress(), refined_runs.disagreement_deg).run()
        assert len(runs.results) == (2 if meets else 5)
        assert (runs.refined_deg is not None) == meets, runs.refined_deg
        if meets:
            assert runs.refined_deg.max() < AGREEMENT_DEG
        unrefined = ConsensusRuns(lambda seed, starts, progress: (found, runner_up)[seed % 2],
                                  five, names, Progress()).run()
        assert len(unrefined.results) == 5
        # each run is refined once (the kept run's refinement is the one the calibration used)
        assert refined_runs.refinement(found) is refined_runs.refinement(found)


def _rig_at_its_truth(cams, poses, num_points, seed):
    """A rig of these intrinsics at its true poses on exact correspondences with 0.1 px noise
    (what dense correspondences measure), its points triangulated, and the refinement's priors
    for its cameras: (tracks, state, blocks, priors)."""
    from sfm_fixtures import gt_tracks

    from densecalib_ros.core.method import image_refinement as ir
    from densecalib_ros.core.method.prior_adjustment import Priors
    from densecalib_ros.core.method.reconstruction import SfMState, triangulate_tracks

    tracks = gt_tracks(cams, poses, num_points=num_points, noise_px=0.1, outlier_frac=0.0,
                       seed=seed)
    state = SfMState.create(tracks, cams)
    state.cam_from_world = [T.copy() for T in poses]
    triangulate_tracks(state)
    blocks = list(range(len(cams)))
    priors = Priors(principal_point_std_px={b: 0.01 * cams[b].width for b in blocks},
                    aspect_std={b: ir.ASPECT_PRIOR_STD for b in blocks})
    return tracks, state, blocks, priors


def _refinement_ties(cams, seed):
    """The ties the refinement chooses for a rig of these intrinsics, found from its true poses on
    exact correspondences with 0.1 px noise (what dense correspondences measure), and what it
    said."""
    from sfm_fixtures import gt_rig

    from densecalib_ros.core.method import image_refinement as ir

    _, poses = gt_rig(len(cams), seed=seed)
    tracks, state, blocks, priors = _rig_at_its_truth(cams, poses, 3000, seed)
    start = state.copy()
    adjustment = ir.adjust_and_gate(state, blocks, priors)
    start.active &= state.active
    _, fold_sigmas = image_folds.determined_by_images(start, blocks, priors)
    said = []
    ties, _, _ = ir.rig_ties(state, blocks, fold_sigmas, priors, adjustment.noise_px,
                           [f"cam{c}" for c in blocks], said.append)
    return dict(ties), said


def test_images_of_one_camera_are_adjusted_as_one_and_different_lenses_apart():
    """A rig's cameras are tied as one camera where that fits correspondences held out of the
    adjustment as well as separate cameras do (one camera moved around: Strecha's DSLR), and
    only as far as they agree where it does not (gt_rig's lenses: focal lengths 0.8-1.1x the
    width, principal points up to 6 px off the centre, distortions drawn per camera)."""
    from sfm_fixtures import gt_rig

    from densecalib_ros.core.types import CameraIntrinsics

    cams, _ = gt_rig(6, seed=11, pp_jitter_px=6.0)
    one = [CameraIntrinsics(c.model, c.width, c.height, cams[0].params.copy()) for c in cams]
    ties, said = _refinement_ties(one, seed=11)
    assert "as one" in said[0], said
    assert {0, 1, 2, 3, 4} <= set(ties)  # f, cx, cy, k1, k2
    ties, said = _refinement_ties(cams, seed=11)
    assert "as far as they agree" in said[0], said
    assert set(ties) == {0, 3, 4}  # f, k1, k2 within the rig's spread; each its own point
    # Lenses this different scatter far beyond their sigmas: the verdict is certain untested.
    assert "not one camera's" in said[0] and "held-out" not in said[0], said
    # One lens model whose principal points differ by up to 6 px: f, k1 and k2 agree, so the
    # held-out test runs, and tells them apart.
    points_apart = [CameraIntrinsics(c.model, c.width, c.height,
                                     np.r_[cams[0].params[:1], c.params[1:3],
                                           cams[0].params[3:]]) for c in cams]
    ties, said = _refinement_ties(points_apart, seed=11)
    assert "as far as they agree" in said[0] and "held-out correspondences" in said[0], said


class _GivenCorrespondences:
    """Dense correspondences already measured (what DenseAhead hands the stage): here the exact
    ones of a generated rig, so that the stage is judged against known intrinsics."""

    def __init__(self, tracks):
        self._tracks = tracks

    def tracks(self, state):
        return self._tracks


def test_cameras_adjusted_as_one_are_determined_and_reported_as_one_camera():
    """Six images of one camera (principal point 6 px off the centre of a 640x480 image),
    refined as one camera: its principal point estimated or held for all of them alike, focal
    sigmas the one camera's (from the images of all six: below what any one image's folds give
    it alone; they differ only where the tie lets each image's aspect), and the focal length within
    three of them of the truth."""
    from sfm_fixtures import gt_rig, gt_tracks

    from densecalib_ros.core.method import image_refinement as ir
    from densecalib_ros.core.method.prior_adjustment import Priors
    from densecalib_ros.core.method.reconstruction import SfMState, triangulate_tracks
    from densecalib_ros.core.types import CameraIntrinsics

    cams, poses = gt_rig(6, seed=11, pp_jitter_px=6.0)
    truth = cams[0]
    tracks = gt_tracks([truth] * 6, poses, num_points=3000, noise_px=0.1, outlier_frac=0.0,
                       seed=11)
    start = truth.params.copy()
    start[0] *= 1.01
    start[1:3] = truth.width / 2.0, truth.height / 2.0  # as the SfM holds it
    state = SfMState.create(tracks, [CameraIntrinsics(truth.model, truth.width, truth.height,
                                                      start.copy()) for _ in cams])
    state.cam_from_world = [T.copy() for T in poses]
    names = [f"cam{c}" for c in range(6)]
    said = []
    refinement = ir.refine_on_images(state, None, None, names, None, 0, said.append, {},
                                     _GivenCorrespondences(tracks))
    assert any("as one" in s for s in said), said
    assert refinement.one_camera == {tuple(names): True}  # the verdict, as one_model reads it
    assert len({tuple(refinement.estimated[n]) for n in names}) == 1
    focal_std = [refinement.uncertainty[n].focal_std_px for n in names]
    # each image's own folds' sigma of its focal length, as the stage measures it per camera
    priors = Priors(principal_point_std_px={c: 0.01 * truth.width for c in range(6)},
                    aspect_std={c: ir.ASPECT_PRIOR_STD for c in range(6)})
    triangulate_tracks(state)
    _, fold_sigmas = image_folds.determined_by_images(state, list(range(6)), priors)
    assert max(focal_std) < min(fold_sigmas[c]["focal_px"] for c in range(6)), fold_sigmas
    for c in range(6):
        f = refinement.state.intrinsics[c].params[0]
        assert abs(f - truth.params[0]) <= 3 * focal_std[c], (f, truth.params[0], focal_std)


def test_the_folds_side_by_side_give_the_loops_numbers(monkeypatch):
    """The folds' adjustments run on threads (parallel.map_threads); each works on its own copy
    of the rig, so the folds' sigmas and held-out errors are those of one fold after another,
    to the last bit (a fold that wrote to the shared rig would change the others')."""
    from sfm_fixtures import gt_rig

    cams, poses = gt_rig(4, seed=5, pp_jitter_px=6.0)
    tracks, state, blocks, priors = _rig_at_its_truth(cams, poses, 1500, seed=5)

    def folds():
        before = state.copy()
        determined, sigmas = image_folds.determined_by_images(state, blocks, priors)
        held_out = image_folds.held_out_errors(state, blocks, priors, 0.1,
                                                [f"cam{c}" for c in blocks], None)
        assert np.array_equal(state.points_xyz, before.points_xyz, equal_nan=True)
        return determined, sigmas, held_out

    # threads even where the machine has one core (map_threads would then run the loop)
    threaded = image_folds.map_threads
    monkeypatch.setattr(image_folds, "map_threads", lambda fn, items: threaded(fn, items, workers=4))
    side_by_side = folds()
    monkeypatch.setattr(image_folds, "map_threads", lambda fn, items: [fn(i) for i in items])
    one_after_another = folds()
    assert side_by_side[:2] == one_after_another[:2]
    assert np.array_equal(side_by_side[2], one_after_another[2], equal_nan=True)


def test_a_pixel_aspect_no_real_sensor_has_is_held_square():
    """A camera whose correspondences ask for fy / fx 1.03 (beyond the 1.5 % no real sensor
    exceeds: a fit gone astray, or images resized unevenly) ends with square pixels, held and
    said; where holding it pushes another camera's beyond the bound, that one is held too (here
    the rest of the rig: the true 3 % must go somewhere), and no camera ends beyond it."""
    from sfm_fixtures import centred_state, gt_rig

    from densecalib_ros.core.method import image_refinement as ir
    from densecalib_ros.core.types import CameraIntrinsics

    cams, poses = gt_rig(5, seed=3, pp_jitter_px=0.0)
    true = [CameraIntrinsics("OPENCV", c.width, c.height,
                             np.r_[c.params[0], c.params[0] * (1.03 if k == 2 else 1.0),
                                   c.params[1:], 0.0, 0.0]) for k, c in enumerate(cams)]
    state = centred_state(true, poses, 0.2, seed=3)
    names = [f"cam{c}" for c in range(5)]
    said = []
    refinement = ir.refine_on_images(state, None, None, names, None, 0, said.append, {},
                                     _GivenCorrespondences(state.tracks))
    assert any(s.startswith("pixel aspect held square for") and "cam2" in s for s in said), said
    held = refinement.state.intrinsics[2]  # written back in its model: one focal length
    assert held.model == "RADIAL" or held.params[1] == pytest.approx(held.params[0], rel=1e-9)
    assert "aspect" not in refinement.estimated["cam2"]
    for c in (0, 1, 3, 4):
        cam = refinement.state.intrinsics[c]
        assert cam.model == "RADIAL" or abs(cam.params[1] / cam.params[0] - 1.0) < 0.015


def _one_lens_refined(aspects, seed):
    """Frames of one lens (RADIAL parameters of a gt_rig camera) whose pixel aspects fy / fx are
    `aspects`, one per frame, at their true poses with 0.1 px noise, handed over as the SfM does
    (focal 1 % off, principal point at the centre), refined on the images: (refinement, camera
    names, what it said)."""
    from sfm_fixtures import gt_rig, gt_tracks

    from densecalib_ros.core.method import image_refinement as ir
    from densecalib_ros.core.method.reconstruction import SfMState
    from densecalib_ros.core.types import CameraIntrinsics

    cams, poses = gt_rig(len(aspects), seed=seed, pp_jitter_px=4.0)
    f, cx, cy, k1, k2 = cams[0].params
    frames = [CameraIntrinsics("OPENCV", 640, 480, np.array([f, a * f, cx, cy, k1, k2, 0, 0]))
              for a in aspects]
    tracks = gt_tracks(frames, poses, num_points=3000, noise_px=0.1, outlier_frac=0.0,
                       seed=seed)
    start = np.array([1.01 * f, 320.0, 240.0, k1, k2])
    state = SfMState.create(tracks, [CameraIntrinsics("RADIAL", 640, 480, start.copy())
                                     for _ in cams])
    state.cam_from_world = [T.copy() for T in poses]
    names = [f"cam{c}" for c in range(len(cams))]
    said = []
    refinement = ir.refine_on_images(state, None, None, names, None, 0, said.append, {},
                                     _GivenCorrespondences(tracks))
    return refinement, names, said


def test_cameras_adjusted_as_one_share_one_pixel_aspect():
    """Six images of one camera whose pixels are 0.2 % taller than wide (fy / fx 1.002, as
    Strecha's DSLR has 1.0017), refined as one camera: one aspect for all six, near the truth.
    Each image's aspect left free trades against its own focal length and principal point."""
    refinement, names, said = _one_lens_refined([1.002] * 6, seed=12)
    assert refinement.one_camera == {tuple(names): True}, said
    aspect = np.array([cam.params[1] / cam.params[0] for cam in refinement.state.intrinsics])
    assert np.ptp(aspect) < 1e-4, aspect
    assert abs(aspect.mean() - 1.002) < 5e-4, aspect


def test_frames_whose_apparent_aspects_differ_are_still_judged_one_lens():
    """Six frames of one lens, each with an apparent pixel aspect of its own (fy / fx 0.996-1.004,
    as a rolling shutter in motion gives a phone's video frames): the one-camera test asks about
    the lens (f, k1, k2, principal point), so they are judged one camera (with one aspect in the
    test as well, they fitted held-out correspondences 103 % worse than six)."""
    refinement, names, said = _one_lens_refined([0.996, 1.004, 0.998, 1.003, 0.997, 1.002],
                                                seed=13)
    assert refinement.one_camera == {tuple(names): True}, said


def test_fisheye_rigs_are_refined_on_the_images_where_their_layout_allows():
    """A ring of fisheye lenses (150-190 deg) is refined on the images as perspective rigs are:
    every camera's principal point, focal length and all four distortion terms estimated, a
    rotation sigma for each camera but the reference, and the rig several times closer than the
    SfM alone left it (0.053 deg before this stage was extended to fisheye lenses). A
    forward-facing fisheye rig (a stereo head) keeps the SfM's lenses (lenses_adjusted)."""
    from densecalib_ros.core.method.focal_determination import lenses_adjusted

    rig = generate_rig(RigSpec(num_cameras=4, camera_model="OPENCV_FISHEYE", seed=202))
    result = run_calibration(rig.images, rig.names, make_config("fisheye"))
    metrics = evaluate_calibration(result.rig, rig.ground_truth())
    assert metrics["auc3"] == 100.0 and metrics["median_rot_err_deg"] < 0.02
    assert max(c["pp_err_px"] for c in metrics["cameras"].values()) < 0.3
    cameras = result.rig.cameras
    assert all(cam.intrinsics.model == "OPENCV_FISHEYE" for cam in cameras.values())
    assert all({"f", "cx", "cy", "k3", "k4"} <= set(cam.quality.estimated_intrinsics)
               for cam in cameras.values())
    assert all(cam.quality.rotation_std_deg for name, cam in cameras.items()
               if name != result.rig.reference_camera)
    ahead = np.eye(3)
    turned = cv2.Rodrigues(np.radians([0.0, 25.0, 0.0]))[0]
    assert not lenses_adjusted(["OPENCV_FISHEYE"] * 2, [ahead, ahead])
    assert lenses_adjusted(["OPENCV_FISHEYE"] * 2, [ahead, turned])
    assert lenses_adjusted(["RADIAL"] * 2, [ahead, ahead])


def test_dense_points_that_leave_groups_of_cameras_unlinked_are_found_and_warned():
    """Cameras 0-1 and 2-3 whose points are never seen across the groups: two groups, and the
    rig refined on them is warned that how the groups stand rests on the keypoint matches; one
    group where the points tie every camera, and no warning."""
    from densecalib_ros.core.method.dense_matches import dense_groups
    from densecalib_ros.core.method.reconstruction import SfMState, triangulate_tracks
    from densecalib_ros.core.stages.record import groups_apart_warning
    from densecalib_ros.core.types import RigQuality
    from sfm_fixtures import gt_calibration, gt_rig, gt_tracks

    cams, poses = gt_rig(4, seed=2)
    names = [f"cam{c}" for c in range(4)]
    found = {}
    for split in (None, [[0, 1], [2, 3]]):
        state = SfMState.create(gt_tracks(cams, poses, noise_px=0.3, outlier_frac=0.0, seed=2,
                                          groups=split), cams)
        state.cam_from_world = [T.copy() for T in poses]
        triangulate_tracks(state, max_error_px=5.0)
        found[split is None] = dense_groups(state, names)
    assert found[True] == [names]
    assert found[False] == [["cam0", "cam1"], ["cam2", "cam3"]]
    rig = gt_calibration(names, cams, poses)
    rig.quality = RigQuality(image_refinement_groups_apart=found[False])
    said = groups_apart_warning(rig)
    assert "{cam0, cam1} and {cam2, cam3}" in said and "keypoint matches alone" in said
    rig.quality = RigQuality()
    assert groups_apart_warning(rig) is None


def test_what_moves_through_later_frame_sets_is_densified_where_it_is_new(real_rig):
    """Beyond the frame sets densified whole, a later frame set gives dense correspondences
    where it shows what no earlier one did (something walking through the static room); a frame
    set that shows nothing new gives none."""
    from densecalib_ros.core.method.all_matches import keypoint_tracks
    from densecalib_ros.core.method.dense_frame_sets import densified_times, later_frame_sets
    from densecalib_ros.core.method.dense_matches import dense_tracks
    from densecalib_ros.core.method.reconstruction import SfMState
    from densecalib_ros.core import match_frame_sets

    full, C = real_rig.images[0], len(real_rig.names)
    h = full[0].shape[0]

    def lower_half_grey(image):
        out = np.array(image, copy=True)
        out[h // 2:] = 128
        return out
    hidden = [lower_half_grey(image) for image in full]
    # six frame sets: the lower half shows up in the fifth only, which is not one of the four
    # taken whole; the second repeats the first
    frame_sets = [hidden, hidden, hidden, hidden, full, hidden]
    seeds = keypoint_tracks(match_frame_sets(frame_sets, make_config("regular")), C)
    assert densified_times(seeds).tolist() == [0, 2, 3, 5]
    later = later_frame_sets(frame_sets, seeds)
    assert list(later) == [4] and 0.5 < later[4] < 0.6  # the lower half, and a margin

    truth = real_rig.ground_truth()
    state = SfMState.create(seeds, [truth.cameras[n].intrinsics for n in real_rig.names])
    state.cam_from_world = [truth.cameras[n].cam_from_rig.copy() for n in real_rig.names]
    found = dense_tracks(frame_sets, state, seeds)
    moved_in = found.time_index == 4
    assert moved_in.sum() > 500
    # each from a reference point on what is new (another camera may see it higher up)
    assert (np.nanmax(found.xy_px[moved_in, :, 1], axis=1) > h // 2 - 40).all()
    assert not (found.xy_px[~moved_in, :, 1] > h // 2 + 40).any()
