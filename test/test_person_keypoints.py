"""Built-in person keypoints (core.method.person_keypoints, BlazePose from the mediapipe wheel's
model files run by ai-edge-litert) and `densecalib keypoints`: the geometry on synthetic images,
then the real models on the real pose2sim ring, whose Qualisys reference says where the same joint
must appear in every camera."""
import itertools
import json
import sys
import time

import cv2
import numpy as np
import pytest
import yaml

from densecalib_ros.cli import main
from densecalib_ros.core.errors import ModelWeightsError
from densecalib_ros.core.method import blazepose as bp
from densecalib_ros.core.method.person_keypoints import (
    DETECTOR_FILE, LANDMARK_FILE, LANDMARK_NAMES, PersonKeypointDetector, PersonKeypointOptions,
    installed_model_file)
from densecalib_ros.eval.datasets import default_data_dir, load_qualisys_videos

POSE2SIM = default_data_dir() / "pose2sim_4cam_ring"
MODELS = [installed_model_file(f) for f in (DETECTOR_FILE, LANDMARK_FILE)]
needs_models = pytest.mark.skipif(
    None in MODELS, reason="BlazePose model files not installed (mediapipe==0.10.21 without its "
                           "dependencies, requirements-nodeps.txt: run scripts/setup_env.sh)")
needs_pose2sim = pytest.mark.skipif(
    not (POSE2SIM / "calibration" / "Calib.qca.txt").is_file(),
    reason=f"pose2sim_4cam_ring not found at {POSE2SIM} (set DENSECALIB_DATA to the shared data)")
# Mirror image of the 33 landmarks (left <-> right): a wrong correspondence to compare against.
MIRROR = [0, 4, 5, 6, 1, 2, 3, 8, 7, 10, 9, 12, 11, 14, 13, 16, 15, 18, 17, 20, 19, 22, 21, 24,
          23, 26, 25, 28, 27, 30, 29, 32, 31]
CONFIDENT = 0.5  # landmark score taken as found (the models' own 0.5 thresholds)


def test_the_anchors_are_the_detectors_2254_in_its_order():
    anchors = bp.ssd_anchor_centres(224)
    assert anchors.shape == (2254, 2)
    np.testing.assert_allclose(anchors[:2], [[0.5 / 28, 0.5 / 28]] * 2)  # 28x28 grid, 2 each
    np.testing.assert_allclose(anchors[2], [1.5 / 28, 0.5 / 28])  # x runs first
    np.testing.assert_allclose(anchors[1568], [0.5 / 14, 0.5 / 14])  # then 14x14 x 2
    np.testing.assert_allclose(anchors[-6:], [[6.5 / 7, 6.5 / 7]] * 6)  # 3 layers on 7x7 x 2


@pytest.mark.parametrize("side_px", [200.0, 700.0])  # sampled directly, and from a shrunk copy
def test_a_rotated_crop_maps_its_pixels_back_to_the_image(side_px):
    dot_xy = np.array([331.0, 262.0])  # OpenCV pixels
    yy, xx = np.mgrid[0:480, 0:640]
    image = (255 * np.exp(-((xx - dot_xy[0]) ** 2 + (yy - dot_xy[1]) ** 2) / (2 * 6.0 ** 2)))
    image = np.repeat(image.astype(np.uint8)[:, :, None], 3, axis=2)
    roi = bp.PoseRoi(np.array([300.0, 250.0]), side_px, 0.5)
    crop = bp.crop(image, roi, 256)[:, :, 0].astype(float)
    cy, cx = np.mgrid[0:256, 0:256]
    found_crop = np.array([(cx * crop).sum(), (cy * crop).sum()]) / crop.sum() + 0.5
    found_xy = roi.image_from_crop(256) @ [*found_crop, 1.0] - 0.5
    assert np.linalg.norm(found_xy - dot_xy) < 0.2 * side_px / 256  # a fifth of a crop pixel
    back = roi.crop_from_image(256) @ [*(found_xy + 0.5), 1.0]
    np.testing.assert_allclose(back, found_crop, atol=1e-9)


def test_weighted_nms_merges_what_overlaps_and_keeps_what_does_not():
    scores = np.array([0.9, 0.6, 0.8])
    boxes = np.array([[0, 0, 10, 10], [1, 0, 11, 10], [50, 50, 60, 60]], float)
    keypoints = np.zeros((3, 4, 2))
    keypoints[1] += 1.0
    out = bp.weighted_nms(scores, boxes, keypoints)
    assert [s for s, _, _ in out] == [0.9, 0.8]
    np.testing.assert_allclose(out[0][1], [0.4, 0, 10.4, 10])  # 0.9 / 0.6 weighted mean
    np.testing.assert_allclose(out[0][2], 0.4)
    np.testing.assert_allclose(out[1][1], boxes[2])


