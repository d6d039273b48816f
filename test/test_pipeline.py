"""End-to-end calibration of a small generated rig through the real matcher, sampling and SfM."""
import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import re

import numpy as np
import pytest

from densecalib_ros.core.config import make_config
from densecalib_ros.core.errors import (CalibrationError, InputError, NotEnoughCamerasError,
                                       NotEnoughOverlapError, UndeterminedRigError)
from densecalib_ros.core.method.matching import create_matcher
from densecalib_ros.core.metrics import evaluate_calibration
from densecalib_ros.core.method.focal_start import start_focals
from densecalib_ros.core import calibrate_rig, match_frame_sets, run_calibration
from densecalib_ros.core.synthetic import RigSpec, generate_rig


@pytest.fixture(scope="module")
def rig():
    return generate_rig(RigSpec(lenses="ideal", num_cameras=4, camera_model="RADIAL", width=640, height=480,
                                seed=0))


@pytest.fixture(scope="module")
def with_stray(rig):
    """(one frame set, names): `rig`'s four cameras and a fifth, "stray", filming another scene."""
    other = generate_rig(RigSpec(lenses="ideal", num_cameras=4, camera_model="RADIAL", width=640,
                                 height=480, seed=7))
    return [list(rig.images[0]) + [other.images[0][0]]], list(rig.names) + ["stray"]


def test_generated_rig_recovers_ground_truth(rig):
    config = make_config("regular", matcher="sift", sfm__num_threads=1)
    result = run_calibration([rig.images[0]], rig.names, config)
    metrics = evaluate_calibration(result.rig, rig.ground_truth())
    # Tolerances: every camera registered, relative poses within 3 deg for >= 80 % (AUC@3),
    # median focal error <= 2 %.
    assert metrics["num_registered"] == 4
    assert metrics["auc3"] >= 80.0
    assert metrics["median_focal_err"] <= 0.02
    assert result.rig.reference_camera == rig.names[0]
    np.testing.assert_allclose(result.rig.cameras[rig.names[0]].cam_from_rig, np.eye(4),
                               atol=1e-9)
    assert result.rig.quality.reprojection_rms_px < 5.0
    assert result.reconstruction.num_reg_images() == 4
    assert {im.name for im in result.reconstruction.images.values()} == set(rig.names)
    # the points carry the scene's colour: that of the reference image where they project
    rec = result.reconstruction
    image = next(im for im in rec.images.values() if im.name == rig.names[0])
    xyz = np.array([p.xyz for p in rec.points3D.values()])
    colours = np.array([p.color for p in rec.points3D.values()], dtype=float)
    in_cam = xyz @ image.cam_from_world().rotation.matrix().T + image.cam_from_world().translation
    uv = np.floor(rec.cameras[image.camera_id].img_from_cam(in_cam)).astype(int)
    h, w = rig.images[0][0].shape[:2]
    inside = (uv[:, 0] >= 0) & (uv[:, 0] < w) & (uv[:, 1] >= 0) & (uv[:, 1] < h)
    seen = rig.images[0][0][uv[inside, 1], uv[inside, 0]].reshape(inside.sum(), -1)[:, :3]
    error = np.abs(colours[inside] - seen).mean()
    shuffled = np.abs(colours[inside] - np.random.default_rng(0).permutation(seen)).mean()
    assert inside.sum() > 50 and error < 0.5 * shuffled, (error, shuffled)


def test_point_colours_average_the_pixels_of_each_tracks_frame_set():
    from densecalib_ros.core.method.reconstruction import point_colours
    from densecalib_ros.core.types import Tracks

    sets = [[np.zeros((4, 6, 3), np.uint8), np.full((4, 6), 50, np.uint8)],
            [np.zeros((4, 6, 3), np.uint8), np.zeros((4, 6), np.uint8)]]
    sets[0][0][2, 5] = (100, 0, 200)
    sets[1][0][1, 0] = (10, 20, 30)
    xy = np.array([[[5.9, 2.0], [0.5, 0.5]],  # pixel (5, 2) of set 0's colour image; grey 50
                   [[0.2, 1.7], [np.nan, np.nan]]])  # set 1: pixel (0, 1) alone
    tracks = Tracks(xy, np.array([2, 2], np.int32), np.zeros(2), np.array([0, 1], np.int32))
    np.testing.assert_array_equal(point_colours(tracks, sets), [[75, 25, 125], [10, 20, 30]])


