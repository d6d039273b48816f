"""The second matcher where sift leaves a perspective rig undetermined (core.robust.second_matcher):
when sift's calibration counts as undetermined, which result is kept, and where the second matcher
applies at all. The pipeline's use of it on a generated wide rig is in test_pipeline.py."""
import numpy as np
from scipy.spatial.transform import Rotation

from densecalib_ros.core.config import make_config
from densecalib_ros.core.robust.consensus import WARN_DISAGREEMENT_DEG
from densecalib_ros.core.method.focal_determination import AIMED_FOCAL_STD_FRACTION
from densecalib_ros.core.robust.second_matcher import (better_determined, rematch_applies,
                                                    undetermined)
from densecalib_ros.core.types import CameraIntrinsics, CameraQuality, RigCalibration, RigCamera


def _rig(names=("a", "b", "c"), failed=(), disagreement=None, focal_std_fraction=None,
         step_deg=30.0, rotation_std_deg=None):
    """Cameras turned step_deg from each other about the vertical; rotation_std_deg: the
    sigmas of the cameras but the reference ("a"), in order."""
    cam = CameraIntrinsics("RADIAL", 640, 480, np.array([500.0, 320, 240, 0, 0]))
    cameras = {}
    for i, n in enumerate(names):
        quality = None if focal_std_fraction is None else CameraQuality(
            0.5, 1000, 0.8, focal_std_px=500.0 * focal_std_fraction,
            rotation_std_deg=rotation_std_deg[i - 1] if rotation_std_deg and i else None)
        cam_from_rig = np.eye(4)
        cam_from_rig[:3, :3] = Rotation.from_euler("y", i * step_deg, degrees=True).as_matrix()
        cameras[n] = RigCamera(n, cam, cam_from_rig, quality)
    rig = RigCalibration("a", cameras, failed_cameras=list(failed))
    rig.quality.consensus_disagreement_deg = disagreement
    return rig


def test_a_calibration_is_undetermined_without_result_with_a_failed_camera_or_runs_apart():
    assert undetermined(None) == "no calibration came out"
    assert undetermined(_rig(("a", "b"), failed=["c"])) == "c not registered"
    far = undetermined(_rig(disagreement=WARN_DISAGREEMENT_DEG + 2.0))
    assert far == f"the calibration runs disagree by {WARN_DISAGREEMENT_DEG + 2.0:.1f} deg"
    assert undetermined(_rig(disagreement=WARN_DISAGREEMENT_DEG)) is None
    assert undetermined(_rig(disagreement=None)) is None  # a single run: nothing to disagree
    loose = undetermined(_rig(disagreement=0.2, focal_std_fraction=0.016))
    assert loose == "the focal lengths are determined to 1.6 % only (1 sigma, median over the " \
                    "cameras)"
    assert undetermined(_rig(disagreement=0.2,
                             focal_std_fraction=AIMED_FOCAL_STD_FRACTION)) is None
    # cameras that look the same way: their layout, not their matches, leaves the focal open
    assert undetermined(_rig(disagreement=0.2, focal_std_fraction=0.11, step_deg=2.0)) is None


def test_the_better_determined_calibration_registers_more_cameras_then_agrees_more():
    full, partial = _rig(disagreement=6.0), _rig(("a", "b"), failed=["c"], disagreement=0.1)
    assert better_determined(full, partial) and not better_determined(partial, full)
    assert better_determined(_rig(disagreement=0.5), _rig(disagreement=8.0))
    assert not better_determined(_rig(disagreement=0.5), _rig(disagreement=0.5))  # tie: keep b
    assert better_determined(partial, None) and not better_determined(None, partial)
    assert not better_determined(None, None)
    # runs that agree (within AUC@3's threshold): the tighter focal lengths decide, not which
    # agree more closely
    tight = _rig(disagreement=0.9, focal_std_fraction=0.008)
    assert better_determined(tight, _rig(disagreement=0.0, focal_std_fraction=0.017))
    assert better_determined(_rig(disagreement=0.5, focal_std_fraction=0.03),
                             _rig(disagreement=8.0, focal_std_fraction=0.001))


def test_calibrations_that_both_place_their_cameras_are_compared_on_their_rotation_sigmas():
    """Where both have rotation sigmas, the one whose cameras are placed more tightly (median
    over the cameras but the reference) is kept, whatever the focal sigmas; where one has none
    (not refined on the images), the focal sigmas decide as before."""
    placed = _rig(disagreement=0.2, focal_std_fraction=0.013, rotation_std_deg=[1.0, 1.2])
    focal = _rig(disagreement=0.0, focal_std_fraction=0.011, rotation_std_deg=[1.0, 1.7])
    assert better_determined(placed, focal) and not better_determined(focal, placed)
    unrefined = _rig(disagreement=0.0, focal_std_fraction=0.011)
    assert better_determined(unrefined, placed) and not better_determined(placed, unrefined)
    # runs apart still come first
    assert better_determined(placed, _rig(disagreement=8.0, focal_std_fraction=0.011,
                                          rotation_std_deg=[0.1, 0.1]))


