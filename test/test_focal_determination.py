"""The warning for rigs whose images leave the focal lengths open (core.method.focal_determination):
its rule on hand-made rigs, and a generated forward-facing rig calibrated end to end, against the
same cameras around the scene."""
import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from densecalib_ros.core.config import make_config
from densecalib_ros.core.method.focal_determination import (WEAK_FOCAL_PREFIX,
                                                            loose_focal_warning,
                                                            optical_axes_spread_deg,
                                                            weak_focal_fractions,
                                                            weak_focal_warning)
from densecalib_ros.core.metrics import mean_focal_px
from densecalib_ros.core import run_calibration
from densecalib_ros.core.synthetic import RigSpec, generate_rig
from densecalib_ros.core.types import (CameraIntrinsics, CameraQuality, RigCalibration, RigCamera,
                                       RigQuality)


def _camera(name: str, yaw_deg: float, f_std_px, model: str = "RADIAL") -> RigCamera:
    params = [800.0, 320.0, 240.0, 0.0, 0.0] if model == "RADIAL" else \
        [300.0, 300.0, 320.0, 240.0, 0.0, 0.0, 0.0, 0.0]
    cam_from_rig = np.eye(4)
    cam_from_rig[:3, :3] = Rotation.from_euler("y", yaw_deg, degrees=True).as_matrix()
    quality = CameraQuality(0.5, 500, 0.8, focal_std_px=f_std_px)
    return RigCamera(name, CameraIntrinsics(model, 640, 480, np.array(params)), cam_from_rig,
                     quality)


def _rig(*cameras: RigCamera, given=()) -> RigCalibration:
    quality = RigQuality(given_intrinsics=list(given) if given else None)
    return RigCalibration(cameras[0].name, {c.name: c for c in cameras}, quality=quality)


def test_the_rig_warns_when_the_median_camera_sigma_is_above_5_percent_of_the_focal():
    rig = _rig(_camera("a", 0, 80.0), _camera("b", 4, 48.0), _camera("c", -3, 8.0))
    warning = weak_focal_warning(rig)
    assert warning.startswith(WEAK_FOCAL_PREFIX)
    assert "a 10.0 %, b 6.0 %, c 1.0 %" in warning  # all cameras, weakest first
    assert "at most 7 deg apart" in warning and "--intrinsics" in warning
    # one weak camera of three is not the rig: its median is 1 %
    assert weak_focal_warning(_rig(_camera("a", 0, 80.0), _camera("b", 20, 8.0),
                                   _camera("c", 40, 8.0))) is None
    # exactly at the bound: no warning
    assert weak_focal_warning(_rig(_camera("a", 0, 40.0), _camera("b", 5, 40.0))) is None


def test_a_weak_rig_around_the_scene_is_told_the_matches_not_the_layout_are_the_cause():
    forward = weak_focal_warning(_rig(_camera("a", 0, 80.0), _camera("b", 19, 80.0)))
    assert "look nearly the same way" in forward and "around the scene" in forward
    around = weak_focal_warning(_rig(_camera("a", 0, 80.0), _camera("b", 30, 60.0),
                                     _camera("c", 60, 48.0)))
    assert around.startswith(WEAK_FOCAL_PREFIX) and "a 10.0 %, b 7.5 %, c 6.0 %" in around
    assert "up to 60 deg apart, so the matches leave them open" in around
    assert "look nearly the same way" not in around and "add frame sets" in around
    assert "--intrinsics" in around


def test_a_rig_around_the_scene_looser_than_1_percent_is_told_so_below_the_weak_warning():
    """Between the 1 % aim and the 5 % weak warning, a rig whose axes spread 20 deg or more is
    told its focal lengths are short of the aim, once: above 5 % the weak warning says it."""
    loose = loose_focal_warning(_rig(_camera("a", 0, 12.0), _camera("b", 30, 9.6),
                                     _camera("c", 60, 4.0)), "asift's matches (kept over sift's)")
    assert loose.startswith("focal lengths looser than the calibration aims at: on asift's "
                            "matches (kept over sift's) f_std is a 1.5 %, b 1.2 %, c 0.5 %")
    assert "add frame sets" in loose and "--intrinsics" in loose
    assert weak_focal_warning(_rig(_camera("a", 0, 12.0), _camera("b", 30, 9.6))) is None
    # at the aim, or above the weak warning's bound: not this warning
    assert loose_focal_warning(_rig(_camera("a", 0, 8.0), _camera("b", 30, 8.0)), "x") is None
    assert loose_focal_warning(_rig(_camera("a", 0, 48.0), _camera("b", 30, 48.0)), "x") is None