def test_rig_mixing_lenses_gets_each_cameras_lens_model():
    """A fisheye camera among pinhole ones (camera_lens): it is calibrated as OPENCV_FISHEYE, the
    others with the perspective model (OPENCV: the refinement on the images frees their pixel
    aspect), and the rig is recovered."""
    models = ("RADIAL", "OPENCV_FISHEYE", "RADIAL", "RADIAL")
    rig = generate_rig(RigSpec(lenses="ideal", num_cameras=4, camera_models=models, width=640, height=480,
                               seed=0))
    config = make_config("regular", matcher="sift", sfm__num_threads=1, consensus_runs=1,
                         cameras__lens={"cam1": "fisheye"})
    result = run_calibration([rig.images[0]], rig.names, config)
    assert [result.rig.cameras[n].intrinsics.model for n in rig.names] == [
        "OPENCV", "OPENCV_FISHEYE", "OPENCV", "OPENCV"]
    assert result.rig.quality.camera_lens == {"cam1": "fisheye"}
    metrics = evaluate_calibration(result.rig, rig.ground_truth())
    assert metrics["num_registered"] == 4
    assert metrics["auc3"] >= 80.0
    assert max(c["focal_err"] for c in metrics["cameras"].values()) <= 0.03
    with pytest.raises(InputError, match="unknown camera"):
        run_calibration([rig.images[0]], rig.names,
                        make_config("regular", cameras__lens={"cam7": "fisheye"}))


def test_camera_lens_gives_per_camera_models_and_the_fisheye_sfm_options():
    """A configuration resolved for its cameras (PipelineConfig.for_cameras) gives each camera its
    lens's model, and a rig with a fisheye camera the fisheye preset's SfM options."""
    names = ["a", "b", "c"]
    plain = make_config("regular").for_cameras(names)
    assert plain.camera_names == tuple(names) and plain.sfm.models(3) == ["RADIAL"] * 3
    mixed = make_config("regular", cameras__lens={"c": "fisheye"}).for_cameras(names)
    assert mixed.sfm.models(3) == ["RADIAL", "RADIAL", "RADIAL_FISHEYE"]
    fisheye = make_config("fisheye")
    for name in ("f_err_px", "b_err_px", "refine_to_model", "refine_principal_point"):
        assert getattr(mixed.sfm, name) == getattr(fisheye.sfm, name), name
    assert mixed.for_cameras(names) is mixed  # resolved once
    with pytest.raises(InputError, match="resolved for the cameras a, b, c"):
        mixed.for_cameras(["a", "b"])
    inverse = make_config("fisheye", "global", cameras__lens={"a": "pinhole"}).for_cameras(names)
    assert inverse.sfm.models(3) == ["RADIAL", "RADIAL_FISHEYE", "RADIAL_FISHEYE"]
    assert inverse.sfm.b_err_px is None  # the global preset's
    # Whose principal point the final adjustment refines (and whose sigma core.method.uncertainty
    # gives).
    assert plain.sfm.principal_point_cameras(3) == ()
    assert fisheye.sfm.principal_point_cameras(3) == (0, 1, 2)
    assert mixed.sfm.principal_point_cameras(3) == (2,)
    assert inverse.sfm.principal_point_cameras(3) == (1, 2)
    # F_err: off for the fisheye preset, but a pair of a mixed rig's pinhole cameras is tested.
    assert plain.sfm.pair_f_err_px(0, 1) == 10.0 and fisheye.sfm.pair_f_err_px(0, 1) is None
    assert mixed.sfm.pair_f_err_px(0, 1) == 10.0 and mixed.sfm.pair_f_err_px(0, 2) is None
    assert inverse.sfm.pair_f_err_px(0, 1) is None and inverse.sfm.pair_f_err_px(1, 2) is None
    with pytest.raises(InputError, match="Unknown lens"):
        make_config(cameras__lens={"a": "tele"}).for_cameras(names)
    with pytest.raises(InputError, match="unknown camera"):
        make_config(cameras__lens={"z": "fisheye"}).for_cameras(names)


def test_a_configuration_is_frozen_and_checked_where_a_calibration_starts():
    """Options are set when a configuration is made (make_config, with_options), never on one;
    values no stage can run with are refused where the calibration starts, naming the option."""
    import dataclasses

    config = make_config("regular")
    with pytest.raises(dataclasses.FrozenInstanceError):
        config.sampling.seed = 3
    seeded = config.with_options(sampling__seed=3, matcher="asift")
    assert (seeded.sampling.seed, seeded.matcher) == (3, "asift") and config.sampling.seed == 0
    with pytest.raises(InputError, match="Unknown option 'sampling__sed'"):
        config.with_options(sampling__sed=3)
    for option, value in (("consensus_runs", 0), ("sampling__max_cycle_order", 5),
                          ("sfm__f_err_px", -1.0), ("max_image_side_px", 10.5),
                          ("sfm__global_init", "nowhere")):
        with pytest.raises(InputError, match=f"Option {option} = "):
            config.with_options(**{option: value}).for_cameras(["a", "b"])
    with pytest.raises(InputError, match="Unknown camera model 'RADIAL_X'"):
        config.with_options(sfm__camera_model="RADIAL_X").check()


