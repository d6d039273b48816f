"""Plausibility of self-calibrated intrinsics (core/method/plausibility.py) and the guarded BA."""
import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

from densecalib_ros.core.method.plausibility import (bundle_adjust_plausibly, implausible_cameras,
                                                     intrinsics_problem)
from densecalib_ros.core.method.reconstruction import BAStage, SfMState, bundle_adjust, triangulate
from densecalib_ros.core.types import CameraIntrinsics, RigCalibration, RigCamera, RigQuality

from sfm_fixtures import gt_rig, gt_tracks


def cam(model, params, width=1024, height=768):
    return CameraIntrinsics(model, width, height, np.array(params, dtype=np.float64))


def test_ordinary_lenses_are_plausible():
    assert intrinsics_problem(cam("RADIAL", [900, 512, 384, -0.1, 0.02])) is None
    assert intrinsics_problem(cam("RADIAL", [900, 512, 384, 0.3, -0.2])) is None
    assert intrinsics_problem(cam("SIMPLE_PINHOLE", [700, 512, 384])) is None
    # The real fisheye bag's lens (~290 px on 640x480, mild distortion).
    assert intrinsics_problem(cam("OPENCV_FISHEYE", [290, 290, 320, 240, 0.05, -0.01, 0, 0],
                                  640, 480)) is None


def test_distortion_that_folds_inside_the_image_is_named():
    # Measured on a wide-baseline rig: k1 ran to -1.1 on a camera placed from 2-view tracks.
    problem = intrinsics_problem(cam("RADIAL", [1486, 512, 384, -1.136, 0.294]))
    assert problem is not None and "folds the image" in problem
    # The same k1 on a long lens (the corner nearer the axis) does not fold inside the image.
    assert intrinsics_problem(cam("RADIAL", [4000, 512, 384, -1.136, 0.294])) is None


def test_runaway_focal_and_non_finite_parameters_are_named():
    assert "focal length" in intrinsics_problem(cam("RADIAL", [20000, 512, 384, 0, 0]))
    assert "not finite" in intrinsics_problem(cam("RADIAL", [np.nan, 512, 384, 0, 0]))


def test_a_runaway_coefficient_that_does_not_fold_is_named_as_the_file_reader_would():
    """Keypoints alone on Caliscope (test_people_rooms) ran cam_1's k2 to 8776 on one CPU: a
    positive k2 never folds, so the calibration was written and read_calibration then refused
    its own file as damaged. The plausibility check holds the reader's bound."""
    from densecalib_ros.core.io.calibration_values import MAX_DISTORTION_COEFFICIENT, \
        params_problem

    lens = cam("RADIAL", [740, 640, 360, -0.3, 8775.6], 1280, 720)
    problem = intrinsics_problem(lens)
    assert problem == "its distortion coefficient k2 is 8775.6: a lens's lies within +-100"
    assert params_problem("cam_1", 1280, 720, lens.parameter_names, lens.params.tolist()) == \
        "camera cam_1's " + problem[len("its "):]
    at_bound = cam("RADIAL", [740, 640, 360, 0.0, MAX_DISTORTION_COEFFICIENT], 1280, 720)
    assert intrinsics_problem(at_bound) is None  # the reader's bound, not a tighter one


def test_fisheye_extent_is_that_of_the_observations():
    # Folds at ~1.05 (normalised) while the corners lie at ~2: fine if nothing is seen out there.
    lens = cam("OPENCV_FISHEYE", [200, 200, 320, 240, -0.04, -0.01, 0.105, -0.144], 640, 480)
    inner = np.array([[320 + 150, 240], [320, 240 + 150]])  # 0.75 normalised
    outer = np.array([[320 + 300, 240 + 200]])  # 1.8 normalised
    assert intrinsics_problem(lens, inner) is None
    assert "folds the image" in intrinsics_problem(lens, np.vstack([inner, outer]))
    assert "folds the image" in intrinsics_problem(lens)  # no observations: the image corners


def test_a_perspective_lens_is_held_to_its_observations_and_warned_past_them():
    """A webcam whose matches stop short of its corners: the two-term fit folds between the last
    observation and the corner. Plausible where the images saw (holding it to the corner held
    Caliscope's webcams at their starting focal lengths), warned as a finished calibration."""
    from densecalib_ros.core.method.plausibility import corner_fold_warning

    # r_d = r (1 - 0.3 r^2) stops increasing at r_d 0.70; the corners lie at 1.15 (normalised)
    webcam = cam("RADIAL", [640, 640, 360, -0.3, 0.0], 1280, 720)
    inner = np.array([[640 + 380, 360], [640, 360 + 300]])  # 0.59 normalised
    assert intrinsics_problem(webcam, inner) is None
    assert "before the farthest observation" in intrinsics_problem(webcam, inner * 1.3)
    assert "before the image corner" in intrinsics_problem(webcam)

    def rig(cameras, given=()):
        return RigCalibration(next(iter(cameras)),
                              {n: RigCamera(n, c, np.eye(4)) for n, c in cameras.items()},
                              quality=RigQuality(given_intrinsics={n: "RADIAL" for n in given}
                                                 or None))

    straight = cam("RADIAL", [640, 640, 360, -0.1, 0.01], 1280, 720)
    warning = corner_fold_warning(rig({"cam_0": webcam, "cam_1": straight, "lab": webcam},
                                      given=["lab"]))
    # the fold at 0.70 x 640 px against the corner's 734 px from the principal point
    assert "cam_0 at 61 %" in warning and "cam_1" not in warning and "lab at" not in warning
    assert "--intrinsics" in warning
    assert corner_fold_warning(rig({"cam_1": straight})) is None
    fisheye = cam("OPENCV_FISHEYE", [200, 200, 320, 240, -0.04, -0.01, 0.105, -0.144], 640, 480)
    assert intrinsics_problem(fisheye) is not None
    assert corner_fold_warning(rig({"fish": fisheye})) is None  # nothing imaged in its corners