def test_the_second_matcher_applies_to_fresh_calibrations_of_perspective_cameras_on_sift():
    three, eight = ["a", "b", "c"], [f"c{k}" for k in range(8)]
    config = make_config("regular", matcher="sift")
    assert config.second_matcher == "asift"
    assert rematch_applies(config, three) and rematch_applies(config, three[:2])
    assert rematch_applies(config, eight)  # long lenses and wide steps thin larger rigs out too
    assert not rematch_applies(make_config("regular", matcher="sift",
                                           cameras__lens={"c5": "fisheye"}), eight)
    assert not rematch_applies(config, three, fresh=False)  # a recalibration
    assert not rematch_applies(make_config("fisheye", matcher="sift"), three)
    assert not rematch_applies(make_config("regular", matcher="sift",
                                           cameras__lens={"b": "fisheye"}), three)
    assert not rematch_applies(make_config("regular", matcher="asift"), three)
    assert not rematch_applies(make_config("regular", matcher="sift", second_matcher=None),
                               three)


def test_runs_apart_that_meet_refined_on_the_images_leave_the_rig_determined():
    """The disagreement that counts is the one that stands after the image refinement
    (consensus.standing_disagreement_deg): runs apart on the keypoint matches whose runner-up,
    refined as the kept rig was, comes out where it does need no second matcher."""
    met = _rig(disagreement=WARN_DISAGREEMENT_DEG + 2.0)
    met.quality.consensus_refined_disagreement_deg = 0.02
    assert undetermined(met) is None
    apart = _rig(disagreement=WARN_DISAGREEMENT_DEG + 2.0)
    apart.quality.consensus_refined_disagreement_deg = WARN_DISAGREEMENT_DEG + 1.0
    assert undetermined(apart) == \
        f"the calibration runs disagree by {WARN_DISAGREEMENT_DEG + 1.0:.1f} deg"
    assert better_determined(met, apart) and not better_determined(apart, met)


def test_a_first_run_that_left_a_camera_out_is_refined_only_where_the_comparison_needs_it():
    """with_second_matcher asks for sift's first run unrefined where the run left a camera out
    (its image refinement is seconds a kept second matcher makes worthless): asift's with every
    camera is kept over it as is; asift's with as many cameras is compared with it refined (the
    focal sigmas decide); asift's that failed has sift's runs completed."""
    from types import SimpleNamespace

    from densecalib_ros.core.errors import CalibrationError
    from densecalib_ros.core.robust.second_matcher import first_runs_undetermined, \
        with_second_matcher

    def policy_with(second):
        calls = []

        def calibrate(matcher, until, refine_cut_short=True):
            calls.append((matcher, until is first_runs_undetermined, refine_cut_short))
            if matcher == "asift":
                if second is None:
                    raise CalibrationError("no rig")
                return SimpleNamespace(rig=second, cut_short=False, unrefined=False)
            cut = until is not None
            sigma = 0.03 if cut and not refine_cut_short else 0.02  # refined: tighter
            rig = _rig(("a", "b"), failed=["c"], disagreement=None, focal_std_fraction=sigma)
            return SimpleNamespace(rig=rig, cut_short=cut, unrefined=cut and not refine_cut_short)
        kept, rematch = with_second_matcher(calibrate, make_config("regular", matcher="sift"),
                                            ["a", "b", "c"], True, lambda message: None)
        return kept, rematch, calls

    every = _rig(disagreement=0.5, focal_std_fraction=0.01)
    kept, rematch, calls = policy_with(every)
    assert kept.rig is every and rematch.kept_second
    assert calls == [("sift", True, False), ("asift", False, True)]

    # as many cameras, looser than sift's refined run but tighter than its unrefined one
    as_many = _rig(("a", "b"), failed=["c"], focal_std_fraction=0.025)
    kept, rematch, calls = policy_with(as_many)
    assert calls[:3] == [("sift", True, False), ("asift", False, True), ("sift", True, True)]
    assert not rematch.kept_second and kept.rig is not as_many

    kept, rematch, calls = policy_with(None)
    assert calls == [("sift", True, False), ("asift", False, True), ("sift", False, True)]
    assert not rematch.kept_second and not kept.cut_short


def _refined(focal_b_px, yaw_b_deg, focal_std_px=5.0, rotation_std_deg=0.5,
             projection_std_px=0.3, names=("a", "b", "c"), cx_c_px=320.0,
             principal_point_std_px=4.0):
    """A rig refined on the images (image_refinement_tracks), each camera with its own sigmas; b
    with focal_b_px and turned yaw_b_deg, c's principal point at cx_c_px."""
    cameras = {}
    for i, n in enumerate(names):
        f = focal_b_px if n == "b" else 500.0
        cx = cx_c_px if n == "c" else 320.0
        cam_from_rig = np.eye(4)
        cam_from_rig[:3, :3] = Rotation.from_euler(
            "y", yaw_b_deg if n == "b" else 30.0 * i, degrees=True).as_matrix()
        cameras[n] = RigCamera(n, CameraIntrinsics("RADIAL", 640, 480,
                                                   np.array([f, cx, 240, 0, 0])),
                               cam_from_rig, CameraQuality(
                                   0.5, 1000, 0.8, focal_std_px=focal_std_px,
                                   projection_std_px=projection_std_px,
                                   principal_point_std_px=principal_point_std_px,
                                   rotation_std_deg=None if n == "a" else rotation_std_deg))
    rig = RigCalibration("a", cameras)
    rig.quality.image_refinement_tracks = 1000
    return rig