def test_loaded_matcher_is_reused_and_result_is_deterministic(rig):
    config = make_config("regular", matcher="sift", sfm__num_threads=1)
    matcher = create_matcher("sift", max_image_side_px=config.max_image_side_px)
    matcher.load()
    frames = [rig.images[0][:3]]
    a = calibrate_rig(frames, rig.names[:3], config, matcher=matcher)
    b = calibrate_rig(frames, rig.names[:3], config, matcher=matcher)
    for name in a.cameras:
        np.testing.assert_allclose(a.cameras[name].intrinsics.params,
                                   b.cameras[name].intrinsics.params, rtol=1e-6)


def test_converging_wide_rig_whose_eq2_focals_are_far_off_is_calibrated():
    """Three cameras 45 deg apart whose optical axes meet: eq. 2 is degenerate there and puts the
    focals at about 0.2x the truth (140-175 px for 714-858 px), beyond the multi-start's eq. 2
    scale starts, and COLMAP's generic prior (1.2 x 1024 px) is too far the other way; the
    wider-lens generic priors (multistart.PRIOR_FOCAL_IMAGE_RATIOS) reach it. With only the
    1.2 prior this rig came out wrong (every camera pair > 40 deg off)."""
    rig = generate_rig(RigSpec(lenses="ideal", num_cameras=3, camera_model="RADIAL", width=1024, height=768,
                               seed=711, gap_deg=45.0, max_arc_deg=360.0))
    config = make_config("regular", matcher="sift", sfm__num_threads=1, consensus_runs=1)
    messages = []
    result = run_calibration([rig.images[0]], rig.names, config, progress=messages.append)
    initial = next(m for m in messages if m.startswith("initial focals"))
    assert all(int(x.split("=")[1]) < 300 for x in initial.split(": ")[1].split(", "))
    metrics = evaluate_calibration(result.rig, rig.ground_truth())
    assert metrics["num_registered"] == 3
    assert metrics["auc3"] >= 66.0
    assert metrics["median_focal_err"] <= 0.05


@pytest.mark.parametrize("pipeline", ["incremental", "global"])
def test_multistart_is_judged_on_matches_the_sampled_tracks_left_out(pipeline):
    """Three cameras 40 deg apart: from some focal starts SfM reaches a wrong rig (AUC@3 11) that
    fits the sampled tracks it was built from better than the right one (0.33 vs 0.41 px), but
    fits the other keypoint matches worse (2.17 vs 2.02 px). Judged on the sampled tracks, three
    of the five consensus runs took the wrong rig and it was kept; judged on the left-out
    matches, every run is right. The global pipeline's incremental start and its choice between
    starts are judged the same way (judged on the sampled tracks it gave AUC@3 11.1 here)."""
    rig = generate_rig(RigSpec(lenses="ideal", num_cameras=3, camera_model="RADIAL", width=1024, height=768,
                               seed=704, gap_deg=40.0, max_arc_deg=360.0))
    config = make_config("regular", pipeline, matcher="sift", sfm__num_threads=1)
    result = run_calibration([rig.images[0]], rig.names, config)
    metrics = evaluate_calibration(result.rig, rig.ground_truth())
    assert metrics["auc3"] >= 66.0
    assert result.rig.quality.consensus_disagreement_deg < 1.0


def test_images_without_overlap_fail_with_overlap_error_naming_each_pairs_matches():
    rng = np.random.default_rng(0)
    frames = [[rng.integers(0, 255, (240, 320), dtype=np.uint8) for _ in range(3)]]
    with pytest.raises(NotEnoughOverlapError) as error:
        calibrate_rig(frames, ["a", "b", "c"], make_config("regular", matcher="sift"))
    said = str(error.value)
    assert re.search(r"Keypoint matches per camera pair \(sift, fewest first\): "
                     r"(a/b|a/c|b/c) \d+, (a/b|a/c|b/c) \d+, (a/b|a/c|b/c) \d+; "
                     r"[abc] and [abc] need frame sets in which both see", said), said


def test_two_camera_groups_without_common_view_are_named():
    """Two pairs filming different scenes: one rig cannot come of it; the error names the groups
    (SfM used to calibrate one group by chance, or fail "from any pair of cameras a0, a1")."""
    from densecalib_ros.core.errors import DisconnectedViewGraphError

    a, b = (generate_rig(RigSpec(lenses="ideal", num_cameras=4, camera_model="RADIAL", width=320, height=240,
                                 seed=s)) for s in (1, 7))
    sets = [[x[0], x[1], y[2], y[3]] for x, y in zip(a.images, b.images)]
    with pytest.raises(DisconnectedViewGraphError, match=r"2 groups .*\{a0, a1\}; \{b2, b3\}"):
        calibrate_rig(sets, ["a0", "a1", "b2", "b3"], make_config("regular", matcher="sift"))


def test_one_camera_and_inconsistent_input_fail_clearly(rig):
    config = make_config("regular", matcher="sift")
    with pytest.raises(NotEnoughCamerasError, match="at least two"):
        calibrate_rig([[rig.images[0][0]]], ["only"], config)
    with pytest.raises(InputError, match="3 images for 2 cameras"):
        calibrate_rig([rig.images[0][:3]], ["a", "b"], config)


