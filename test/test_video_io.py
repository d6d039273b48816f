"""Frame sets from one video per camera (core.io.video_io, `densecalib calibrate --videos`): videos
written here with OpenCV in three containers, frames placed on the common timeline with offsets,
errors that say what to do, and a generated rig calibrated from its videos."""
import logging
import os
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import cv2
import numpy as np
import pytest

from densecalib_ros.cli import main
from densecalib_ros.core.errors import InputError, NotEnoughCamerasError
from densecalib_ros.core.io.export import read_calibration
from densecalib_ros.core.metrics import evaluate_calibration
from densecalib_ros.core.synthetic import RigSpec, generate_rig
from densecalib_ros.core.io.video_io import (VideoInfo, read_video_frame_sets,
                                             synchronising_trims)

BITS = 8


def _write_video(path, frames_rgb, fps, fourcc):
    h, w = frames_rgb[0].shape[:2]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), fps, (w, h))
    assert writer.isOpened(), f"OpenCV cannot write {fourcc} to {path}"
    for frame in frames_rgb:
        writer.write(cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
    writer.release()


def _numbered_frames(count, h=96, w=160):
    """Frame i shows i in binary as 16x16 black/white blocks (survives lossy codecs)."""
    frames = []
    for i in range(count):
        frame = np.full((h, w, 3), 90, np.uint8)
        for b in range(BITS):
            frame[16:32, 16 * b:16 * (b + 1)] = 255 if (i >> b) & 1 else 0
        frames.append(frame)
    return frames


def _frame_number(frame):
    return sum(1 << b for b in range(BITS) if frame[24, 16 * b + 8].mean() > 128)


# camera -> (file, fps, frames, codec, offset s): three containers, three frame rates
VIDEOS = {"camA": ("camA.mp4", 25.0, 60, "mp4v", 0.0),
          "camB": ("camB.avi", 30.0, 80, "MJPG", 0.5),   # started 0.5 s before camA
          "camC": ("camC.mkv", 10.0, 25, "FFV1", -0.2)}  # started 0.2 s after camA


@pytest.fixture(scope="module")
def video_dir(tmp_path_factory):
    path = tmp_path_factory.mktemp("videos")
    for file, fps, count, fourcc, _ in VIDEOS.values():
        _write_video(path / file, _numbered_frames(count), fps, fourcc)
    (path / "notes.txt").write_text("not a video")
    return path


def test_frames_are_taken_at_common_times_with_offsets(video_dir):
    offsets = {n: v[4] for n, v in VIDEOS.items() if v[4]}
    frame_sets, names, times = read_video_frame_sets(video_dir, 4, offsets)
    assert names == ["camA", "camB", "camC"]
    # common span: camA covers 0..2.4 s, camB -0.5..2.167 s, camC 0.2..2.7 s
    first, last = 0.2, 80 / 30 - 0.5
    even = first + (np.arange(4) + 0.5) * (last - first) / 4
    # each moved to the middle of the frame the slowest camera (camC, 10 fps) shows then
    _, slow_fps, _, _, slow_offset = VIDEOS["camC"]
    assert np.allclose(((np.asarray(times) + slow_offset) * slow_fps) % 1.0, 0.5)
    assert np.all(np.abs(np.asarray(times) - even) <= 0.5 / slow_fps)
    for t, time_s in enumerate(times):
        for c, name in enumerate(names):
            _, fps, _, _, offset = VIDEOS[name]
            frame = frame_sets[t][c]
            assert frame.shape == (96, 160, 3) and frame.dtype == np.uint8
            # the frame showing at the common time in this camera's file
            number = _frame_number(frame)
            assert number / fps <= time_s + offset < (number + 1) / fps


def test_window_and_set_count(video_dir):
    _, _, times = read_video_frame_sets(video_dir, 3, start_s=1.0, end_s=1.6)
    # 1.1, 1.3 and 1.5 s, each in the middle of one of camC's 0.1 s frames
    assert np.all(np.abs(np.asarray(times) - [1.1, 1.3, 1.5]) <= 0.05 + 1e-9)
    assert np.allclose(((np.asarray(times) - 0.2) * 10.0) % 1.0, 0.5)
    # never more sets than the slowest camera has frames in the window (camC: 10 fps)
    frame_sets, _, times = read_video_frame_sets(video_dir, 50, start_s=1.0, end_s=1.6)
    assert len(times) == len(frame_sets) == 6
    numbers = [_frame_number(fs[2]) for fs in frame_sets]
    assert numbers == sorted(set(numbers))


def test_an_offset_off_by_under_half_a_frame_picks_the_same_frames(tmp_path):
    """Two cameras at 6 fps started together (Caliscope's webcams): with an offset off by 0.3
    of a frame (50 ms, what motion sync estimated there) every set still takes the same frame
    number in both, wherever the evenly spaced times fall; at 0.7 of a frame the offset is
    taken as the next frame's."""
    for name in ("cam0", "cam1"):
        _write_video(tmp_path / f"{name}.mkv", _numbered_frames(57), 6.0, "FFV1")
    for offset, shift in ((0.05, 0), (-0.05, 0), (0.7 / 6, 1)):
        frame_sets, _, times = read_video_frame_sets(tmp_path, 8, {"cam1": offset})
        assert len(times) == 8
        assert all(_frame_number(fs[1]) == _frame_number(fs[0]) + shift for fs in frame_sets)


def test_trims_start_together_where_offsets_are_a_fraction_of_a_frame_off():
    """Four 6 fps videos started together, with the offsets motion sync estimates on
    Caliscope's webcams (+52, -33, -47 ms: up to a third of a frame off): every video is cut at
    the same frame, where at the latest camera's start cam_1's nearest frame was the next one;
    offsets of whole frames are kept exactly."""
    infos = [VideoInfo(Path(f"cam_{c}.mp4"), 6.0, 57, 1280, 720) for c in range(4)]
    trims = synchronising_trims(infos, [0.0, 0.052, -0.033, -0.047])
    assert len({t.first_frame for t in trims}) == 1 and len({t.num_frames for t in trims}) == 1
    trims = synchronising_trims(infos, [0.0, 2 / 6, -1 / 6, 0.0])
    assert [t.first_frame for t in trims] == [1, 3, 0, 1]


def test_errors_say_what_to_do(video_dir, tmp_path, caplog):
    with pytest.raises(InputError, match="unknown camera.*camZ.*camA, camB, camC"):
        read_video_frame_sets(video_dir, 2, {"camZ": 1.0})
    with pytest.raises(InputError, match="share no time span"):
        read_video_frame_sets(video_dir, 2, {"camB": 10.0})
    with pytest.raises(InputError, match="No videos"):
        read_video_frame_sets(tmp_path, 2)
    (tmp_path / "only.mp4").write_bytes((video_dir / "camA.mp4").read_bytes())
    with pytest.raises(NotEnoughCamerasError, match="only one video"):
        read_video_frame_sets(tmp_path, 2)
    (tmp_path / "only.avi").write_bytes((video_dir / "camB.avi").read_bytes())
    with pytest.raises(InputError, match="share the camera name.*only"):
        read_video_frame_sets(tmp_path, 2)
    (tmp_path / "only.avi").unlink()
    # a camera in another container is read; one given as a still among videos is warned of
    (tmp_path / "other.flv").write_bytes((video_dir / "camB.avi").read_bytes())
    cv2.imwrite(str(tmp_path / "still.png"), np.zeros((8, 8, 3), np.uint8))
    with caplog.at_level(logging.WARNING):
        assert read_video_frame_sets(tmp_path, 2)[1] == ["only", "other"]
    assert "still.png (images: only the videos are read" in caplog.text
    for name in ("other.flv", "still.png"):
        (tmp_path / name).unlink()
    (tmp_path / "broken.mp4").write_bytes(b"\x00" * 4096)
    with pytest.raises(InputError, match="Cannot open video .*broken.mp4"):
        read_video_frame_sets(tmp_path, 2)


@pytest.mark.parametrize("args, message", [
    (["--time-offset", "cam1"], "expected NAME=SECONDS"),
    (["--start", "1.0"], "--start belong(s) to --videos"),
    (["--topics", "/a", "/b"], "--topics belongs to --bag"),
    (["--align", "time"], "--align belongs to --images"),
    (["--start", "nan", "--videos"], "--start nan: give a time in seconds"),
    (["--end", "inf", "--videos"], "--end inf: give a time in seconds")])
def test_cli_video_options_are_checked(video_dir, tmp_path, caplog, args, message):
    source = [] if args[0] == "--start" else ["--videos", str(video_dir)]
    if args[-1] == "--videos":
        args, source = args[:-1], ["--videos", str(video_dir)]
    if not source:
        source = ["--images", str(tmp_path)]
    with caplog.at_level(logging.ERROR):
        assert main(["calibrate", *source, "--out", str(tmp_path / "o"), *args]) == 2
    assert message in caplog.text and not (tmp_path / "o").exists()


def test_rig_calibrated_from_its_videos(tmp_path):
    """Two scene states, 1 s each at 10 fps, one lossless video per camera; cam2 started
    recording 1 s early (its file opens with 10 black frames), which --time-offset undoes."""
    rig = generate_rig(RigSpec(lenses="ideal", num_cameras=4, camera_model="RADIAL", width=640, height=480,
                               num_time_steps=2, seed=3))
    videos = tmp_path / "videos"
    videos.mkdir()
    for c, name in enumerate(rig.names):
        frames = [rig.images[t][c] for t in range(2) for _ in range(10)]
        if name == "cam2":
            frames = [np.zeros_like(frames[0])] * 10 + frames
        _write_video(videos / f"{name}.mkv", frames, 10.0, "FFV1")
    out = tmp_path / "out"
    assert main(["calibrate", "--videos", str(videos), "--out", str(out), "--max-frame-sets", "2",
                 "--time-offset", "cam2=1", "--matcher", "sift", "--threads", "1",
                 "--consensus-runs", "1"]) == 0
    frame_sets, _, _ = read_video_frame_sets(videos, 2, {"cam2": 1.0})
    for t in range(2):  # lossless: the rig's own images
        assert all(np.array_equal(frame_sets[t][c], rig.images[t][c]) for c in range(4))
    unaligned, _, _ = read_video_frame_sets(videos, 2)
    assert not unaligned[0][2].any()  # without the offset: a black frame
    calibration = read_calibration(out)
    assert calibration.quality.input["time_offsets_s"] == {"cam2": 1.0}
    # the middle of the frames showing at 0.5 and 1.5 s
    assert calibration.quality.input["frame_set_times_s"] == pytest.approx([0.55, 1.55])
    metrics = evaluate_calibration(calibration, rig.ground_truth())
    assert metrics["num_registered"] == 4
    assert metrics["auc3"] >= 80.0 and metrics["median_focal_err"] <= 0.02
