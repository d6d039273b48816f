"""Offline bag reading (core.io.bag): bags written here with `rosbags` (sqlite3 and mcap, raw and
compressed) read back to the same synchronised frames; camera names; errors; the shared real bag."""
from pathlib import Path

import numpy as np
import pytest

from densecalib_ros.core.io.bag import (camera_names_from_topics, iter_image_messages,
                                        read_frame_sets, write_image_bag)
from densecalib_ros.core.errors import InputError
from densecalib_ros.core.io.image_encoding import decode_compressed, encode_compressed

TOPICS = ["/rig/cam_a/image_raw", "/rig/cam_b/image_raw", "/cam_c/image_raw/compressed"]
SHARED_BAG = (Path(__file__).resolve().parents[2] / "shared" / "data"
              / "ros2bag_fisheye_stereo_derived" / "fisheye_stereo_bag")


def _frames(num_sets=5, num_cams=3, seed=0):
    rng = np.random.default_rng(seed)
    # 16x16 blocks (the jpeg MCU) so that jpeg with chroma subsampling stays close
    base = rng.integers(0, 256, (num_sets, num_cams, 6, 8, 3)).astype(np.uint8)
    return [[np.kron(base[t, c], np.ones((16, 16, 1), np.uint8)) for c in range(num_cams)]
            for t in range(num_sets)]


def _stamps(num_sets, num_cams, seed=1):
    """Set t at t*100 ms, each camera jittered by up to +-4 ms."""
    rng = np.random.default_rng(seed)
    return [[t * 100_000_000 + int(rng.integers(-4, 5)) * 1_000_000 for _ in range(num_cams)]
            for t in range(num_sets)]


def test_camera_names_from_topics():
    assert camera_names_from_topics(TOPICS) == ["rig_cam_a", "rig_cam_b", "cam_c"]
    assert camera_names_from_topics(["/stereo/left/image_raw", "/stereo/right/image_raw"]) == [
        "stereo_left", "stereo_right"]
    # stripping the stream name would collide: fall back to the whole topic
    assert camera_names_from_topics(["/cam0/image_raw", "/cam0/image_rect"]) == [
        "cam0_image_raw", "cam0_image_rect"]
    with pytest.raises(InputError, match="distinct"):
        camera_names_from_topics(["/a/image_raw", "/a/image_raw"])


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
@pytest.mark.parametrize("encoding", ["rgb8", "bgr8", "mono8", "mono16", "png", "jpeg",
                                      "bayer_grbg8"])
def test_round_trip(tmp_path, storage, encoding):
    frames = _frames()
    if encoding.startswith("mono"):
        frames = [[im[..., 1] for im in fs] for fs in frames]
    bag = tmp_path / f"bag_{storage}_{encoding}"
    write_image_bag(bag, frames, TOPICS, _stamps(5, 3), storage=storage, encoding=encoding)
    got, names = read_frame_sets(bag, TOPICS, slop_s=0.01)
    assert names == ["rig_cam_a", "rig_cam_b", "cam_c"]
    assert len(got) == 5
    for t in range(5):
        for c in range(3):
            assert got[t][c].shape == frames[t][c].shape and got[t][c].dtype == np.uint8
            err = np.abs(got[t][c].astype(int) - frames[t][c]).mean()
            # jpeg: lossy; Bayer: demosaicing blurs the 16x16 blocks' edges only
            assert err < (5.0 if encoding in ("jpeg", "bayer_grbg8") else 1e-9), (t, c, err)
            if encoding == "jpeg":  # the bag carries the encoder's bytes unchanged
                direct = decode_compressed("jpeg", encode_compressed(frames[t][c], "jpeg"))
                assert np.array_equal(got[t][c], direct)


def test_slop_selects_sets_and_stride_and_max(tmp_path):
    frames = _frames(num_sets=12, num_cams=2)
    stamps = _stamps(12, 2)
    stamps[4][1] += 30_000_000  # set 4: camera 1 is 30 ms late -> no set within 10 ms
    bag = tmp_path / "bag"
    write_image_bag(bag, frames, TOPICS[:2], stamps, storage="mcap", encoding="png")
    got, _ = read_frame_sets(bag, TOPICS[:2], slop_s=0.01)
    kept = [t for t in range(12) if t != 4]
    assert len(got) == 11
    assert all(np.array_equal(got[k][0], frames[t][0]) for k, t in enumerate(kept))
    got, _ = read_frame_sets(bag, TOPICS[:2], slop_s=0.05)
    assert len(got) == 12
    got, _ = read_frame_sets(bag, TOPICS[:2], slop_s=0.01, stride=2, max_frame_sets=3)
    # stride 2 over the 11 sets -> kept[0::2] (6 sets), then 3 evenly spaced: 0, 2 (rounded), 5
    expect = [kept[0::2][i] for i in (0, 2, 5)]
    assert [next(t for t in range(12) if np.array_equal(g[1], frames[t][1])) for g in got] == expect
    _, _, used = read_frame_sets(bag, TOPICS[:2], slop_s=0.01, stride=2, max_frame_sets=3,
                                 return_stamps=True)  # what a calibration records it used
    assert used == [stamps[t] for t in expect]