def test_bad_names_and_images_are_refused_before_any_work(rig, tmp_path):
    """Each with a message that names the camera and frame set; a camera name that would write
    outside the output folder never reaches a file."""
    config = make_config("regular", matcher="sift")
    images = [list(s) for s in rig.images]
    names = list(rig.names)
    for bad, message in ((["/cam0/image_raw"] + names[1:], "cannot name a file"),
                         (["../up"] + names[1:], "cannot name a file"),
                         ([names[0]] * len(names), f"repeat \\({names[0]}\\)"),
                         (list(range(len(names))), "must be strings, got 0 \\(int\\)")):
        with pytest.raises(InputError, match=message):
            calibrate_rig(images, bad, config)
    last = len(images) - 1
    for bad, message in ((images[last][1].astype(np.float32), "dtype float32"),
                         (images[last][1][..., :1], r"\(one channel: image\[..., 0\]\)"),
                         (None, "is a NoneType, not a numpy array")):
        broken = [list(s) for s in images]
        broken[last][1] = bad
        with pytest.raises(InputError, match=f"camera {names[1]} in frame set {last} .*{message}"):
            calibrate_rig(broken, names, config)
    with pytest.raises(InputError, match="Frame set 0 is not a list of images"):
        calibrate_rig([images[0][0]], names, config)  # one image, not a frame set
    twice = [list(s) for s in images]  # one camera's images given under two names
    twice[last][2] = twice[last][0].copy()
    with pytest.raises(InputError, match=f"Cameras {names[0]} and {names[2]} gave identical "
                                         f"images in frame set {last}: one camera was given twice"):
        calibrate_rig(twice, names, config)
    twice[last][0] = twice[last][2] = np.zeros_like(images[last][0])  # two covered lenses: no
    from densecalib_ros.core.method.frame_checks import (check_frame_sets)
    check_frame_sets(twice, names)
    stacked = np.stack([np.stack(s) for s in images])  # (T, C, H, W, 3) is fine as frame sets
    assert check_frame_sets(stacked, names) == check_frame_sets(images, names)
    # a read calibration is checked too: its camera names become file names on export
    from densecalib_ros.core.io.export import read_calibration, write_calibration_files
    truth = rig.ground_truth()
    write_calibration_files(truth, str(tmp_path / "calib"))  # a str folder is fine
    text = (tmp_path / "calib" / "calibration.json").read_text()
    (tmp_path / "calib" / "calibration.json").write_text(text.replace(f'"{names[1]}"',
                                                                      '"../../x"'))
    with pytest.raises(InputError, match="damaged calibration file .*calibration.json: Camera "
                                         "name '../../x'"):
        read_calibration(tmp_path / "calib")


def test_a_settled_first_run_that_registered_every_camera_is_the_only_one_and_single_run_has_no_consensus(rig):
    """An easy rig: every focal start that fits about as well ends in one rig (settled) and every
    camera is registered, so another sample could only repeat the first run: no second run. A
    settled run that left a camera out, or one that did not settle, is checked by more runs."""
    from dataclasses import replace

    from densecalib_ros.core.progress import Progress
    from densecalib_ros.core.robust.consensus_runs import ConsensusRuns
    from densecalib_ros.core.products.report import overall_lines

    config = make_config("regular", matcher="sift", sfm__num_threads=1)
    assert config.consensus_runs == 5
    lines = []
    result = run_calibration([rig.images[0]], rig.names, config, progress=lines.append)
    q = result.rig.quality
    assert q.consensus_runs == 1 and q.consensus_failed_runs == 0 and q.consensus_seed == 0
    assert len(q.consensus_settled_starts) == 2
    assert not any(m.startswith("consensus run 2") for m in lines)
    assert any("one run: every focal start" in line for line in overall_lines(result.rig))
    # The consensus policy on that run (each run gives the same result): settled and whole, it
    # alone answers; a camera left out, or a multi-start that did not settle, takes a second run
    # (which agrees, so no third).
    unsettled = replace(result, settled_starts=None)
    for run, names, runs_made in ((result, rig.names, 1),
                                  (result, rig.names + ["cam_left_out"], 2),
                                  (unsettled, rig.names, 2)):
        runs = ConsensusRuns(lambda seed, starts, progress: run, config, names, Progress())
        assert len(runs.run().results) == runs_made, names
    single = run_calibration([rig.images[0]], rig.names,
                             make_config("regular", matcher="sift", sfm__num_threads=1,
                                         consensus_runs=1))
    assert single.rig.quality.consensus_runs is None