def test_a_missing_model_says_which_file_and_what_to_install(tmp_path):
    with pytest.raises(ModelWeightsError, match="not found at .*nowhere.tflite"):
        PersonKeypointDetector(PersonKeypointOptions(
            detector_model=str(tmp_path / "nowhere.tflite"))).load()
    junk = tmp_path / "junk.tflite"
    junk.write_bytes(b"not a model")
    with pytest.raises(ModelWeightsError, match="unreadable|not the BlazePose|not installed"):
        PersonKeypointDetector(PersonKeypointOptions(detector_model=str(junk),
                                                     landmark_model=str(junk))).load()


@pytest.mark.parametrize("option", [["--max-persons", "0"], ["--min-pose-presence", "1"],
                                    ["--threads", "0"], ["--mask", "strip.png"]])
def test_the_command_refuses_an_option_out_of_range_naming_it(option, tmp_path, caplog):
    out = tmp_path / "kp"
    assert main(["keypoints", "--images", str(tmp_path), "--out", str(out), *option]) == 2
    assert option[0] in caplog.text and not out.exists()


@needs_models
def test_the_models_load_from_the_installed_wheel_without_importing_mediapipe():
    PersonKeypointDetector(PersonKeypointOptions(num_threads=1)).load()
    assert not any(m == "mediapipe" or m.startswith("mediapipe.") for m in sys.modules)
    with pytest.raises(ModelWeightsError, match="not the BlazePose model"):  # files swapped
        PersonKeypointDetector(PersonKeypointOptions(
            detector_model=str(MODELS[1]), landmark_model=str(MODELS[0]))).load()


@pytest.fixture(scope="module")
def detector():
    return PersonKeypointDetector(PersonKeypointOptions(num_threads=1)).load()


@pytest.fixture(scope="module")
def ring():
    """4 frame sets of the ring, as calibrate --videos reads them, and the Qualisys reference."""
    return load_qualisys_videos(POSE2SIM, num_sets=4)


@pytest.fixture(scope="module")
def ring_keypoints(detector, ring):
    """{camera: (33, 3)} per frame set, the first person found, and the seconds per image."""
    out, start = [], time.perf_counter()
    for frame_set in ring.frame_sets:
        found = {n: detector.detect(image) for n, image in zip(ring.camera_names, frame_set)}
        assert all(len(p) >= 1 for p in found.values()), {n: len(p) for n, p in found.items()}
        out.append({n: p[0] for n, p in found.items()})
    return out, (time.perf_counter() - start) / (len(ring.frame_sets) * len(ring.camera_names))


@needs_models
@needs_pose2sim
def test_the_person_is_found_in_every_cameras_frame_and_inside_it(ring, ring_keypoints):
    per_set, seconds = ring_keypoints
    print(f"BlazePose on the ring, 1 thread: {1000 * seconds:.0f} ms per 1088x1920 image")
    for keypoints, frame_set in zip(per_set, ring.frame_sets):
        for name, image in zip(ring.camera_names, frame_set):
            points = keypoints[name]
            height, width = image.shape[:2]
            assert points.shape == (33, 3) and len(LANDMARK_NAMES) == 33
            confident = points[points[:, 2] > CONFIDENT]
            assert len(confident) >= 25, (name, len(confident))  # a whole body (measured 28-33)
            assert (confident[:, :2] >= 0).all() and (confident[:, 0] <= width - 1).all()
            assert (confident[:, 1] <= height - 1).all()
            # one person on the platform 3-3.7 m away, leaning and stretching out a leg: the
            # landmarks span 25-75 % of the image's height (measured 33-42 %)
            extent = np.ptp(confident[:, :2], axis=0).max() / height
            assert 0.25 < extent < 0.75, (name, extent)


def _opencv_camera(ring, name):
    """K (OpenCV pixels), distortion, 3x4 cam_from_world of the Qualisys reference."""
    p = ring.gt.cameras[name].intrinsics.params  # COLMAP's OPENCV model: OpenCV's + 0.5
    k = np.array([[p[0], 0, p[2] - 0.5], [0, p[1], p[3] - 0.5], [0, 0, 1]])
    return k, np.asarray(p[4:8]), ring.gt_cam_from_world[name][:3]


def _transfer_errors_px(ring, per_set, order=None) -> np.ndarray:
    """Each confident joint triangulated from two cameras and reprojected into a third (the
    reference calibration): distance to where the third camera found it, every triple. `order`:
    the joints' order in the third camera (MIRROR: a wrong correspondence)."""
    cams = {n: _opencv_camera(ring, n) for n in ring.camera_names}
    errors = []
    for keypoints in per_set:
        for a, b in itertools.combinations(ring.camera_names, 2):
            rays = [cv2.undistortPoints(keypoints[n][:, None, :2].astype(np.float64),
                                        *cams[n][:2]).reshape(-1, 2).T for n in (a, b)]
            xyz = cv2.triangulatePoints(cams[a][2], cams[b][2], *rays)
            xyz = (xyz[:3] / xyz[3]).T
            for c in set(ring.camera_names) - {a, b}:
                k, dist, pose = cams[c]
                third = keypoints[c][order] if order is not None else keypoints[c]
                seen, _ = cv2.projectPoints(xyz, cv2.Rodrigues(pose[:, :3])[0], pose[:, 3], k,
                                            dist)
                ok = (keypoints[a][:, 2] > CONFIDENT) & (keypoints[b][:, 2] > CONFIDENT) & (
                    third[:, 2] > CONFIDENT)
                errors.append(np.linalg.norm(seen.reshape(-1, 2) - third[:, :2], axis=1)[ok])
    return np.concatenate(errors)