def test_the_loose_focal_warning_names_the_keypoints_where_they_joined_the_matches():
    from densecalib_ros.core.stages.record import warnings

    rig = _rig(_camera("a", 0, 12.0), _camera("b", 30, 9.6), _camera("c", 60, 4.0))
    config = make_config("regular", second_matcher=None)
    told = [w for w in warnings(rig, config, ["a", "b", "c"], None, None, None, keypoints=True)
            if w.startswith("focal lengths looser")]
    assert told and told[0].startswith(
        "focal lengths looser than the calibration aims at: on sift's matches and the keypoints "
        "f_std is a 1.5 %")
    # cameras that look the same way: the layout leaves the focal open, which the probe's sigma
    # and the weak warning cover
    assert loose_focal_warning(_rig(_camera("a", 0, 12.0), _camera("b", 10, 12.0)), "x") is None


def _with_focal(camera: RigCamera, focal_px: float) -> RigCamera:
    params = np.array(camera.intrinsics.params, float)
    params[0] = focal_px
    camera.intrinsics = CameraIntrinsics(camera.intrinsics.model, 640, 480, params)
    return camera


def test_images_that_could_come_from_one_camera_are_told_to_share_intrinsics():
    """A rig short of the focal aim whose cameras could be one (one image size and model, not
    one set of intrinsics already) is told that --share-intrinsics estimates one set from every
    image; a rig at the aim, one set already, or cameras of another size are not."""
    from densecalib_ros.core.method.focal_determination import one_camera_hint

    def rig(focals, f_std_px=12.0):  # 1.5 % of 800 px: short of the aim, below the weak bound
        return _rig(*(_with_focal(_camera(n, yaw, f_std_px), f)
                      for n, yaw, f in zip("abc", (0, 30, 60), focals)))
    # one phone's frames calibrated apart: focal lengths several of their sigmas apart
    alike = rig([800.0, 740.0, 860.0])
    loose = loose_focal_warning(alike, "sift's matches")
    assert "--share-intrinsics" in loose and loose.endswith(one_camera_hint(alike))
    assert weak_focal_warning(rig([800.0, 740.0, 860.0], 48.0)).endswith(one_camera_hint(alike))
    assert one_camera_hint(rig([800.0, 812.0, 790.0], 4.0)) == ""  # at the aim
    assert one_camera_hint(rig([800.0, 800.0, 800.0])) == ""  # one set of intrinsics already
    units = rig([800.0, 740.0, 860.0])  # calibrated as units (each its own after the refinement)
    units.quality.identical_units = [{"cameras": ["a", "b", "c"], "why": "assumed"}]
    assert one_camera_hint(units) == ""
    units.quality.identical_units = [{"cameras": ["a", "b"], "why": "EXIF"}]
    assert one_camera_hint(units) == one_camera_hint(alike)
    other_size = rig([800.0, 812.0, 790.0])
    c = other_size.cameras["c"]
    c.intrinsics = CameraIntrinsics("RADIAL", 1280, 960, np.array(c.intrinsics.params))
    assert one_camera_hint(other_size) == "" and "--share-intrinsics" not in \
        loose_focal_warning(other_size, "sift's matches")


def test_fisheye_given_and_unestimated_cameras_are_left_out():
    rig = _rig(_camera("a", 0, 80.0), _camera("fish", 10, 200.0, "OPENCV_FISHEYE"),
               _camera("lab", 5, 400.0), _camera("b", 3, 4.0), given=["lab"])
    assert weak_focal_fractions(rig) == pytest.approx({"a": 0.1, "b": 0.005})
    assert weak_focal_warning(rig) is not None  # median of a and b: 5.25 %
    rig.cameras["b"].quality.focal_std_px = None
    rig.cameras["a"].quality.focal_std_px = None
    assert weak_focal_fractions(rig) == {} and weak_focal_warning(rig) is None


def test_spread_is_the_largest_angle_between_two_optical_axes():
    rig = _rig(_camera("a", 0, 1.0), _camera("b", 25, 1.0), _camera("c", -10, 1.0))
    assert optical_axes_spread_deg(rig) == pytest.approx(35.0)
    assert optical_axes_spread_deg(_rig(_camera("a", 0, 1.0))) == 0.0


@pytest.mark.parametrize("layout,refine_on_images", [("bar", False), ("bar", True),
                                                     ("arc", True)])