def test_first_runs_apart_refined_go_to_the_second_matcher_after_two_runs(rig):
    """Two runs that the images, refined, leave apart beyond the warning's threshold are the
    second matcher's case: its rule ends sift's runs there instead of after three more (they stay
    apart however many are made); runs that the images bring together end the consensus as
    before, and without a refined judgement the runs go on."""
    import copy
    from dataclasses import replace

    from densecalib_ros.core.progress import Progress
    from densecalib_ros.core.robust.consensus import WARN_DISAGREEMENT_DEG, rig_disagreement_deg
    from densecalib_ros.core.robust.consensus_runs import ConsensusRuns
    from densecalib_ros.core.robust.second_matcher import first_runs_undetermined

    config = make_config("regular", matcher="sift", sfm__num_threads=1)
    found = run_calibration([rig.images[0]], rig.names, config)
    turned = copy.deepcopy(found.rig)  # the same rig with one camera turned 20 deg about y
    c, s = np.cos(np.radians(20.0)), np.sin(np.radians(20.0))
    camera = turned.cameras[rig.names[-1]]
    camera.cam_from_rig = camera.cam_from_rig.copy()
    camera.cam_from_rig[:3, :3] = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]) \
        @ camera.cam_from_rig[:3, :3]
    runs_made = [replace(found, settled_starts=None), replace(found, rig=turned,
                                                                settled_starts=None)]

    def once(seed, starts, progress):
        return runs_made[seed % 2]

    def as_found(results):  # the runs "refined": as they are, 20 deg apart on the turned pairs
        return np.array([[rig_disagreement_deg(a.rig, b.rig, rig.names) for b in results]
                         for a in results])

    runs = ConsensusRuns(once, config, rig.names, Progress(), as_found).run(
        first_runs_undetermined)
    assert len(runs.results) == 2 and runs.cut_short
    assert runs.judged_apart_deg > WARN_DISAGREEMENT_DEG
    runs.run()  # completed where the other matcher does no better: on from the third run
    assert len(runs.results) == config.consensus_runs and not runs.cut_short
    together = ConsensusRuns(once, config, rig.names, Progress(),
                             lambda results: np.zeros((2, 2))).run(first_runs_undetermined)
    assert len(together.results) == 2 and not together.cut_short
    unrefined = ConsensusRuns(once, config, rig.names, Progress()).run(first_runs_undetermined)
    assert len(unrefined.results) == config.consensus_runs and not unrefined.cut_short


def test_two_agreeing_runs_end_the_consensus_where_the_multi_start_did_not_settle(rig):
    """Every camera's intrinsics given and one start (no first-pair starts): the multi-start has
    no second trial to settle with. The second run, on another track sample, lands in the first
    one's rig: they have answered the sampling's lottery, so no third run is made (it used to
    take three where the first run had not settled)."""
    gt = rig.ground_truth()
    known = {n: gt.cameras[n].intrinsics for n in rig.names}
    lines = []
    result = run_calibration([rig.images[0]], rig.names,
                             make_config("regular", matcher="sift", sfm__num_threads=1,
                                         sfm__brute_force_first_pair=False,
                                         cameras__known_intrinsics=known),
                             progress=lines.append)
    q = result.rig.quality
    assert q.consensus_settled_starts is None
    assert q.consensus_runs == 2 and q.consensus_disagreement_deg < 1.0
    assert any(m.startswith("consensus run 2") for m in lines)
    assert not any(m.startswith("consensus run 3") for m in lines)
    assert evaluate_calibration(result.rig, gt)["auc3"] >= 80.0


def test_runs_that_leave_the_same_camera_out_agree_and_the_user_is_told_what_would_place_it(rig, with_stray):
    """A fifth camera filming another scene is registered by no run. The runs agree on the four
    others, so the consensus stops at its early stop (the pairs with the stray camera, placed by
    neither run, say nothing about their agreement: they used to count 180 deg and every run was
    made, with a warning that the runs disagree); the warning names the camera, its best partner
    and what would place it."""
    frames, names = with_stray
    lines = []
    result = run_calibration(frames, names,
                             make_config("regular", matcher="sift", second_matcher=None,
                                         sfm__num_threads=1), progress=lines.append)
    q = result.rig.quality
    assert result.rig.failed_cameras == ["stray"] and len(result.rig.cameras) == 4
    assert q.consensus_runs == 2 and q.consensus_disagreement_deg < 1.0
    partner, count = q.unregistered_best_partner["stray"]
    assert partner in rig.names and 0 <= count < 50
    assert len(q.warnings) == 1 and not any("disagree" in w for w in q.warnings)
    assert q.warnings[0].startswith(f"stray could not be registered: it shares at most {count} "
                                    f"keypoint matches with another camera ({partner}). The "
                                    "other 4 cameras are calibrated without it.")
    assert "--matcher asift" in q.warnings[0]
    assert sum(q.warnings[0] in line for line in lines) == 1  # said once


