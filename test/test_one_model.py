"""Units of one model assumed from the images (issue 81; core.robust.one_model): where the
cameras' own intrinsics leave the consensus runs apart and the cameras could be one model, the
matches are calibrated again as one model, kept where that is better determined and fits the
keypoint matches as well. The fit is what tells units from lenses that differ; the policy runs
only where nothing the user said or the images' sizes and lenses rule it out."""
from types import SimpleNamespace

import numpy as np
import pytest

from densecalib_ros.core import InputError, calibrate_from_tracks, make_config
from densecalib_ros.core.method.multistart import WORSE_FIT_RATIO
from densecalib_ros.core.products.report import overall_lines
from densecalib_ros.core.robust.consensus import WARN_DISAGREEMENT_DEG
from densecalib_ros.core.robust.one_model import (as_one_model, first_runs_apart, fit_costs_px,
                                                  judged_one_camera, judged_several,
                                                  one_model_applies, with_one_model)
from densecalib_ros.core.types import CameraIntrinsics
from sfm_fixtures import gt_rig, gt_tracks

NAMES = ["a", "b", "c", "d"]
SIZES = [(640, 480)] * 4


def _rig_tracks(focals_px, seed=3):
    """A 4-camera rig with these focal lengths (else gt_rig's) and its tracks."""
    cams, poses = gt_rig(4, seed=seed)
    cams = [CameraIntrinsics("RADIAL", 640, 480, np.r_[f, c.params[1:3], 0.0, 0.0])
            for f, c in zip(focals_px, cams)]
    return gt_tracks(cams, poses, num_points=2500, noise_px=0.5, outlier_frac=0.0, seed=seed)


def _attempt(tracks, config, apart_deg=None):
    """A calibration of `tracks` with `config` as the policy sees one (rig, its SfM's, config,
    matches; no refinement on images here); its runs standing apart_deg apart."""
    config = config.for_cameras(NAMES) if not config.camera_names else config
    result = calibrate_from_tracks(tracks, SIZES, NAMES, config)
    result.rig.quality.consensus_disagreement_deg = apart_deg
    return SimpleNamespace(rig=result.rig, sfm_rig=result.rig, config=config, refinement=None,
                           matched=SimpleNamespace(keypoint_tracks=tracks))


@pytest.mark.parametrize("focals_px, one_fits", [((560.0,) * 4, True),
                                                 ((450.0, 560.0, 700.0, 560.0), False)])
def test_one_model_fits_units_matches_as_well_and_differing_lenses_clearly_worse(focals_px,
                                                                                  one_fits):
    tracks = _rig_tracks(focals_px)
    config = make_config("regular", sfm__num_threads=1).for_cameras(NAMES)
    own = _attempt(tracks, config)
    one = _attempt(tracks, as_one_model(config, NAMES, "test"))
    assert len(set(c.intrinsics.params[0] for c in one.rig.cameras.values())) == 1
    own_px, one_px = fit_costs_px([own.rig, one.rig], tracks, NAMES, config)
    assert (one_px <= WORSE_FIT_RATIO * own_px) == one_fits, (own_px, one_px)


def test_the_policy_keeps_one_model_only_where_it_fits_and_says_why():
    """Lenses the refinement on the images does not adjust (here: no refinement): the fit to the
    keypoint matches decides."""
    config = make_config("regular", sfm__num_threads=1, refine_on_images=False).for_cameras(NAMES)
    apart = WARN_DISAGREEMENT_DEG + 5.0
    for focals_px, keep in (((560.0,) * 4, True), ((450.0, 560.0, 700.0, 560.0), False)):
        tracks = _rig_tracks(focals_px)
        kept = _attempt(tracks, config, apart)
        said = []
        out, what = with_one_model(kept, lambda c, until: _attempt(tracks, c), NAMES, SIZES, True,
                                   said.append)
        assert what is not None and what.kept == keep and what.own_apart_deg == apart
        assert (out is not kept) == keep
        assert "calibrating them again as one model" in said[0]
        if keep:
            (units, why), = out.config.cameras.identical_units
            assert units == tuple(NAMES) and why.startswith(
                f"assumed from the images: with each camera's own intrinsics the calibration "
                f"runs stood {apart:.1f} deg apart")
            out.rig.quality.identical_units = [{"cameras": list(units), "why": why}]
            assert any(line.startswith("identical units a, b, c, d (one set of intrinsics in the "
                                       "SfM): assumed from the images")
                       for line in overall_lines(out.rig))
        else:
            assert "fits the matches clearly worse: kept each camera's own intrinsics" in said[-1]


def test_pinhole_units_need_the_one_camera_tests_verdict():
    """Where the refinement on the images adjusts the lenses, the keypoint matches' fit is not
    enough (they cannot tell lenses a few percent apart): the refinement's one-camera test must
    have judged the units one camera."""
    config = make_config("regular", sfm__num_threads=1).for_cameras(NAMES)
    tracks = _rig_tracks((560.0,) * 4)
    kept = _attempt(tracks, config, WARN_DISAGREEMENT_DEG + 5.0)
    kept.refinement = SimpleNamespace(one_camera={})  # its own refinement could not judge them
    for verdicts, keep in ((None, False), ({("a", "b", "c", "d"): False}, False),
                           ({("a", "b", "c", "d"): True}, True)):
        def again(c, until):
            one = _attempt(tracks, c)
            one.refinement = verdicts and SimpleNamespace(one_camera=verdicts)
            return one
        said = []
        out, what = with_one_model(kept, again, NAMES, SIZES, True, said.append)
        assert what.kept == keep and (out is not kept) == keep, said
        if not keep:
            assert "the refinement on the images did not judge them one camera" in said[-1]
    # Where the calibration's own refinement told them apart already, no second calibration.
    kept.refinement = SimpleNamespace(one_camera={("a", "b", "c", "d"): False})
    called, said = [], []
    out, what = with_one_model(kept, lambda *a: called.append(a), NAMES, SIZES, True,
                               said.append)
    assert out is kept and what is None and not called and "told the cameras apart" in said[0]


