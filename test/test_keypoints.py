"""Pose keypoints read as correspondences by identity (core.io.keypoints*, core.method.
identity_tracks): every tool's file gives back what was written, in COLMAP pixels as tracks; the
likelihood threshold, the frame offsets and the cap on tracks; errors that name the camera, the
file and the frame. No calibration here (test_arena_keypoints.py calibrates)."""
import json

import h5py
import numpy as np
import pytest

from densecalib_ros.core.errors import InputError
from densecalib_ros.core.io.keypoints import camera_of, keypoint_sources, read_keypoints
from densecalib_ros.core.method.identity_tracks import MIN_LIKELIHOOD, identity_tracks
from keypoint_fixtures import (JOINTS, SCORER, arena, dlc_frame, write_dlc, write_openpose,
                               write_slp)

SIZE = (640, 480)


@pytest.fixture(scope="module")
def walk():
    return arena(seed=3, num_cameras=3, gap_deg=70, frames=120)


def _read(folder, names):
    return {n: read_keypoints(p) for n, p in keypoint_sources([str(folder)], names).items()}


@pytest.mark.parametrize("fmt", ["csv", "h5"])
def test_deeplabcut_files_read_back_as_written_and_become_colmap_tracks(walk, tmp_path, fmt):
    write_dlc(walk, tmp_path, fmt)
    names = walk.rig.names
    read = _read(tmp_path, names)
    assert sorted(read) == names  # the scorer after the video's name is not the camera's
    kp = read["cam1"]
    assert kp.tool == "DeepLabCut" and kp.joints == JOINTS and kp.individuals == ("",)
    np.testing.assert_array_equal(kp.frames, np.arange(120))
    np.testing.assert_allclose(kp.xy_px[:, 0], walk.xy_px[1], equal_nan=True)
    np.testing.assert_allclose(kp.likelihood[:, 0], walk.likelihood[1])

    found = identity_tracks(read, names, [SIZE] * 3)
    confident = np.isfinite(walk.xy_px[..., 0]) & (walk.likelihood >= MIN_LIKELIHOOD)
    expected = (confident.sum(axis=0) >= 2).sum()  # (frame, joint) seen by two or more
    assert found.tracks.num_tracks == expected == found.record["tracks"]
    # every observation is a confident one, moved to COLMAP's pixel centres (+0.5)
    obs = found.tracks.observed()
    assert obs.sum(axis=1).min() >= 2
    frames, joints = np.nonzero(confident.sum(axis=0) >= 2)
    for c in range(3):
        want = np.where(confident[c, frames, joints, None], walk.xy_px[c, frames, joints] + 0.5,
                        np.nan)
        np.testing.assert_allclose(found.tracks.xy_px[:, c], want, equal_nan=True)


def test_a_lower_threshold_keeps_the_mistakes_the_tool_scored_low(walk, tmp_path):
    write_dlc(walk, tmp_path)
    read = _read(tmp_path, walk.rig.names)
    strict = identity_tracks(read, walk.rig.names, [SIZE] * 3)
    loose = identity_tracks(read, walk.rig.names, [SIZE] * 3, min_likelihood=0.0)
    assert loose.tracks.observed().sum() > strict.tracks.observed().sum() * 1.04


def test_multi_animal_csv_pairs_individuals_by_name_not_column_order(tmp_path):
    rng = np.random.default_rng(0)
    xy = rng.uniform(10, 400, (5, 2, 3, 2))  # (frames, individuals, joints, 2)
    like = np.full((5, 2, 3), 0.9)
    dlc_frame(xy, like, ["mouse1", "mouse2"]).to_csv(tmp_path / "camA.csv")
    dlc_frame(xy[:, ::-1] + 1, like, ["mouse2", "mouse1"]).to_csv(tmp_path / "camB.csv")
    read = _read(tmp_path, ["camA", "camB"])
    assert read["camA"].individuals == ("mouse1", "mouse2")
    found = identity_tracks(read, ["camA", "camB"], [SIZE] * 2)
    assert found.tracks.num_tracks == 5 * 2 * 3 and found.record["individuals"] == [
        "mouse1", "mouse2"]
    np.testing.assert_allclose(found.tracks.xy_px[:, 1] - found.tracks.xy_px[:, 0], 1.0)