def test_a_rig_left_with_one_pair_is_refused_unless_the_pairs_intrinsics_are_given(rig, with_stray):
    """Two of the rig's cameras and the stray one: only the pair registers. Self-calibrated, one
    pair's geometry leaves its focal lengths open and nothing checks it, so the calibration is
    refused (stages.record.pair_alone_refusal) naming the pair and the stray camera; with the
    pair's intrinsics given it is calibrated, the stray camera warned of."""
    frames, names = with_stray
    three = [[frames[0][0], frames[0][1], frames[0][-1]]]
    pair_and_stray = [names[0], names[1], "stray"]
    config = dict(matcher="sift", second_matcher=None, sfm__num_threads=1)
    with pytest.raises(UndeterminedRigError) as refused:
        run_calibration(three, pair_and_stray, make_config("regular", **config))
    assert str(refused.value).startswith(f"the calibration is refused: of the 3 cameras only "
                                         f"{names[0]} and {names[1]} were registered")
    assert "stray could not be registered" in str(refused.value)
    gt = rig.ground_truth()
    known = {n: gt.cameras[n].intrinsics for n in names[:2]}
    result = run_calibration(three, pair_and_stray,
                             make_config("regular", cameras__known_intrinsics=known, **config))
    assert result.rig.failed_cameras == ["stray"] and len(result.rig.cameras) == 2
    assert evaluate_calibration(result.rig, gt)["pairs"][0]["rot_err_deg"] < 0.5
    assert result.rig.quality.warnings[0].startswith("stray could not be registered")


def test_a_camera_the_first_sift_run_leaves_out_goes_to_asift_after_that_one_run(rig, with_stray):
    """The stray camera of the test above with the second matcher on: sift's first consensus run
    leaves it out, so asift is tried right after that run instead of after sift's further runs.
    Where asift does no better, sift's runs are completed and the rig is the one the consensus
    without a second matcher gives (the test above: two runs that agree; the test below makes
    asift give nothing)."""
    frames, names = with_stray
    lines = []
    result = run_calibration(frames, names,
                             make_config("regular", matcher="sift", sfm__num_threads=1),
                             progress=lines.append)
    q = result.rig.quality
    rematch = [k for k, m in enumerate(lines)
               if m.startswith("sift: stray not registered; matching again with asift")]
    assert len(rematch) == 1
    before = lines[:rematch[0]]
    assert sum(m.startswith("consensus run 1 of up to 5") for m in before) == 1
    assert not any(m.startswith("consensus run 2") for m in before)
    # that run is not refined on the images before asift has had its say (with_second_matcher)
    assert not any(m.startswith("refined on") and "dense image" in m for m in before)
    assert result.rig.failed_cameras == ["stray"] and len(result.rig.cameras) == 4
    assert q.rematch["first_result"] == "stray not registered"
    completed = [m for m in lines if m == "asift: no better determined; completing sift's "
                                          "consensus runs"]
    if q.rematch["kept"] == "sift":
        assert len(completed) == 1
        assert q.consensus_runs == 2 and q.consensus_disagreement_deg < 1.0
    else:
        assert not completed and q.matcher == "asift"
    assert evaluate_calibration(result.rig, rig.ground_truth())["auc3"] >= 80.0


def test_where_asift_does_no_better_sifts_runs_are_completed_as_without_it(rig, with_stray):
    """The same sift matches, and images in which asift finds nothing (uniform grey): asift's
    leg gives no calibration, so sift's consensus runs go on after its one run (not made again),
    and the kept rig is the consensus's of the test above (two runs that agree; the grey images
    leave the dense refinement nothing, so the rig is kept as the matches found it)."""
    from densecalib_ros.core.progress import Progress
    from densecalib_ros.core.robust.second_matcher import with_second_matcher
    from densecalib_ros.core.stages.attempt import Calibrator
    from densecalib_ros.core.stages.inputs import prepare
    from densecalib_ros.core.stages.matching import match_rig

    frames, names = with_stray
    config = make_config("regular", matcher="sift", sfm__num_threads=1)
    grey = prepare([[np.full_like(image, 128) for image in frames[0]]], names, config)
    lines = []
    progress = Progress(on_message=lines.append)
    calibrators = {"sift": Calibrator(grey, match_rig(prepare(frames, names, config),
                                                      grey.config, progress),
                                      grey.config, progress)}

    def calibrate(name, until, refine_cut_short=True):
        if name not in calibrators:
            other = grey.config.with_options(matcher=name)
            calibrators[name] = Calibrator(grey, match_rig(grey, other, progress), other,
                                           progress)
        return calibrators[name].calibrate(until, refine_cut_short)
    kept, rematch = with_second_matcher(calibrate, grey.config, names, True, progress.say)
    q = kept.rig.quality
    assert kept.config.matcher == "sift" and rematch.record() == {
        "first": "sift", "first_result": "stray not registered", "second": "asift",
        "second_result": "no calibration came out", "kept": "sift"}
    done = lines.index("asift: no better determined; completing sift's consensus runs")
    assert not any(m.startswith("consensus run 1 of up to 5") for m in lines[done:])
    assert sum(m.startswith("consensus run 2 of up to 5") for m in lines[done:]) == 1
    assert q.consensus_runs == 2 and q.consensus_disagreement_deg < 1.0
    assert kept.rig.failed_cameras == ["stray"] and len(kept.rig.cameras) == 4
    assert evaluate_calibration(kept.rig, rig.ground_truth())["auc3"] >= 80.0