def test_iter_image_messages_gives_stamps_in_bag_order(tmp_path):
    frames, stamps = _frames(3, 2), _stamps(3, 2)
    write_image_bag(tmp_path / "b", frames, TOPICS[:2], stamps)
    got = [(i, s) for i, s, _, _, _ in iter_image_messages(tmp_path / "b", TOPICS[:2])]
    assert sorted(got, key=lambda x: (x[1], x[0])) == got
    assert sorted(got) == sorted((c, stamps[t][c]) for t in range(3) for c in range(2))


def test_a_topic_that_changes_resolution_is_refused_for_every_command(tmp_path):
    """check and overlay read bags through commands.inputs.read_input as calibrate does: a
    camera whose topic switched resolution part-way was judged moved there (calibrate's own check
    came later, in the pipeline); now the reader refuses it, naming the camera."""
    import argparse

    from densecalib_ros.commands.inputs import add_input_arguments, read_input

    frames = _frames(3, 2)
    frames[2][1] = frames[2][1][::2, ::2].copy()
    write_image_bag(tmp_path / "b", frames, TOPICS[:2], _stamps(3, 2))
    parser = argparse.ArgumentParser()
    add_input_arguments(parser)
    args = parser.parse_args(["--bag", str(tmp_path / "b"), "--topics", *TOPICS[:2]])
    with pytest.raises(InputError, match="Camera rig_cam_b's images change size between frame "
                                         "sets: 128x96 in set 0, 64x48 in set 2"):
        read_input(args)


def test_a_malformed_image_names_its_camera_and_stamp(tmp_path, monkeypatch):
    """A raw image whose data is shorter than its step says (a driver's bug, a cut recording):
    the error names the camera, topic and header stamp, and the bytes the size needs."""
    from densecalib_ros.core.io import image_encoding

    encode = image_encoding.encode_raw
    calls = []

    def cut_third(image, encoding):  # the 3rd message written (set 1, cam_a) loses its rows
        h, w, step, raw = encode(image, encoding)
        calls.append(1)
        return (h, w, step, raw[:1000]) if len(calls) == 3 else (h, w, step, raw)

    monkeypatch.setattr(image_encoding, "encode_raw", cut_third)
    write_image_bag(tmp_path / "b", _frames(2, 2), TOPICS[:2], [0, 10**8])
    with pytest.raises(InputError, match=r"Camera rig_cam_a \(/rig/cam_a/image_raw\), frame set "
                                         r"1 \(header stamp 100000000 ns\).*Malformed rgb8 "
                                         r"image: 128x96 needs step >= 384 and 36864 bytes, got "
                                         r"step 384 and 1000 bytes"):
        read_frame_sets(tmp_path / "b", TOPICS[:2])


def test_errors_name_what_to_do(tmp_path):
    write_image_bag(tmp_path / "b", _frames(2, 2), TOPICS[:2], [[0, 1000], [10**8, 10**8 + 1]])
    with pytest.raises(InputError, match="not in bag.*/rig/cam_a/image_raw"):
        read_frame_sets(tmp_path / "b", ["/nope/image_raw", TOPICS[0]])
    with pytest.raises(InputError, match="does not exist"):
        read_frame_sets(tmp_path / "missing", TOPICS[:2])
    with pytest.raises(InputError, match="No synchronised frame sets.*raise the slop.*--time-offset"):
        read_frame_sets(tmp_path / "b", TOPICS[:2], slop_s=0.0)
    with pytest.raises(InputError, match="sqlite3 or mcap"):
        write_image_bag(tmp_path / "c", _frames(1, 2), TOPICS[:2], [0], storage="zip")


