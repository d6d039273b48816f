"""Later frame sets are matched only where they show something new (core.method.new_content)."""
import cv2
import numpy as np
import pytest

from densecalib_ros.core.config import make_config
from densecalib_ros.core.metrics import evaluate_calibration
from densecalib_ros.core.method.matching import create_matcher
from densecalib_ros.core.method.new_content import new_content_regions
from densecalib_ros.core import calibrate_rig, match_frame_sets
from densecalib_ros.core.synthetic import RigSpec, generate_rig


def _room(square_at=None, brightness=0):
    """A textured static background 240x320 with a bright 40x40 square at (row, col)."""
    rng = np.random.default_rng(0)
    image = np.kron(rng.integers(0, 200, (24, 32)), np.ones((10, 10))).astype(np.int16)
    if square_at is not None:
        r, c = square_at
        image[r:r + 40, c:c + 40] = 250
    return np.clip(image + brightness, 0, 255).astype(np.uint8)


def test_regions_are_what_no_earlier_frame_set_showed():
    sets = [[_room((100, 50))], [_room((100, 200))], [_room((100, 50))], [_room(None, 60)]]
    regions = [r[0] for r in new_content_regions(sets)]
    assert regions[0] is None  # the first frame set is matched whole
    new = regions[1]
    assert new.shape == (240, 320)
    # the square's new place and the background it uncovered are new, the rest is not
    assert new[110:130, 210:230].all() and new[110:130, 60:80].all()
    assert not new[:60].any() and not new[:, 280:].any()
    # back where it was in the first set: nothing there is new; where it was in the second, the
    # background shows again, as in the first set
    assert not regions[2].any()
    # the light changed: everything is new
    assert regions[3].mean() > 0.9


def test_sift_keypoints_only_in_the_regions_and_other_matchers_drop_matches_outside():
    image = _room((100, 50))
    region = np.zeros(image.shape, bool)
    region[:, :160] = True
    matcher = create_matcher("sift")
    match_set = matcher.match([image, image.copy()], [region, region])
    assert len(match_set.sites[0]) > 20
    assert match_set.sites[0][:, 0].max() < 160 + 2  # within the region (keypoint subpixel)
    whole = matcher.match([image, image.copy()])
    assert len(whole.sites[0]) > len(match_set.sites[0])


def test_keypoints_detected_on_the_regions_box_are_those_of_the_whole_image():
    # A region is detected on its bounding box grown by sift.REGION_MARGIN_FRACTION: away from the
    # box's edge the keypoints are the whole image's, to the subpixel.
    rng = np.random.default_rng(1)
    image = cv2.GaussianBlur(rng.integers(0, 255, (480, 640)).astype(np.uint8), (0, 0), 1.5)
    region = np.zeros(image.shape, bool)
    region[150:330, 200:420] = True
    matcher = create_matcher("sift")
    in_box, _, _ = matcher._features(image, region)
    whole, _, _ = matcher._features(image)
    assert len(in_box) > 100
    # within the region (sites in COLMAP px: pixel centres at +0.5; keypoints subpixel)
    assert (in_box.min(axis=0) > (200 - 1, 150 - 1)).all()
    assert (in_box.max(axis=0) < (420 + 1, 330 + 1)).all()
    # whole-image keypoints well inside the region (their descriptor windows too)
    inner = whole[(whole[:, 0] > 230) & (whole[:, 0] < 390) & (whole[:, 1] > 180)
                  & (whole[:, 1] < 300)]
    nearest = np.min(np.linalg.norm(inner[:, None] - in_box[None], axis=2), axis=1)
    assert len(inner) > 50 and np.mean(nearest < 0.01) > 0.95
    empty, _, _ = matcher._features(image, np.zeros(image.shape, bool))
    assert len(empty) == 0