def test_sleap_labels_file_predictions_tracks_and_legacy_pixel_origin(walk, tmp_path):
    xy = np.stack([walk.xy_px[0], walk.xy_px[0] + 5], axis=1)
    like = np.stack([walk.likelihood[0]] * 2, axis=1)
    path = tmp_path / "cam0.predictions.slp"
    write_slp(path, xy, like, "cam0.mp4", SIZE, track_names=("rat_a", "rat_b"))
    assert camera_of(path) == "cam0"
    kp = read_keypoints(path)
    assert kp.tool == "SLEAP" and kp.image_size == SIZE and kp.individuals == ("rat_a", "rat_b")
    seen = np.isfinite(kp.xy_px[..., 0])
    np.testing.assert_allclose(kp.xy_px[:, 1][seen[:, 1]], xy[kp.frames][:, 1][seen[:, 1]])
    np.testing.assert_allclose(kp.likelihood[seen], like[kp.frames][seen])
    with h5py.File(path, "a") as f:  # files before format 1.1 put (0, 0) at the pixel's corner
        f["metadata"].attrs["format_id"] = 1.0
    old = read_keypoints(path)
    np.testing.assert_allclose(old.xy_px[seen], kp.xy_px[seen] - 0.5)


def test_sleap_analysis_h5_and_openpose_json(walk, tmp_path):
    path = tmp_path / "cam2.analysis.h5"
    with h5py.File(path, "w") as f:  # SLEAP's export: (individuals, 2, nodes, frames)
        f["tracks"] = walk.xy_px[2].transpose(2, 1, 0)[None]
        f["point_scores"] = walk.likelihood[2].T[None]
        f["node_names"] = [n.encode() for n in JOINTS]
        f["track_names"] = [b"rat"]
    kp = read_keypoints(path)
    assert kp.tool == "SLEAP" and kp.individuals == ("rat",) and kp.joints == JOINTS
    np.testing.assert_allclose(kp.xy_px[:, 0], walk.xy_px[2], equal_nan=True)

    write_openpose(tmp_path / "op" / "cam1_json", walk.xy_px[1], walk.likelihood[1], "cam1")
    assert list(keypoint_sources([str(tmp_path / "op")])) == ["cam1"]
    kp = read_keypoints(tmp_path / "op" / "cam1_json")
    seen = np.isfinite(walk.xy_px[1, :, :, 0])
    assert kp.tool == "OpenPose" and len(kp.joints) == len(JOINTS)
    np.testing.assert_allclose(kp.xy_px[:, 0][seen], walk.xy_px[1][seen])


def test_openpose_frames_with_several_unnamed_people_are_left_out(tmp_path):
    one = {"people": [{"person_id": [-1], "pose_keypoints_2d": [10, 20, 0.9] * 4}]}
    two = {"people": one["people"] * 2}
    named = {"people": [{"person_id": [7], "pose_keypoints_2d": [30, 40, 0.8] * 4},
                        {"person_id": [9], "pose_keypoints_2d": [50, 60, 0.8] * 4}]}
    for frame, content in ((3, one), (4, two), (5, named)):
        (tmp_path / f"vid_{frame:012d}_keypoints.json").write_text(json.dumps(content))
    kp = read_keypoints(tmp_path)
    assert list(kp.frames) == [3, 5] and kp.individuals == ("", "7", "9")
    assert kp.xy_px[1, 2, 0].tolist() == [50, 60] and np.isnan(kp.xy_px[1, 0]).all()


def test_frame_offset_pairs_a_camera_that_started_early(walk, tmp_path):
    kps = {}
    for c, name in enumerate(walk.rig.names):
        frame = dlc_frame(walk.xy_px[c], walk.likelihood[c])
        if name == "cam1":  # started 7 frames before the others: its frame k + 7 is their k
            frame.index = frame.index + 7
        frame.to_csv(tmp_path / f"{name}.csv")
        kps[name] = read_keypoints(tmp_path / f"{name}.csv")
    right = identity_tracks(_read_written(walk, tmp_path / "right"), walk.rig.names, [SIZE] * 3)
    paired = identity_tracks(kps, walk.rig.names, [SIZE] * 3, frame_offsets={"cam1": 7})
    np.testing.assert_array_equal(paired.tracks.xy_px, right.tracks.xy_px)
    assert paired.record["frame_offsets"] == {"cam1": 7}
    unpaired = identity_tracks(kps, walk.rig.names, [SIZE] * 3)
    assert unpaired.tracks.num_tracks != right.tracks.num_tracks


def _read_written(walk, folder):
    write_dlc(walk, folder)
    return _read(folder, walk.rig.names)


def test_the_tracks_come_from_evenly_spaced_frames_when_there_are_too_many(walk, tmp_path):
    read = _read_written(walk, tmp_path)
    capped = identity_tracks(read, walk.rig.names, [SIZE] * 3, max_tracks=300)
    assert 200 <= capped.tracks.num_tracks <= 300
    assert capped.record["frames_used"] < 60