def test_a_damaged_bag_gives_the_frame_sets_before_the_damage(tmp_path, caplog):
    """A page of a bag's database overwritten (a disk error, a copy cut short): the frame sets
    read before it are calibrated from, with a warning naming the bag (apsw.CorruptError was a
    traceback); damage before any whole frame set is an InputError saying what to do."""
    frames = [[np.kron(im, np.ones((2, 2, 1), np.uint8)) for im in fs] for fs in _frames(12, 2)]
    write_image_bag(tmp_path / "b", frames, TOPICS[:2], _stamps(12, 2))
    db = next((tmp_path / "b").glob("*.db3"))
    written = db.read_bytes()
    page = 4096  # sqlite's default page size; the messages fill the pages in stamp order

    def damage(index):
        data = bytearray(written)
        data[index * page:(index + 1) * page] = b"\xab" * page
        db.write_bytes(bytes(data))
    damage(len(written) // page * 2 // 3)
    with caplog.at_level("WARNING", logger="densecalib_ros.core.io.bag"):
        got, _ = read_frame_sets(tmp_path / "b", TOPICS[:2], slop_s=0.01)
    assert 1 <= len(got) < 12
    for t, frame_set in enumerate(got):
        assert all(np.array_equal(a, b) for a, b in zip(frame_set, frames[t]))
    assert f"Bag {tmp_path / 'b'} is damaged" in caplog.text
    assert f"Calibrating from the {len(got)} frame sets before it" in caplog.text
    damage(10)  # past the schema's pages, inside the first image (36 pages each)
    with pytest.raises(InputError, match="damaged.*no whole frame set before it. Record"):
        read_frame_sets(tmp_path / "b", TOPICS[:2], slop_s=0.01)


@pytest.mark.data
def test_shared_fisheye_stereo_bag():
    if not SHARED_BAG.exists():
        pytest.skip(f"shared data absent: {SHARED_BAG}")
    topics = ["/stereo/left/image_raw", "/stereo/right/image_raw"]
    frames, names = read_frame_sets(SHARED_BAG, topics)
    assert names == ["stereo_left", "stereo_right"]
    assert len(frames) == 20  # SOURCE.md: 20 pairs sharing one stamp each
    assert all(im.shape == (503, 800) and im.dtype == np.uint8 for fs in frames for im in fs)
    assert 40 < np.mean([fs[0].mean() for fs in frames]) < 220
    with pytest.raises(InputError, match="CameraInfo, not an image"):
        read_frame_sets(SHARED_BAG, ["/stereo/left/camera_info", topics[1]])


@pytest.mark.data
def test_shared_bag_calibrated_with_its_camera_info_matches_the_target_based_reference(tmp_path):
    """The real fisheye stereo bag carries the lab (checkerboard) intrinsics on its CameraInfo
    topics and the lab extrinsics on /tf_static (SOURCE.md): keeping the intrinsics, the
    calibration from the scene finds the right camera's rotation within 1 deg of the lab's."""
    if not SHARED_BAG.exists():
        pytest.skip(f"shared data absent: {SHARED_BAG}")
    from scipy.spatial.transform import Rotation

    from densecalib_ros.cli import main
    from densecalib_ros.core.io.export import read_calibration

    topics = ["/stereo/left/image_raw", "/stereo/right/image_raw"]
    out = tmp_path / "out"
    assert main(["calibrate", "--bag", str(SHARED_BAG), "--topics", *topics, "--preset",
                 "fisheye", "--bag-camera-info", "--max-frame-sets", "5", "--consensus-runs",
                 "1", "--out", str(out)]) == 0
    rig = read_calibration(out)
    left = rig.cameras["stereo_left"].intrinsics
    assert left.model == "OPENCV_FISHEYE"  # SOURCE.md: fx 290.738946, k1 -0.054041
    np.testing.assert_allclose(left.params[[0, 4]], [290.738946, -0.054041])
    # Reference: /tf_static left -> right optical frame = left_from_right; cam_from_rig of the
    # right camera (rig = left) is right_from_left.
    q = _tf_static_quaternion_xyzw(SHARED_BAG, "stereo_right_optical_frame")
    ref_right_from_left = Rotation.from_quat(q).inv()
    est = Rotation.from_matrix(rig.cameras["stereo_right"].cam_from_rig[:3, :3])
    error_deg = np.degrees((ref_right_from_left * est.inv()).magnitude())
    assert error_deg < 1.0


def _tf_static_quaternion_xyzw(bag_path: Path, child_frame: str) -> list[float]:
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    with Reader(bag_path) as reader:
        conns = [c for c in reader.connections if c.topic == "/tf_static"]
        for conn, _, raw in reader.messages(connections=conns):
            for tf in store.deserialize_cdr(raw, conn.msgtype).transforms:
                if tf.child_frame_id == child_frame:
                    r = tf.transform.rotation
                    return [r.x, r.y, r.z, r.w]
    raise AssertionError(f"no /tf_static transform to {child_frame}")
