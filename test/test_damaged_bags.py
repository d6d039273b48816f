"""Bags cut short or damaged, written here with `rosbags` and cut with truncate (issue 85 item 6):
a .db3 or .mcap cut at 5-99 % was refused whole ("File end magic is invalid", "database disk
image is malformed"); now the frame sets before the cut are read, with a warning that names the
damage and says what to do. In an mcap whose chunks carry no CRC (rosbags writes none), a damaged
message header was taken silently (a channel id changed hands cam_a's image to cam_b); now each
chunk's messages are checked against their MessageIndex records. Where a chunk has a CRC, damaged
image bytes are noticed too."""
import os
import shutil
import struct
import subprocess
import sys
import zlib

import numpy as np
import pytest

from densecalib_ros.core.io.bag import read_frame_sets, write_image_bag
from densecalib_ros.core.errors import InputError

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
TOPICS = ["/cam_a/image_raw", "/cam_b/image_raw"]
SETS = 16


def _frames(num_sets=SETS, num_cams=2, seed=0):
    rng = np.random.default_rng(seed)
    return [[rng.integers(0, 256, (48, 64, 3), np.uint8) for _ in range(num_cams)]
            for _ in range(num_sets)]


def _bag(tmp_path, storage, frames=None, name="bag"):
    """A bag of frames (16 sets of 2 cameras, 100 ms apart, camera c stamped c ms late); its
    storage file."""
    frames = frames or _frames()
    bag = tmp_path / name
    write_image_bag(bag, frames, TOPICS, [[t * 100_000_000 + c * 1_000_000 for c in range(2)]
                                          for t in range(len(frames))],
                    storage=storage, encoding="rgb8")
    return bag, next(p for p in bag.iterdir() if p.suffix in (".db3", ".mcap"))


def _same(got, frames):
    return all(np.array_equal(a, b) for fs, gs in zip(frames, got) for a, b in zip(fs, gs))


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
@pytest.mark.parametrize("kept", [0.3, 0.6, 0.95])
def test_a_bag_cut_short_gives_the_frame_sets_before_the_cut(tmp_path, caplog, storage, kept):
    frames = _frames()
    bag, stored = _bag(tmp_path, storage, frames)
    os.truncate(stored, int(stored.stat().st_size * kept))
    with caplog.at_level("WARNING", logger="densecalib_ros.core.io.bag"):
        got, _ = read_frame_sets(bag, TOPICS, slop_s=0.01)
    assert 1 <= len(got) < SETS and len(got) >= int(SETS * kept) - 3, len(got)
    assert _same(got, frames)  # the first sets, whole and as written
    assert f"Bag {bag} is damaged" in caplog.text
    assert f"Calibrating from the {len(got)} frame sets before it" in caplog.text
    assert "mcap recover" in caplog.text and "ros2 bag reindex" in caplog.text


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_a_bag_cut_before_its_first_frame_set_says_what_to_do(tmp_path, storage):
    bag, stored = _bag(tmp_path, storage)
    os.truncate(stored, int(stored.stat().st_size * 0.02))
    with pytest.raises(InputError, match="damaged.*no whole frame set before it. Record the rig "
                                         "again, or copy the bag"):
        read_frame_sets(bag, TOPICS, slop_s=0.01)


def _message_at(data: bytes, log_time_ns: int) -> int:
    """The offset in the file of the message record whose log and publish time are
    log_time_ns (write_image_bag writes both as the stamp)."""
    stamp = struct.pack("<QQ", log_time_ns, log_time_ns)
    at = data.index(stamp)
    assert data.find(stamp, at + 1) < 0
    return at - 6  # channel id (u16) and sequence (u32) before the log time