def test_guarded_bundle_adjustment_keeps_a_camera_out_of_a_folding_lens():
    """Camera 3's observations come from a lens whose k1 folds inside the image; a free BA fits
    that lens (implausible), the guarded BA keeps camera 3's previous intrinsics instead."""
    cams, poses = gt_rig(4, seed=3)
    true3 = cams[3]
    cams[3] = CameraIntrinsics("RADIAL", 640, 480, np.array([1.6 * 640, 320, 240, -1.2, 0.0]))
    assert intrinsics_problem(cams[3]) is not None
    tracks = gt_tracks(cams, poses, num_points=800, outlier_frac=0.0, seed=3)
    start = cams[:3] + [true3]

    def fresh_state():
        state = SfMState.create(tracks, [CameraIntrinsics(c.model, c.width, c.height,
                                                          c.params.copy()) for c in start])
        state.cam_from_world = [T.copy() for T in poses]
        triangulate(state, np.arange(tracks.num_tracks), 50.0)
        return state

    stage = BAStage(100, refine_focal=True, refine_extra=True)
    free = fresh_state()
    bundle_adjust(free, list("abcd"), stage, num_threads=1)
    assert 3 in implausible_cameras(free)
    guarded = fresh_state()
    bundle_adjust_plausibly(guarded, list("abcd"), stage, num_threads=1)
    assert implausible_cameras(guarded) == {}
    np.testing.assert_array_equal(guarded.camera(3).params, true3.params)


def test_radial_coefficients_are_read_from_the_colmap_parameter_order():
    import pycolmap

    # k1 placed where each model keeps it (pycolmap's params_info), strong enough to fold.
    for model in ("SIMPLE_RADIAL", "RADIAL", "OPENCV", "FULL_OPENCV", "RADIAL_FISHEYE",
                  "OPENCV_FISHEYE"):
        camera = pycolmap.Camera.create_from_model_name(0, model, 300.0, 1024, 768)
        names = [n.strip() for n in camera.params_info.split(",")]
        params = np.array(camera.params, dtype=np.float64)
        assert intrinsics_problem(cam(model, params)) is None, model
        for k in ("k", "k1", "k2", "k3"):
            if k in names:
                folded = params.copy()
                folded[names.index(k)] = -3.0
                assert "folds the image" in intrinsics_problem(cam(model, folded)), (model, k)


def test_principal_points_and_aspects_no_real_lens_has_are_named_and_warned():
    from densecalib_ros.core.method.plausibility import (UNLIKE_LENS_PREFIX, unlike_a_real_lens,
                                                         unlike_lens_warning)

    def opencv(fx, fy, cx, cy):
        return CameraIntrinsics("OPENCV", 1024, 768, np.array([fx, fy, cx, cy, -0.1, 0.0, 0, 0]))

    # s603 of `densecalib bench --forward` (four cameras on a bar) came out like this
    stretched = opencv(1994.0, 2476.1, 361.0, 394.2)
    assert unlike_a_real_lens(stretched) == \
        "principal point 151 px (15 % of the long side) off the image centre, pixel aspect " \
        "fy/fx 1.242"
    # a real lens: 2 % off-centre on both axes, pixels square to 0.5 %
    real = opencv(800.0, 804.0, 512 + 20.0, 384 - 20.0)
    assert unlike_a_real_lens(real) is None
    assert unlike_a_real_lens(opencv(800.0, 800.0, 512 + 52.0, 384.0)) is not None  # 5.1 %
    assert unlike_a_real_lens(opencv(800.0, 813.0, 512.0, 384.0)) is not None  # 1.6 %
    radial = CameraIntrinsics("RADIAL", 1024, 768, np.array([800.0, 512 + 60.0, 384.0, 0, 0]))
    assert unlike_a_real_lens(radial) == \
        "principal point 60 px (6 % of the long side) off the image centre"
    fisheye = CameraIntrinsics("OPENCV_FISHEYE", 1024, 768,
                               np.array([300.0, 330.0, 600.0, 384.0, 0.0, 0.0, 0.0, 0.0]))
    assert unlike_a_real_lens(fisheye) is None  # the images place a fisheye's centre

    def rig(cameras, given=()):
        return RigCalibration(next(iter(cameras)),
                              {n: RigCamera(n, c, np.eye(4)) for n, c in cameras.items()},
                              quality=RigQuality(given_intrinsics={n: "OPENCV" for n in given}
                                                 or None))

    warning = unlike_lens_warning(rig({"cam0": stretched, "cam1": real, "lab": stretched},
                                      given=["lab"]))
    assert warning.startswith(f"{UNLIKE_LENS_PREFIX}: cam0 principal point 151 px")
    assert "lab" not in warning.split(". ")[0] and "cam1" not in warning
    assert "Check the given intrinsics" in warning  # they may be what pushed cam0 there
    assert "--intrinsics" in unlike_lens_warning(rig({"cam0": stretched}))
    assert unlike_lens_warning(rig({"cam1": real})) is None