def test_known_focal_lengths_are_the_start_and_bad_ones_are_refused(rig):
    """initial_focal_px (CLI --focal-px, node initial_focal_px) replaces the eq. 2 estimate in
    the sampling and as the SfM's start; the SfM still refines it."""
    gt = rig.ground_truth()
    truth = np.array([gt.cameras[n].intrinsics.params[0] for n in rig.names])
    config = make_config("regular", matcher="sift", sfm__num_threads=1, consensus_runs=1,
                         cameras__initial_focal_px={"*": 1.1 * truth[0],
                                                    rig.names[1]: 1.1 * truth[1]})
    result = run_calibration([rig.images[0]], rig.names, config)
    start = np.full(len(rig.names), 1.1 * truth[0])
    start[1] = 1.1 * truth[1]
    np.testing.assert_allclose(result.focal_init_px, start)
    metrics = evaluate_calibration(result.rig, gt)
    assert metrics["auc3"] >= 80.0 and metrics["median_focal_err"] <= 0.02  # refined from +10 %

    for hint, message in (({"nope": 500.0}, "unknown camera"),
                          ({rig.names[0]: 500.0}, "No initial focal length for camera"),
                          ({"*": -5.0}, "must be positive")):
        lines = []
        with pytest.raises(InputError, match=message):
            run_calibration([rig.images[0]], rig.names,
                            make_config("regular", matcher="sift", consensus_runs=1,
                                        cameras__initial_focal_px=hint), progress=lines.append)
        # Refused at once: bad input is not a reason to match again with asift (few cameras).
        assert not any("matching again" in m for m in lines)


def test_exif_focals_start_the_cameras_they_name_below_the_users_and_a_previous_calibration(rig):
    """config.cameras.exif_focal_px (the offline command reads it from the images' EXIF) is the
    start of the cameras it names; the others are estimated (eq. 2, at the named cameras' scale)."""
    gt = rig.ground_truth()
    truth = np.array([gt.cameras[n].intrinsics.params[0] for n in rig.names])
    names, sizes = rig.names, [(640, 480)] * 4
    config = make_config("regular", matcher="sift", sfm__num_threads=1, consensus_runs=1,
                         cameras__exif_focal_px={names[0]: 1.05 * truth[0], "not-a-camera": 999.0})
    result = run_calibration([rig.images[0]], names, config)
    assert result.focal_init_px[0] == pytest.approx(1.05 * truth[0])
    assert np.all(np.isfinite(result.focal_init_px)) and result.rig.quality.exif_focal_px == {
        names[0]: pytest.approx(1.05 * truth[0], abs=0.1), "not-a-camera": 999.0}
    metrics = evaluate_calibration(result.rig, gt)
    assert metrics["auc3"] >= 80.0 and metrics["median_focal_err"] <= 0.02

    exif = {n: 800.0 for n in names}
    user_some = {names[0]: 700.0, names[1]: 710.0, names[2]: 720.0}
    np.testing.assert_allclose(  # the user's focals first, EXIF for the rest
        start_focals(make_config(cameras__initial_focal_px=user_some, cameras__exif_focal_px=exif),
                     None, names, sizes), [700.0, 710.0, 720.0, 800.0])
    np.testing.assert_allclose(  # a previous calibration of the same cameras before EXIF
        start_focals(make_config(cameras__exif_focal_px=exif), gt, names, sizes), truth)


def test_known_focals_add_a_start_and_keep_the_eq2_start():
    """With the true focals as the only start, SfM on this 3-camera rig (40 deg apart) picks the
    wide first pair, whose relative pose the still unmodelled distortion turns by ~11 deg, and
    ends in a wrong rig (AUC@3 22); from eq. 2's start it ends right. Known focals (user, EXIF)
    therefore join the multi-start beside eq. 2 and the matches decide."""
    rig = generate_rig(RigSpec(lenses="ideal", num_cameras=3, camera_model="RADIAL", seed=704, gap_deg=40.0,
                               max_arc_deg=360.0))
    gt = rig.ground_truth()
    truth = {n: float(gt.cameras[n].intrinsics.params[0]) for n in rig.names}
    # The multi-start is what is tested: the image refinement, which moves a rig within its
    # basin afterwards, is left out (on this rig of ideal lenses it turned AUC@3 100 to 44: see
    # core.method.image_refinement on rigs of three cameras).
    config = make_config("regular", matcher="sift", sfm__num_threads=1, consensus_runs=1,
                         cameras__initial_focal_px=truth, refine_on_images=False)
    messages = []
    result = run_calibration([rig.images[0]], rig.names, config, progress=messages.append)
    metrics = evaluate_calibration(result.rig, gt)
    assert metrics["auc3"] >= 90.0 and metrics["median_focal_err"] <= 0.02
    assert any(m.startswith("focal multi-start") and "eq. 2:" in m for m in messages)