def test_a_damaged_message_header_is_noticed_in_an_mcap_without_chunk_crcs(tmp_path, caplog):
    """Set 9's cam_a message had its channel id changed to cam_b's: rosbags handed its image to
    cam_b without a word. Every chunk's messages are held against their index."""
    frames = [[np.kron(im, np.ones((4, 4, 1), np.uint8)) for im in fs] for fs in _frames()]
    bag, stored = _bag(tmp_path, "mcap", frames)  # 190x256 images: several chunks
    data = bytearray(stored.read_bytes())
    at = _message_at(bytes(data), 9 * 100_000_000)
    cam_b = struct.unpack_from("<H", data, _message_at(bytes(data), 9 * 100_000_000 + 1_000_000))
    assert struct.unpack_from("<H", data, at) != cam_b
    data[at:at + 2] = struct.pack("<H", *cam_b)
    stored.write_bytes(bytes(data))
    with caplog.at_level("WARNING", logger="densecalib_ros.core.io.bag"):
        got, _ = read_frame_sets(bag, TOPICS, slop_s=0.01)
    assert "differ from its index (a damaged message header)" in caplog.text, caplog.text
    assert 1 <= len(got) < 9 and _same(got, frames)


def _add_chunk_crcs(stored):
    """Write each chunk's CRC into an mcap that rosbags wrote without (as ros2 bag's mcap
    writer stores them by default); uncompressed chunks."""
    data = bytearray(stored.read_bytes())
    pos = 8
    while pos < len(data):
        opcode, length = struct.unpack_from("<BQ", data, pos)
        if opcode == 0x06:
            body = pos + 9
            (stored_len,) = struct.unpack_from("<Q", data, body + 28 + 4)  # compression ''
            records = bytes(data[body + 40:body + 40 + stored_len])
            struct.pack_into("<I", data, body + 24, zlib.crc32(records))
        if opcode == 0x0F:
            break
        pos += 9 + length
    stored.write_bytes(bytes(data))


def test_with_chunk_crcs_damaged_image_bytes_are_noticed(tmp_path, caplog):
    frames = [[np.kron(im, np.ones((4, 4, 1), np.uint8)) for im in fs] for fs in _frames()]
    bag, stored = _bag(tmp_path, "mcap", frames)
    _add_chunk_crcs(stored)
    got, _ = read_frame_sets(bag, TOPICS, slop_s=0.01)
    assert len(got) == SETS and _same(got, frames)
    data = bytearray(stored.read_bytes())
    at = _message_at(bytes(data), 12 * 100_000_000)
    data[at + 4000:at + 4100] = b"\xab" * 100  # inside that image's pixels
    stored.write_bytes(bytes(data))
    with caplog.at_level("WARNING", logger="densecalib_ros.core.io.bag"):
        got, _ = read_frame_sets(bag, TOPICS, slop_s=0.01)
    assert "fails its CRC check" in caplog.text and 1 <= len(got) <= 12 and _same(got, frames)


def test_calibrate_from_a_bag_cut_short_uses_the_frame_sets_before_the_cut(tmp_path):
    """`densecalib calibrate --bag` on an mcap cut at 60 % (a recorder killed by a full disk):
    exit 0 from the sets before the cut, the warning saying so (it was exit 2, "File end magic
    is invalid")."""
    from densecalib_ros.core.synthetic import RigSpec, generate_rig

    rig = generate_rig(RigSpec(lenses="ideal", num_cameras=3, camera_model="RADIAL", width=320,
                               height=240, num_time_steps=5, seed=1))
    topics = [f"/{name}/image_raw" for name in rig.names]
    bag = tmp_path / "bag"
    write_image_bag(bag, rig.images, topics, [t * 100_000_000 for t in range(5)],
                    storage="mcap", encoding="rgb8")
    stored = bag / "bag.mcap"
    os.truncate(stored, int(stored.stat().st_size * 0.6))
    env = {**os.environ, "PYTHONPATH": REPO + os.pathsep + os.environ.get("PYTHONPATH", "")}
    done = subprocess.run([sys.executable, "-m", "densecalib_ros.cli", "calibrate", "--bag",
                           str(bag), "--topics", *topics, "--out", str(tmp_path / "out"),
                           "--consensus-runs", "1"], capture_output=True, text=True, env=env,
                          timeout=300)
    said = done.stdout + done.stderr
    assert done.returncode == 0, said
    assert f"Bag {bag} is damaged (bag.mcap is cut short" in said
    assert "Calibrating from the 2 frame sets before it" in said or \
        "Calibrating from the 3 frame sets before it" in said, said
    assert (tmp_path / "out" / "calibration.json").exists()
    shutil.rmtree(tmp_path / "out")