def test_two_matchers_refined_calibrations_apart_widen_the_kept_ones_sigmas():
    """Both matchers' calibrations refined on the images, the same cameras placed: where their
    answers stand further apart than their joint sigma, the kept one's sigmas widen by that
    factor (with equal sigmas: to their distance / sqrt 2); where the other is the looser, its
    own sigma explains the distance; where either was not refined, or they placed other
    cameras, nothing is compared. The principal point likewise: c's 40 px apart widens its
    sigma, b's in the same place leaves it."""
    from types import SimpleNamespace

    from densecalib_ros.core.robust.second_matcher import Rematch, matchers_apart
    from densecalib_ros.core.robust.second_matcher import with_matchers_apart

    def attempt(rig, unrefined=False):
        return SimpleNamespace(rig=rig, unrefined=unrefined)

    names = ["a", "b", "c"]
    kept, other = _refined(500.0, 30.0), _refined(540.0, 36.0, cx_c_px=360.0)
    apart = matchers_apart(attempt(kept), attempt(other), names)
    assert np.isclose(apart["b"][0], 40.0 / np.hypot(5.0, 5.0)) and apart["c"][0] == 0.0
    assert np.isclose(apart["c"][3], 40.0 / np.hypot(4.0, 4.0)) and apart["b"][3] == 0.0
    assert np.isclose(apart["b"][2], 6.0 / np.hypot(0.5, 0.5)) and np.isclose(apart["c"][2], 0.0)
    assert np.isnan(apart["a"][2])  # the reference camera has no rotation sigma
    with_matchers_apart(kept, Rematch("sift", "loose", "asift", "loose", False, apart))
    b, c = kept.cameras["b"].quality, kept.cameras["c"].quality
    assert np.isclose(b.focal_std_px, 40.0 / np.sqrt(2))
    assert np.isclose(b.rotation_std_deg, 6.0 / np.sqrt(2))
    assert (c.focal_std_px, c.rotation_std_deg) == (5.0, 0.5)  # they agree: its own stand
    assert np.isclose(c.principal_point_std_px, 40.0 / np.sqrt(2))
    assert b.principal_point_std_px == 4.0
    assert kept.quality.sigmas_matchers_spread == "asift"

    # the other calibration as far off but eight times as loose: its sigma explains it
    loose = _refined(500.0, 30.0)
    with_matchers_apart(loose, Rematch("sift", "loose", "asift", "loose", False, matchers_apart(
        attempt(loose), attempt(_refined(540.0, 36.0, 40.0, 6.0, 30.0)), names)))
    assert loose.cameras["b"].quality.focal_std_px == 5.0
    assert loose.cameras["b"].quality.rotation_std_deg == 0.5
    assert loose.quality.sigmas_matchers_spread is None

    assert matchers_apart(attempt(kept), attempt(other, unrefined=True), names) == {}
    assert matchers_apart(attempt(kept), attempt(_refined(540.0, 36.0, names=("a", "b"))),
                          names) == {}
    unrefined_on_images = _refined(540.0, 36.0)
    unrefined_on_images.quality.image_refinement_tracks = None
    assert matchers_apart(attempt(kept), attempt(unrefined_on_images), names) == {}
    assert matchers_apart(attempt(kept), None, names) == {}


def test_the_matchers_are_compared_only_where_the_kept_calibration_is_undetermined_too():
    """with_second_matcher's Rematch.apart: where neither matcher determines the rig, their two
    refined answers' distance is the outside measure of what the images leave open; where the
    second's calibration is determined and kept, its sigmas stand and nothing is compared."""
    from types import SimpleNamespace

    from densecalib_ros.core.robust.second_matcher import with_second_matcher

    def rematch_with(second_focal_std_px):
        legs = {"sift": _refined(500.0, 30.0, focal_std_px=12.0),
                "asift": _refined(540.0, 36.0, focal_std_px=second_focal_std_px,
                                  rotation_std_deg=0.4)}  # the better placed, kept

        def calibrate(matcher, until, refine_cut_short=True):
            return SimpleNamespace(rig=legs[matcher], cut_short=False, unrefined=False)
        return with_second_matcher(calibrate, make_config("regular", matcher="sift"),
                                   ["a", "b", "c"], True, lambda message: None)

    kept, rematch = rematch_with(8.0)  # 1.6 %: asift's kept, short of the aim as well
    assert rematch.kept_second and undetermined(kept.rig) is not None
    assert rematch.apart["b"][0] > 1.0
    kept, rematch = rematch_with(2.0)  # 0.4 %: determined
    assert rematch.kept_second and undetermined(kept.rig) is None
    assert rematch.apart == {}