def test_consensus_runs_that_end_in_different_minima_give_the_rig_that_fits_best():
    """Four cameras 45 deg apart whose sift matches leave minima that differ in one end camera's
    focal: the five runs end in different rigs (which of them right depends on the CPU's floating
    point: on one all five were wrong, on another the last right). The kept run, hopped where a
    better minimum is near it (core.robust.focal_hops; test_focal_hops has such a minimum made on
    purpose), is the right rig."""
    rig = generate_rig(RigSpec(lenses="ideal", num_cameras=4, camera_model="RADIAL", width=1024,
                               height=768, seed=704, gap_deg=45.0, max_arc_deg=360.0))
    # The image refinement after the consensus moved this rig of ideal lenses (principal points
    # within 4 px of the centre) from 100 to 83.3; sift's runs stay the result (no second matcher).
    config = make_config("regular", matcher="sift", sfm__num_threads=1, refine_on_images=False,
                         second_matcher=None)
    result = run_calibration([rig.images[0]], rig.names, config)
    metrics = evaluate_calibration(result.rig, rig.ground_truth())
    assert result.rig.quality.consensus_kept_by_fit
    assert metrics["auc3"] >= 88.0
    assert metrics["median_focal_err"] <= 0.02


def test_three_cameras_far_apart_that_sift_cannot_calibrate_are_matched_again_with_asift():
    """Three cameras 55 deg apart (640x480): sift's matches give no calibration; the pipeline
    matches again with asift (config.second_matcher) and calibrates the rig, and says so."""
    wide = generate_rig(RigSpec(num_cameras=3, camera_model="RADIAL", width=640, height=480,
                                seed=1, gap_deg=55.0, max_arc_deg=360.0))
    off = make_config("regular", matcher="sift", second_matcher=None, sfm__num_threads=1)
    with pytest.raises(CalibrationError):
        run_calibration([wide.images[0]], wide.names, off)
    lines = []
    config = make_config("regular", matcher="sift", sfm__num_threads=1)
    result = run_calibration([wide.images[0]], wide.names, config, progress=lines.append)
    q = result.rig.quality
    # asift's verdict: a calibration, its focal sigma on either side of the 1 % aim (1.0 % on
    # one CPU, 1.1 % on another: three cameras of 640x480 hold their focal lengths only so well).
    verdicts = dict(q.rematch)
    second_result = verdicts.pop("second_result")
    assert q.matcher == "asift" and verdicts == {
        "first": "sift", "first_result": "no calibration came out", "second": "asift",
        "kept": "asift"}
    assert second_result == "determined" or second_result.startswith(
        "the focal lengths are determined to 1.")
    assert any(m.startswith("sift: no calibration came out; matching again with asift")
               for m in lines)
    assert evaluate_calibration(result.rig, wide.ground_truth())["auc3"] > 80.0


def test_an_essential_matrix_with_too_few_inliers_is_a_failed_pair_not_an_opencv_error():
    """Three cameras 55 deg apart (640x480, another seed): one pair's essential matrix fit too
    few of sift's matches for OpenCV's recoverPose, which raised an assertion error; the pair now
    counts as failed, and the other pairs calibrate the rig."""
    wide = generate_rig(RigSpec(num_cameras=3, camera_model="RADIAL", width=640, height=480,
                                seed=3, gap_deg=55.0, max_arc_deg=360.0))
    off = make_config("regular", matcher="sift", second_matcher=None, sfm__num_threads=1)
    result = run_calibration([wide.images[0]], wide.names, off)
    assert len(result.rig.cameras) == 3


def test_a_rig_a_noisy_camera_keeps_from_the_image_refinement_is_warned_unrefined(rig):
    """A camera whose images are too noisy for the patch alignment (no aligned patch correlates
    at MIN_NCC) while SIFT still matches them: the rig is registered but kept as the SfM found
    it, and the user is told so, naming the camera and what would fix it; the same rig with a
    clean camera is refined and not warned."""
    from densecalib_ros.core.method.dense_matches import MIN_CAMERA_OBSERVATIONS

    config = make_config("regular", matcher="sift", sfm__num_threads=1, consensus_runs=1,
                         second_matcher=None)
    noisy = [im.copy() for im in rig.images[0]]
    noise = np.random.default_rng(0).normal(0.0, 45.0, noisy[3].shape)
    noisy[3] = np.clip(noisy[3] + noise, 0, 255).astype(np.uint8)
    for images, thin in ((rig.images[0], None), (noisy, rig.names[3])):
        q = run_calibration([images], rig.names, config).rig.quality
        said = [w for w in q.warnings if w.startswith("not refined on the images")]
        if thin is None:
            assert q.image_refinement_tracks and not q.image_refinement_too_few_dense and not said
            continue
        assert len(q.image_refinement_too_few_dense) == 1
        assert q.image_refinement_too_few_dense[thin] < MIN_CAMERA_OBSERVATIONS
        assert q.image_refinement_tracks is None and len(said) == 1
        assert f"{thin} kept" in said[0] and f"in which {thin} sees" in said[0]