def test_a_forward_facing_rig_is_warned_about_and_one_around_the_scene_is_not(layout,
                                                                              refine_on_images):
    # The same cameras and scene: side by side on a bar (axes parallel within 3 deg) or around
    # the scene's centre 20 deg apart. On the bar the keypoint matches leave the focal lengths
    # open (2.3 % off, f_std 11-65 %); the dense correspondences of the image refinement pin
    # them down through the few degrees between the axes (< 0.1 % off) and nothing is warned.
    rig = generate_rig(RigSpec(lenses="ideal", num_cameras=4, camera_model="RADIAL", width=640,
                               height=480, seed=3, layout=layout))
    config = make_config("regular", matcher="sift", sfm__num_threads=1,
                         refine_on_images=refine_on_images)
    result = run_calibration([rig.images[0]], rig.names, config)
    warnings = [w for w in result.rig.quality.warnings
                if w.startswith(WEAK_FOCAL_PREFIX)]
    fractions = weak_focal_fractions(result.rig)
    assert len(fractions) == 4
    truth = rig.ground_truth()
    errors = [abs(mean_focal_px(c.intrinsics) / mean_focal_px(truth.cameras[n].intrinsics) - 1)
              for n, c in result.rig.cameras.items()]
    if layout == "bar" and not refine_on_images:
        assert optical_axes_spread_deg(result.rig) < 10.0
        assert len(warnings) == 1 and np.median(list(fractions.values())) > 0.05
    elif layout == "bar":
        assert warnings == [] and max(errors) < 0.01
        assert max(errors) < 3 * max(fractions.values())  # the sigma is not smaller than the error
    else:
        assert optical_axes_spread_deg(result.rig) > 30.0
        assert warnings == [] and max(fractions.values()) < 0.05
        assert np.median(errors) < 0.02


def _probe_state(yaws_deg, noise_px=0.3):
    """Four cameras with the same intrinsics 0.3 m apart along x, each turned by its yaw about
    the vertical, or on gt_rig's 60 deg arc (yaws_deg None); the truth's poses, points
    triangulated and adjusted with the image refinement's priors. (state, blocks, priors, noise
    of the adjustment)."""
    from sfm_fixtures import gt_rig, gt_tracks, look_at

    from densecalib_ros.core.method.prior_adjustment import Priors, adjust_with_priors
    from densecalib_ros.core.method.reconstruction import SfMState, triangulate_tracks

    cams, poses = gt_rig(4, seed=1)
    if yaws_deg is not None:
        poses = []
        for c, yaw in enumerate(yaws_deg):
            centre = np.array([0.3 * (c - 1.5), 0.0, 0.0])
            target = centre + [np.sin(np.radians(yaw)), 0.0, np.cos(np.radians(yaw))]
            poses.append(look_at(centre, target))
        cams = [cams[0]] * 4
    tracks = gt_tracks(cams, poses, num_points=3000, noise_px=noise_px, outlier_frac=0.0)
    state = SfMState.create(tracks, list(cams))
    state.cam_from_world = [T.copy() for T in poses]
    triangulate_tracks(state, max_error_px=50.0)
    blocks = sorted(set(int(b) for b in state.camera_block))
    priors = Priors({b: 6.4 for b in blocks}, {b: None for b in blocks})
    adjustment = adjust_with_priors(state, blocks, priors)
    return state, blocks, priors, adjustment.noise_px


@pytest.mark.parametrize("layout", ["bar", "arc"])
def test_the_probe_finds_the_focal_scale_open_on_a_bar_and_fixed_around_the_scene(layout):
    from densecalib_ros.core.method.focal_determination import (axes_spread_deg,
                                                                probed_focal_scale_std)

    # On the bar the axes are within 1 deg of each other: the images leave the common scale of
    # the focal lengths open (exactly so for parallel axes), and a restart 15 % away fits as
    # well. 60 deg around the scene the restarts' cost rises by hundreds of sigmas.
    state, blocks, priors, noise_px = _probe_state([0.5, -0.5, 0.3, -0.2] if layout == "bar"
                                                   else None)
    spread = axes_spread_deg([state.cam_from_world[c][:3, :3] for c in state.registered()])
    before = [c.params.copy() for c in state.intrinsics]
    std = probed_focal_scale_std(state, blocks, priors, noise_px)
    assert all(np.array_equal(a, c.params) for a, c in zip(before, state.intrinsics))  # untouched
    if layout == "bar":
        assert spread < 2.0 and std > 0.05
    else:
        assert spread > 30.0 and std < 0.01