@needs_models
@needs_pose2sim
def test_the_same_joint_agrees_across_cameras_under_the_reference_calibration(ring,
                                                                             ring_keypoints):
    per_set, _ = ring_keypoints
    errors = _transfer_errors_px(ring, per_set)
    mirrored = _transfer_errors_px(ring, per_set, MIRROR)
    print(f"two cameras -> third, {len(errors)} joints: median {np.median(errors):.1f} px, "
          f"{np.mean(errors < 60):.0%} within 60 px; left/right swapped: median "
          f"{np.median(mirrored):.1f} px")
    # Measured (4 sets, 1467 joint transfers): median 28.8 px of a 1920-px image (the person
    # spans ~700 px), 82 % within 60 px; swapped, 88 px. The reference's distortion alone is
    # uncertain by up to ~7 px (SOURCE.md).
    assert len(errors) > 1000
    assert np.median(errors) < 45
    assert np.mean(errors < 60) > 0.65
    assert np.median(mirrored) > 1.4 * np.median(errors)  # identity is what agrees


@needs_models
@needs_pose2sim
def test_landmarks_follow_the_image_when_it_is_turned_upside_down(detector, ring):
    image = ring.frame_sets[1][2]
    height, width = image.shape[:2]
    upright = detector.detect(image)[0]
    turned = detector.detect(cv2.rotate(image, cv2.ROTATE_180))[0]
    back = np.column_stack([width - 1 - turned[:, 0], height - 1 - turned[:, 1]])
    moved = np.linalg.norm(back - upright[:, :2], axis=1)
    # measured 5-7 px median (the detections, hence the crops, differ a little)
    assert np.median(moved) < 12, np.median(moved)


def _command(out) -> list[str]:
    return ["keypoints", "--videos", str(POSE2SIM / "videos"), "--out", str(out),
            "--max-frame-sets", "2", "--threads", "1"]


@pytest.fixture(scope="module")
def written(tmp_path_factory):
    """KP_DIR as `densecalib keypoints` wrote it from 2 frame sets of the ring."""
    out = tmp_path_factory.mktemp("keypoints") / "kp"
    assert main(_command(out)) == 0
    return out


@needs_models
@needs_pose2sim
def test_the_command_writes_openpose_json_per_camera_and_frame(detector, written):
    source = yaml.safe_load((written / "keypoints_source.yaml").read_text())
    # 100 frames at 60 fps: the sets at 0.42 and 1.25 s are each video's frames 25 and 75
    assert source["frame_numbers"] == {f"cam0{i}": [25, 75] for i in range(1, 5)}
    assert source["keypoints"] == list(LANDMARK_NAMES)
    for name in ("cam01", "cam02", "cam03", "cam04"):
        files = sorted(p.name for p in (written / name).iterdir())
        assert files == [f"{name}_000000000025_keypoints.json",
                         f"{name}_000000000075_keypoints.json"]
    text = (written / "cam03" / "cam03_000000000075_keypoints.json").read_text()
    values = np.reshape(json.loads(text)["people"][0]["pose_keypoints_2d"], (33, 3))
    cap = cv2.VideoCapture(str(POSE2SIM / "videos" / "cam03.mp4"))
    cap.set(cv2.CAP_PROP_POS_FRAMES, 75)  # the file's number is the video's frame
    frame = cv2.cvtColor(cap.read()[1], cv2.COLOR_BGR2RGB)
    cap.release()
    expected = detector.detect(frame)[0]
    expected[expected[:, 2] <= 0] = 0.0
    np.testing.assert_allclose(values, expected, atol=2e-3)


@needs_models
@needs_pose2sim
def test_calibrates_keypoint_reader_takes_the_folder_as_one_camera_per_subfolder(written):
    reader = pytest.importorskip("densecalib_ros.core.io.keypoints",
                                 reason="calibrate's keypoint reader is not in this checkout")
    sources = reader.keypoint_sources([str(written)])
    assert sorted(sources) == ["cam01", "cam02", "cam03", "cam04"]
    for path in sources.values():
        read = reader.read_keypoints(path)
        assert list(read.frames) == [25, 75] and len(read.joints) == 33
        assert np.isfinite(read.xy_px).mean() > 0.8  # most landmarks are in the image


@needs_models
@needs_pose2sim
def test_the_command_replaces_its_own_output_and_nothing_else(written, tmp_path):
    assert main(_command(written)) == 0
    assert len(list((written / "cam01").iterdir())) == 2
    mine = tmp_path / "mine"
    mine.mkdir()
    (mine / "notes.txt").write_text("keep")
    assert main(_command(mine)) == 2
    assert (mine / "notes.txt").read_text() == "keep"