def test_errors_name_the_camera_the_file_and_what_to_do(walk, tmp_path):
    read = _read_written(walk, tmp_path)
    with pytest.raises(InputError, match=r"cam1 .*cam1DLC.*outside its 320x240 images \(frame"):
        identity_tracks(read, walk.rig.names, [SIZE, (320, 240), SIZE])
    with pytest.raises(InputError, match="camX.*which the rig does not have"):
        identity_tracks({**read, "camX": read["cam0"]}, walk.rig.names, [SIZE] * 3)
    other = dlc_frame(walk.xy_px[0][:, :2], walk.likelihood[0][:, :2])
    other.columns = other.columns.set_levels(["nose", "tail"], level="bodyparts")
    other.to_csv(tmp_path / "cam2.csv")
    with pytest.raises(InputError, match="share no joints.*cam2 .*cam2.csv.*(nose|tail)"):
        identity_tracks({**read, "cam2": read_keypoints(tmp_path / "cam2.csv")},
                        walk.rig.names, [SIZE] * 3)
    (tmp_path / "bad.csv").write_text("frame,x,y\n0,1,2\n")
    with pytest.raises(InputError, match="bad.csv: not a DeepLabCut CSV"):
        read_keypoints(tmp_path / "bad.csv")
    with pytest.raises(InputError, match="cam0 given twice"):
        keypoint_sources([str(tmp_path / f"cam0{SCORER}.csv"), f"cam0={tmp_path / 'cam2.csv'}"],
                         walk.rig.names)


def test_a_folder_with_deeplabcuts_h5_and_csv_of_one_video_reads_the_h5(walk, tmp_path):
    write_dlc(walk, tmp_path, "csv")
    write_dlc(walk, tmp_path, "h5")
    sources = keypoint_sources([str(tmp_path)])
    assert sorted(sources) == walk.rig.names and {p.suffix for p in sources.values()} == {".h5"}


def test_labelled_data_csv_rows_are_images_numbered_by_frame(tmp_path):
    import pandas as pd

    columns = pd.MultiIndex.from_product([["Alex"], ["snout", "tail"], ["x", "y"]],
                                         names=["scorer", "bodyparts", "coords"])
    rows = pd.MultiIndex.from_tuples([("labeled-data", "cam0", f"img{k:04d}.png")
                                      for k in (42, 7)])
    values = np.array([[1.0, 2.0, np.nan, np.nan], [3.0, 4.0, 5.0, 6.0]])
    pd.DataFrame(values, index=rows, columns=columns).to_csv(tmp_path / "CollectedData_Alex.csv")
    kp = read_keypoints(tmp_path / "CollectedData_Alex.csv")
    assert list(kp.frames) == [7, 42] and kp.joints == ("snout", "tail")
    assert kp.xy_px[1, 0, 0].tolist() == [1.0, 2.0] and np.isnan(kp.likelihood[1, 0, 1])
    assert kp.likelihood[0, 0].tolist() == [1.0, 1.0]  # a person placed them


def test_with_videos_the_time_offsets_pair_the_keypoints_by_each_videos_frame_rate(walk,
                                                                                    tmp_path):
    import argparse

    import cv2

    from densecalib_ros.commands import calibrate
    from densecalib_ros.commands.keypoint_inputs import read_keypoint_input

    videos = tmp_path / "videos"
    videos.mkdir()
    for name in walk.rig.names:  # 25 fps: cam1's 0.28 s early start is 7 of its frames
        writer = cv2.VideoWriter(str(videos / f"{name}.avi"), cv2.VideoWriter_fourcc(*"MJPG"),
                                 25.0, (64, 48))
        for _ in range(5):
            writer.write(np.zeros((48, 64, 3), np.uint8))
        writer.release()
    for c, name in enumerate(walk.rig.names):
        frame = dlc_frame(walk.xy_px[c], walk.likelihood[c])
        if name == "cam1":
            frame.index = frame.index + 7
        frame.to_csv(tmp_path / f"{name}.csv")
    parser = argparse.ArgumentParser()
    calibrate.add_arguments(parser)
    args = parser.parse_args(["--videos", str(videos), "--keypoints", *(
        str(tmp_path / f"{n}.csv") for n in walk.rig.names), "--out", str(tmp_path / "out")])
    frame_sets = [[np.zeros((480, 640, 3), np.uint8)] * 3]
    found = read_keypoint_input(args, walk.rig.names, frame_sets,
                                {"time_offsets_s": {"cam0": 0.0, "cam1": 0.28, "cam2": 0.0}})
    right = identity_tracks(_read_written(walk, tmp_path / "right"), walk.rig.names, [SIZE] * 3)
    assert found.record["frame_offsets"] == {"cam0": 0, "cam1": 7, "cam2": 0}
    np.testing.assert_array_equal(found.tracks.xy_px, right.tracks.xy_px)


def test_files_of_frames_no_two_cameras_share_are_refused_with_their_spans(walk, tmp_path):
    read = _read_written(walk, tmp_path)
    with pytest.raises(InputError, match=r"No joint .*cam1 frames 500-619.*frame offset"):
        identity_tracks(read, walk.rig.names, [SIZE] * 3, frame_offsets={"cam1": -500,
                                                                           "cam2": 300})
