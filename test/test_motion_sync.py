"""Time offsets of a rig's videos from their motion (core.io.motion_sync, `--time-offset auto`):
videos of one moving object seen by three cameras with different views, gains, frame rates and
start times give back each camera's start within half a frame; a static scene is refused with
what to do."""
import argparse
import json
import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import cv2
import numpy as np
import pytest

from densecalib_ros.commands.inputs import add_input_arguments, read_input
from densecalib_ros.core.errors import InputError
from densecalib_ros.core.io.video_io import list_video_folder
from densecalib_ros.core.io.motion_sync import estimate_video_offsets
from motion_fixtures import arena_views

# camera -> (fps, recording start in world time [s], view (y0, y1, x0, x1) of the world, gain)
CAMERAS = {"cam0": (25.0, 0.0, (0, 360, 0, 560), 1.0),
           "cam1": (30.0, -0.7, (20, 360, 60, 640), 0.8),   # started 0.7 s before cam0
           "cam2": (25.0, 1.23, (0, 330, 40, 600), 1.15)}   # started 1.23 s after cam0
# the same rig filmed at 10, 60 and 25 fps, lossy MPEG-4
MIXED_RATES = {name: (fps, *rest) for (name, (_, *rest)), fps in zip(CAMERAS.items(),
                                                                      (10.0, 60.0, 25.0))}


def _write_videos(folder, moving=True, cameras=CAMERAS, codec=("MJPG", ".avi")):
    for name, frames in arena_views(cameras, moving).items():
        writer = cv2.VideoWriter(str(folder / f"{name}{codec[1]}"),
                                 cv2.VideoWriter_fourcc(*codec[0]), cameras[name][0], (320, 200))
        assert writer.isOpened()
        for frame in frames:
            writer.write(cv2.cvtColor(frame, cv2.COLOR_GRAY2BGR))
        writer.release()


@pytest.fixture(scope="module")
def videos(tmp_path_factory):
    folder = tmp_path_factory.mktemp("arena")
    _write_videos(folder)
    return folder


def test_offsets_found_within_a_fraction_of_a_frame(videos):
    paths, names = list_video_folder(videos)
    estimates = estimate_video_offsets(paths, names)
    for name, (fps, start_s, _, _) in CAMERAS.items():
        truth = CAMERAS["cam0"][1] - start_s  # an early start is a positive offset
        assert abs(estimates[name].offset_s - truth) < 0.2 / fps, (name, estimates[name])
    assert estimates["cam1"].correlation > 0.5


def test_cameras_at_different_frame_rates(tmp_path):
    """10 fps against 60 fps: each pair's offset within half the slower camera's frame."""
    _write_videos(tmp_path, cameras=MIXED_RATES, codec=("mp4v", ".mp4"))
    estimates = estimate_video_offsets(*list_video_folder(tmp_path))
    for name, (fps, start_s, _, _) in MIXED_RATES.items():
        truth = MIXED_RATES["cam0"][1] - start_s
        slower = min(fps, MIXED_RATES["cam0"][0])
        assert abs(estimates[name].offset_s - truth) < 0.5 / slower, (name, estimates[name])


def test_auto_offsets_place_the_frame_sets(videos):
    parser = argparse.ArgumentParser()
    add_input_arguments(parser)
    args = parser.parse_args(["--videos", str(videos), "--time-offset", "auto",
                              "--max-frame-sets", "3"])
    frame_sets, names, record, _ = read_input(args)
    assert names == list(CAMERAS) and len(frame_sets) == 3
    assert record["time_offsets_s"]["cam1"] == pytest.approx(0.7, abs=0.02)
    assert record["time_offsets_estimated"]["cam2"]["offset_s"] == pytest.approx(-1.23, abs=0.02)
    # the common span starts when the last camera (cam2) started
    assert record["frame_set_times_s"][0] > 1.23
    mixed = parser.parse_args(["--videos", str(videos), "--time-offset", "auto", "cam1=0.7"])
    with pytest.raises(InputError, match="give `auto` alone"):
        read_input(mixed)