def test_a_static_scene_filmed_twice_adds_no_matches_and_the_same_calibration():
    """The second frame set repeats the first (sensor noise only): nothing in it is new, so it
    is not matched, and the calibration is the one from the first frame set alone."""
    rig = generate_rig(RigSpec(lenses="ideal", num_cameras=4, camera_model="RADIAL", width=640,
                               height=480, seed=0))
    noisy = [np.clip(im.astype(np.int16) + np.random.default_rng(1).integers(-3, 4, im.shape),
                     0, 255).astype(np.uint8) for im in rig.images[0]]
    # sift (cheap to test with) made a matcher that matches later frame sets on what is new only
    config = make_config("regular", matcher="sift", sfm__num_threads=1,
                         new_content_matchers=("sift",))
    match_sets = match_frame_sets([rig.images[0], noisy], config, camera_names=rig.names)
    assert sum(len(s) for s in match_sets[0].sites) > 1000
    assert all(len(s) == 0 for s in match_sets[1].sites) and not match_sets[1].pairs
    # by default sift matches every frame set whole (asift only on what is new)
    whole = match_frame_sets([rig.images[0], noisy], make_config("regular", matcher="sift"),
                             camera_names=rig.names)
    assert sum(len(s) for s in whole[1].sites) > 1000
    once = calibrate_rig([rig.images[0]], rig.names, config)
    twice = calibrate_rig([rig.images[0], noisy], rig.names, config)
    for name in rig.names:
        np.testing.assert_allclose(twice.cameras[name].intrinsics.params,
                                   once.cameras[name].intrinsics.params, rtol=1e-9)
    assert evaluate_calibration(twice, rig.ground_truth())["auc3"] >= 80.0


@pytest.mark.parametrize("new_content_only", [True, False])
def test_a_scene_that_moves_between_frame_sets_calibrates_either_way(new_content_only):
    """Objects move between the time steps: the later ones are matched on them (and what they
    uncovered) only, or whole when switched off; both calibrate the rig."""
    rig = generate_rig(RigSpec(lenses="ideal", num_cameras=4, camera_model="RADIAL", width=640,
                               height=480, seed=3, num_time_steps=3))
    config = make_config("regular", matcher="sift", sfm__num_threads=1,
                         new_content_matchers=("sift",) if new_content_only else ())
    match_sets = match_frame_sets(rig.images, config, camera_names=rig.names)
    sites = [sum(len(s) for s in m.sites) for m in match_sets]
    if new_content_only:
        assert 0 < sites[1] < sites[0] and 0 < sites[2] < sites[0]
    result = calibrate_rig(rig.images, rig.names, config)
    assert evaluate_calibration(result, rig.ground_truth())["auc3"] >= 80.0


def test_a_camera_bumped_between_frame_sets_of_a_static_scene_is_found_by_checks():
    """A static scene, cam2 turned by 1 deg before the second frame set: only cam2's image is
    new there, its partners' are not, so new-content matching leaves cam2 without matches in
    that set; a check matches every frame set whole (each_on_its_own) and names cam2."""
    from densecalib_ros.core.monitor.consistency import check_latest
    from scipy.spatial.transform import Rotation
    from sfm_fixtures import turned_image  # pytest puts test/ on sys.path

    rig = generate_rig(RigSpec(lenses="ideal", num_cameras=4, camera_model="RADIAL", width=640,
                               height=480, seed=3))
    truth = rig.ground_truth()
    later = [np.clip(im.astype(np.int16) + np.random.default_rng(c).integers(-3, 4, im.shape),
                     0, 255).astype(np.uint8) for c, im in enumerate(rig.images[0])]
    later[2] = turned_image(later[2], truth.cameras["cam2"].intrinsics,
                            Rotation.from_euler("x", 1.0, degrees=True).as_matrix())
    sets = [rig.images[0], later]
    config = make_config("regular", matcher="sift", new_content_matchers=("sift",))
    regions = list(new_content_regions(sets))[1]
    assert regions[2].mean() > 0.9 and not any(regions[c].any() for c in (0, 1, 3))
    bumped = match_frame_sets(sets, config)[1]
    assert all((m.target < 0).all() for m in bumped.pairs.values())
    whole = match_frame_sets(sets, config, each_on_its_own=True)
    report = check_latest(truth, rig.names, whole)
    assert report.frame_sets_before_change == 1 and report.suspects == ["cam2"]