def test_runs_in_agreement_leave_the_cameras_their_own_intrinsics():
    tracks = _rig_tracks((560.0,) * 4)
    config = make_config("regular", sfm__num_threads=1).for_cameras(NAMES)
    kept = _attempt(tracks, config, WARN_DISAGREEMENT_DEG - 0.5)
    called = []
    out, what = with_one_model(kept, lambda *a: called.append(a), NAMES, SIZES, True, print)
    assert out is kept and what is None and not called


def test_only_cameras_that_could_be_one_model_the_user_did_not_name():
    config = make_config("regular").for_cameras(NAMES)
    assert one_model_applies(config, NAMES, SIZES)
    assert not one_model_applies(config, NAMES, SIZES, fresh=False)  # a recalibration
    assert not one_model_applies(config, NAMES, SIZES[:3] + [(1280, 720)])
    assert not one_model_applies(make_config("regular", cameras__lens={"d": "fisheye"})
                                 .for_cameras(NAMES), NAMES, SIZES)
    assert not one_model_applies(make_config("regular", sfm__share_intrinsics=True)
                                 .for_cameras(NAMES), NAMES, SIZES)
    assert not one_model_applies(as_one_model(config, NAMES, "named"), NAMES, SIZES)
    assert not one_model_applies(make_config("regular", cameras__identical_units=(
        (("a", "b"), "EXIF"),)).for_cameras(NAMES), NAMES, SIZES)
    known = {"a": CameraIntrinsics("RADIAL", 640, 480, np.array([560.0, 320, 240, 0, 0]))}
    assert not one_model_applies(make_config("regular", cameras__known_intrinsics=known)
                                 .for_cameras(NAMES), NAMES, SIZES)
    assert not one_model_applies(make_config("regular", consensus_runs=1).for_cameras(NAMES),
                                 NAMES, SIZES)
    # the user's word that they differ (calibrate --separate-intrinsics)
    assert not one_model_applies(make_config("regular", cameras__units_from_images=False)
                                 .for_cameras(NAMES), NAMES, SIZES)


def test_the_one_camera_verdict_covers_every_unit():
    assert judged_one_camera(SimpleNamespace(one_camera={("a", "b", "c", "d"): True}), NAMES)
    assert not judged_one_camera(SimpleNamespace(one_camera={("a", "b", "c"): True}), NAMES)
    assert not judged_one_camera(SimpleNamespace(one_camera={("a", "b", "c", "d"): False}), NAMES)
    assert not judged_one_camera(None, NAMES)
    assert judged_several(SimpleNamespace(one_camera={("a", "b", "x"): False}), NAMES)
    assert not judged_several(SimpleNamespace(one_camera={("a", "x", "y"): False}), NAMES)
    assert not judged_several(None, NAMES)


def test_calibrate_separate_intrinsics_says_the_cameras_differ():
    import argparse

    from densecalib_ros.commands import calibrate

    parser = argparse.ArgumentParser()
    calibrate.add_arguments(parser)
    for flags, assumed in (([], True), (["--separate-intrinsics"], False)):
        args = parser.parse_args(["--images", "rig", "--out", "calib", *flags])
        assert calibrate._config(args).cameras.units_from_images == assumed
    both = parser.parse_args(["--images", "rig", "--out", "calib", "--share-intrinsics",
                              "--separate-intrinsics"])
    with pytest.raises(InputError, match="give one of them"):
        calibrate._config(both)


def test_the_calibration_as_one_model_ends_once_its_first_runs_stand_apart():
    """It is kept only where its runs agree: once its first runs, judged, stand apart beyond the
    warning's bar (refined on the images where they could be, else on the keypoint matches
    where only the refinement's verdict could keep it), more runs are not made."""
    apart, close = WARN_DISAGREEMENT_DEG + 4.0, WARN_DISAGREEMENT_DEG - 1.0

    def runs(on_matches, refined):
        return SimpleNamespace(apart_on_matches_deg=on_matches, judged_apart_deg=refined)
    for needs_verdict in (False, True):
        rule = first_runs_apart(needs_verdict)
        assert not rule(runs(None, None))  # not judged yet
        assert rule(runs(apart, apart)) and not rule(runs(apart, close))  # refined decides
        assert rule(runs(apart, None)) == needs_verdict  # not refined: the matches, if needed
        assert not rule(runs(close, None))
    # The policy hands the rule to the calibration and says where it ended the runs.
    config = make_config("regular", sfm__num_threads=1).for_cameras(NAMES)
    tracks = _rig_tracks((560.0,) * 4)
    kept = _attempt(tracks, config, apart)
    rules, said = [], []

    def again(c, until):
        rules.append(until)
        one = _attempt(tracks, c, apart)
        one.cut_short, one.consensus = True, SimpleNamespace(num_runs=2)
        return one
    out, what = with_one_model(kept, again, NAMES, SIZES, True, said.append)
    assert out is kept and not what.kept
    assert rules[0](runs(apart, apart)) and not rules[0](runs(close, close))
    assert f"as one model: its first 2 runs {apart:.1f} deg apart" in said[-1]