def test_a_static_scene_gives_no_offsets(tmp_path):
    _write_videos(tmp_path, moving=False)
    paths, names = list_video_folder(tmp_path)
    with pytest.raises(InputError, match="does not determine the time offset of cam1.*"
                                         "--time-offset NAME=S"):
        estimate_video_offsets(paths, names)


def _stamps(bag, topic):
    """The header stamps [ns] of a bag topic's messages, in bag order."""
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    with Reader(bag) as reader:
        conns = [c for c in reader.connections if c.topic == topic]
        assert conns, topic
        return [(lambda h: h.stamp.sec * 1_000_000_000 + h.stamp.nanosec)(
            store.deserialize_cdr(raw, c.msgtype).header)
            for c, _, raw in reader.messages(connections=conns)]


def test_bag_topics_stamped_by_different_clocks_are_synchronised(tmp_path, capsys):
    """A bag whose cam1 stamps run 0.35 s ahead and cam2's 0.8 s behind cam0's: synchronised by
    stamps alone, its frame sets join images taken up to 0.8 s apart (at 25 fps every offset
    leaves a partner within the slop); --time-offset auto finds the clocks from the motion."""
    from densecalib_ros.core.io.bag import write_image_bag

    clocks = {"cam0": 0.0, "cam1": 0.35, "cam2": -0.8}
    phases = {"cam0": 0.0, "cam1": 0.006, "cam2": 0.013}  # capture moments within the slop
    spec = {n: (25.0, phases[n], CAMERAS[n][2], CAMERAS[n][3]) for n in CAMERAS}
    views = arena_views(spec, size=(160, 100))
    frames = [list(fs) for fs in zip(*views.values())]  # frames[k][c]
    stamps = [[int(round((k / 25.0 + phases[n] + clocks[n]) * 1e9)) for n in CAMERAS]
              for k in range(len(frames))]
    bag = tmp_path / "arena_bag"
    topics = [f"/{n}/image_raw" for n in CAMERAS]
    overview = [f[0] for f in frames]  # a fourth image topic that is not one of the cameras
    write_image_bag(bag, [f + [o] for f, o in zip(frames, overview)],
                    topics + ["/overview/image_raw"],
                    [s + [s[0]] for s in stamps], encoding="mono8",
                    camera_infos=[{"image_width": 160, "image_height": 100,
                                   "distortion_model": "plumb_bob",
                                   "distortion_coefficients": {"data": [0.0] * 5},
                                   "camera_matrix": {"data": [100, 0, 80, 0, 100, 50, 0, 0, 1]},
                                   "rectification_matrix": {"data": [1, 0, 0, 0, 1, 0, 0, 0, 1]},
                                   "projection_matrix": {"data": [100, 0, 80, 0, 0, 100, 50, 0,
                                                                  0, 0, 1, 0]}}] * 4)
    parser = argparse.ArgumentParser()
    add_input_arguments(parser)


    def spread_s(row):  # of the moments a frame set's images were taken
        taken = [t * 1e-9 - clocks[n] for t, n in zip(row, CAMERAS)]
        return max(taken) - min(taken)

    plain = parser.parse_args(["--bag", str(bag), "--topics", *topics, "--max-frame-sets", "4"])
    assert all(spread_s(row) > 0.3 for row in read_input(plain)[2]["frame_set_stamps_ns"])
    args = parser.parse_args(["--bag", str(bag), "--topics", *topics, "--max-frame-sets", "4",
                              "--time-offset", "auto"])
    frame_sets, names, record, _ = read_input(args)
    assert names == list(CAMERAS) and len(frame_sets) == 4
    for name, clock in clocks.items():
        assert record["time_offsets_s"][name] == pytest.approx(clock, abs=0.5 / 25.0)
    # each set's images were taken together: their recorded stamps differ by the clocks
    assert all(spread_s(row) < 0.02 for row in record["frame_set_stamps_ns"])
    manual = parser.parse_args(["--bag", str(bag), "--topics", *topics, "--max-frame-sets", "4",
                                "--time-offset", "cam1=0.35", "cam2=-0.8"])
    assert len(read_input(manual)[0]) == 4
    from densecalib_ros.cli import main

    assert main(["sync", "--bag", str(bag), "--topics", *topics]) == 0
    node_line = capsys.readouterr().out.splitlines()[-1]
    offsets = json.loads(node_line.split(":=")[1])  # the node parameter, in the topics' order
    assert offsets == pytest.approx(list(clocks.values()), abs=0.5 / 25.0)

    # --restamp: a copy whose stamps synchronise without offsets; camera_info moved with its
    # camera, a topic that is not a camera's (/overview) and the log times as recorded
    from densecalib_ros.core.io.bag import iter_image_messages

    restamped = tmp_path / "restamped"
    assert main(["sync", "--bag", str(bag), "--topics", *topics, "--restamp",
                 str(restamped)]) == 0
    out = capsys.readouterr().out
    assert "/cam1/image_raw 500, /cam1/camera_info 500" in out, out
    same = parser.parse_args(["--bag", str(restamped), "--topics", *topics,
                              "--max-frame-sets", "4"])
    frame_sets, _, record, _ = read_input(same)
    assert len(frame_sets) == 4
    assert all(max(row) - min(row) < 0.02e9 for row in record["frame_set_stamps_ns"])
    all_topics = topics + ["/overview/image_raw"]
    before = list(iter_image_messages(bag, all_topics))
    after = list(iter_image_messages(restamped, all_topics))
    assert [(i, log) for i, _, log, _, _ in before] == [(i, log) for i, _, log, _, _ in after]
    moved = {}
    for (i, s0, _, _, m0), (_, s1, _, _, m1) in zip(before, after):
        moved.setdefault(i, set()).add(s0 - s1)
        assert np.array_equal(m0.data, m1.data)
    assert moved[0] == {0} and moved[3] == {0}  # the reference camera and /overview
    assert len(moved[1]) == len(moved[2]) == 1
    assert abs(moved[1].pop() - 0.35e9) < 0.5e9 / 25 and abs(moved[2].pop() + 0.8e9) < 0.5e9 / 25
    for i, topic in enumerate(topics):  # each CameraInfo keeps its image's stamp
        assert _stamps(restamped, f"/{topic.split('/')[1]}/camera_info") == \
            [s for j, s, _, _, _ in after if j == i]
    # given offsets give exactly those; an existing folder is never overwritten
    exact = tmp_path / "exact"
    assert main(["sync", "--bag", str(bag), "--topics", *topics, "--restamp", str(exact),
                 "--time-offset", "cam1=0.35", "cam2=-0.8", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["restamped"]["cam2"] == {
        "/cam2/image_raw": 500, "/cam2/camera_info": 500}
    shifted = [s for i, s, _, _, _ in iter_image_messages(exact, topics) if i == 2]
    original = [s for i, s, _, _, _ in iter_image_messages(bag, topics) if i == 2]
    assert [a - b for a, b in zip(original, shifted)] == [-800_000_000] * len(original)
    assert main(["sync", "--bag", str(bag), "--topics", *topics, "--restamp", str(exact),
                 "--time-offset", "cam1=0.35"]) == 2
    assert len(list(iter_image_messages(exact, topics))) == len(original) * 3


def test_sync_command_prints_the_offsets(videos, capsys, caplog):
    from densecalib_ros.cli import main

    assert main(["sync", "--videos", str(videos), "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["reference"] == "cam0"
    assert data["offsets_s"]["cam2"] == pytest.approx(-1.23, abs=0.01)
    evidence = data["evidence"]["cam2"]  # as the text's "correlation", and the runner-up
    assert evidence["correlation"] > 0.5 > evidence["second_correlation"]
    assert main(["sync", "--videos", str(videos)]) == 0
    out = capsys.readouterr().out
    assert "calibrate with: --time-offset cam1=0.70" in out and "correlation" in out
    with caplog.at_level("ERROR"):
        assert main(["sync", "--bag", str(videos)]) == 2
    assert "--bag needs --topics" in caplog.text


def test_cameras_seeing_different_halves_are_tied_through_a_third(tmp_path):
    """cam0 sees the arena's left 60 %, cam2 its right 60 %, cam1 all of it: cam0 and cam2 share
    little motion, but each shares enough with cam1, and every pair is compared."""
    from densecalib_ros.core.io.motion_sync import estimate_offset, motion_signal
    from densecalib_ros.core.io.video_io import probe_video

    halves = {"cam0": (25.0, 0.0, (0, 360, 0, 380), 1.0),
              "cam1": (25.0, -0.7, (0, 360, 0, 640), 0.8),
              "cam2": (25.0, 1.23, (0, 360, 260, 640), 1.15)}
    _write_videos(tmp_path, cameras=halves)
    estimates = estimate_video_offsets(*list_video_folder(tmp_path))
    for name, (fps, start_s, _, _) in halves.items():
        assert abs(estimates[name].offset_s - (0.0 - start_s)) < 0.5 / fps, name
    direct = estimate_offset(*(motion_signal(probe_video(tmp_path / f"{n}.avi"), 120.0)
                               for n in ("cam0", "cam2")), 0.04, 0.04)
    assert estimates["cam2"].correlation > direct.correlation  # from its pair with cam1


def test_trim_writes_videos_whose_frame_k_shows_one_instant(tmp_path, capsys, caplog):
    """sync --trim: three 25 fps videos started at 0, -0.7 and +1.23 s are cut (by the measured
    offsets) to start within half a frame of one another, with as many frames each, every
    trimmed frame the source frame sync.json names; given offsets cut the same way."""
    same_rate = {name: (25.0, *rest) for name, (_, *rest) in CAMERAS.items()}
    folder = tmp_path / "arena"
    folder.mkdir()
    _write_videos(folder, cameras=same_rate)
    from densecalib_ros.cli import main

    out = tmp_path / "trimmed"
    assert main(["sync", "--videos", str(folder), "--trim", str(out), "--codec", "MJPG"]) == 0
    assert "3 videos starting together" in capsys.readouterr().out
    cuts = json.loads((out / "sync.json").read_text())["cameras"]
    assert len({c["frames"] for c in cuts.values()}) == 1
    shown = [same_rate[n][1] + c["first_frame"] / 25.0 for n, c in cuts.items()]  # world time
    assert max(shown) - min(shown) <= 0.5 / 25.0 + 1e-9
    for name, cut in cuts.items():
        source, trimmed = (cv2.VideoCapture(str(p)) for p in (folder / f"{name}.avi",
                                                               out / cut["file"]))
        source.set(cv2.CAP_PROP_POS_FRAMES, cut["first_frame"])
        a, b = (c.read()[1].astype(float) for c in (source, trimmed))
        assert 10 * np.log10(255 ** 2 / np.mean((a - b) ** 2)) > 30  # the same frame, re-encoded
    given = tmp_path / "given"
    assert main(["sync", "--videos", str(folder), "--trim", str(given), "--codec", "FFV1",
                 "--time-offset", "cam1=0.7", "cam2=-1.23", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert {n: c["first_frame"] for n, c in data["trimmed"].items()} == \
        {n: c["first_frame"] for n, c in cuts.items()}
    cut = data["trimmed"]["cam2"]  # FFV1 is lossless: every frame as decoded from the source
    assert cut["file"] == "cam2.mkv"
    source, trimmed = (cv2.VideoCapture(str(p)) for p in (folder / "cam2.avi", given / "cam2.mkv"))
    source.set(cv2.CAP_PROP_POS_FRAMES, cut["first_frame"])
    for _ in range(cut["frames"]):
        assert np.array_equal(source.read()[1], trimmed.read()[1])
    assert not trimmed.read()[0]
    assert main(["sync", "--videos", str(folder), "--trim", str(tmp_path / "one"), "--codec",
                 "FFV1", "--time-offset", "cam1=0.7"]) == 0
    text = capsys.readouterr().out
    assert "given" in text and "not given: 0" in text  # cam2 was not named: 0, and said so
    with caplog.at_level("ERROR"):
        assert main(["sync", "--videos", str(folder), "--time-offset", "cam1=0.7"]) == 2
    assert "it goes with --trim" in caplog.text
    # options of another mode: refused, not ignored
    for options, said in ((["--codec", "FFV1"], "--codec is the --trim videos' codec"),
                          (["--max-time-gap", "1"], "--max-time-gap goes with --images")):
        caplog.clear()
        with caplog.at_level("ERROR"):
            assert main(["sync", "--videos", str(folder), *options]) == 2
        assert said in caplog.text
