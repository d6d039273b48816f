"""Approximate-time synchronisation and the frame-set buffer (core.io.sync, shared by bag reader and
node), plus the node's thread-safe message adapter (ros.sync)."""
import logging
import threading

import numpy as np
import pytest

from densecalib_ros.core.errors import InputError
from densecalib_ros.core.io.sync import (ApproximateTimeSynchronizer, FrameSet, FrameSetBuffer,
                                         evenly_spaced)

MS = 1_000_000


def test_pairs_within_slop_and_drops_unmatched():
    sync = ApproximateTimeSynchronizer(2, slop_s=0.005)
    out = []
    # stream 0 at 0, 100, 200 ms; stream 1 at 3, 150 (no partner), 198 ms
    for stream, t in [(0, 0), (1, 3), (0, 100), (1, 150), (0, 200), (1, 198)]:
        out += sync.add(stream, t * MS, (stream, t))
    assert [s.items for s in out] == [[(0, 0), (1, 3)], [(0, 200), (1, 198)]]
    assert [s.stamp_ns for s in out] == [3 * MS, 200 * MS]
    assert sync.stats.matched == 2
    assert sync.stats.dropped_unmatched == 2  # 100 (stream 0) and 150 (stream 1)
    assert sync.pending() == [0, 0]


def test_three_streams_with_jitter_and_reordering():
    rng = np.random.default_rng(0)
    sync = ApproximateTimeSynchronizer(3, slop_s=0.01, queue_size=20)
    events = []
    for k in range(20):
        for c in range(3):
            events.append((k * 100 * MS + int(rng.integers(-4, 4)) * MS, c, k))
    # arrival order: by stamp, with cameras 1 and 2 swapped inside each frame
    events.sort(key=lambda e: (e[0] // (100 * MS), -e[1]))
    out = []
    for t, c, k in events:
        out += sync.add(c, t, k)
    assert len(out) == 20
    assert all(s.items == [k, k, k] for k, s in enumerate(out))
    assert all(max(s.stamps_ns) - min(s.stamps_ns) <= 10 * MS for s in out)


def test_exact_stamps_with_zero_slop_and_queue_overflow():
    sync = ApproximateTimeSynchronizer(2, slop_s=0.0, queue_size=3)
    for t in range(5):  # stream 1 silent: stream 0's queue keeps only the newest 3
        assert sync.add(0, t, t) == []
    assert sync.stats.dropped_overflow == 2
    assert sync.pending() == [3, 0]
    out = sync.add(1, 3, "b3")
    assert len(out) == 1 and out[0].items == [3, "b3"]
    assert sync.stats.dropped_unmatched == 1  # stamp 2 can no longer be matched


def test_invalid_arguments_are_refused():
    with pytest.raises(InputError, match="slop_s"):
        ApproximateTimeSynchronizer(2, slop_s=-1.0)
    with pytest.raises(InputError, match="at least one stream"):
        ApproximateTimeSynchronizer(0, slop_s=0.1)
    with pytest.raises(InputError, match="out of range"):
        ApproximateTimeSynchronizer(2, slop_s=0.1).add(2, 0, None)
    with pytest.raises(InputError, match="capacity"):
        FrameSetBuffer(0)


def test_buffer_drops_oldest_and_skips_close_sets():
    buf = FrameSetBuffer(capacity=3, min_interval_s=0.5)
    stamps_s = [0.0, 0.2, 1.0, 2.0, 3.0, 3.4, 4.0]
    accepted = [buf.push(FrameSet([int(t * 1e9)] * 2, [t, t])) for t in stamps_s]
    assert accepted == [True, False, True, True, True, False, True]
    assert [s.items[0] for s in buf.snapshot()] == [2.0, 3.0, 4.0]
    assert buf.dropped_oldest == 2 and buf.skipped_interval == 2 and len(buf) == 3


def test_message_synchronizer_is_thread_safe():
    pytest.importorskip("rclpy")
    from sensor_msgs.msg import Image

    from densecalib_ros.ros.sync import MessageSynchronizer

    sync = MessageSynchronizer(2, slop_s=0.001, buffer_size=1000)

    def feed(stream):
        for k in range(300):
            msg = Image()
            msg.header.stamp.sec, msg.header.stamp.nanosec = k, 0
            sync.add(stream, msg)

    threads = [threading.Thread(target=feed, args=(c,)) for c in (0, 1)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    stats = sync.stats()
    assert stats["received"] == [300, 300]
    # Every message is accounted for exactly once (no lost update under concurrency).
    assert 2 * stats["matched"] + stats["dropped_unmatched"] + stats["dropped_overflow"] + \
        sum(stats["pending"]) == 600
    assert stats["matched"] == stats["buffered"] >= 1
    sets = sync.snapshot()
    assert all(s.items[0].header.stamp.sec == s.items[1].header.stamp.sec for s in sets)


def test_evenly_spaced_keeps_the_ends_and_logs(caplog):
    items = list(range(100))
    with caplog.at_level(logging.INFO):
        assert evenly_spaced(items, 5) == [0, 25, 50, 74, 99]
    assert "Using 5 of 100 frame sets" in caplog.text
    assert evenly_spaced(items[:3], 5) == [0, 1, 2] and evenly_spaced(items, None) == items
    with pytest.raises(InputError, match="at least 1"):
        evenly_spaced(items, 0)


def test_message_synchronizer_takes_clock_offsets_off_the_stamps():
    """Stream 1's clock runs 0.35 s ahead: at 25 Hz its stamps still find partners within the
    slop, 9 frames off; with its offset given, each set holds the images taken together."""
    pytest.importorskip("rclpy")
    from sensor_msgs.msg import Image

    from densecalib_ros.ros.sync import MessageSynchronizer

    def run(offsets):
        sync = MessageSynchronizer(2, slop_s=0.02, buffer_size=1000, stamp_offsets_s=offsets)
        for k in range(100):
            for stream, clock_ns in ((0, 0), (1, 350_000_000)):
                msg = Image()
                stamp = k * 40_000_000 + clock_ns
                msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 1_000_000_000)
                msg.header.frame_id = str(k)  # the moment it was taken
                sync.add(stream, msg)
        return [(int(s.items[0].header.frame_id), int(s.items[1].header.frame_id))
                for s in sync.snapshot()]

    assert all(b - a == -9 for a, b in run(None))
    together = run([0.0, 0.35])
    assert len(together) >= 90 and all(a == b for a, b in together)


def test_message_synchronizer_tells_why_no_frame_sets_form():
    """A camera never heard from, one that stopped, and clocks further apart than the slop are
    each named as such (an operator's first question when a calibration is refused)."""
    pytest.importorskip("rclpy")
    from sensor_msgs.msg import Image

    from densecalib_ros.ros.sync import MessageSynchronizer

    now = [0.0]
    names, topics = ["left", "right", "rear"], ["/l/image", "/r/image", "/b/image"]
    sync = MessageSynchronizer(3, slop_s=0.02, buffer_size=10, clock=lambda: now[0])

    def publish(stream, stamp_s):
        msg = Image()
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(stamp_s * 1e9), 10**9)
        sync.add(stream, msg)

    for k in range(3):
        now[0] = float(k)
        publish(0, k), publish(1, k)
    assert len(sync) == 0
    why = sync.why_few_sets(names, topics)
    assert why.startswith("no image received from rear (/b/image)") and "left 3" in why

    for k in range(3, 10):  # rear publishes once, at t=3 s, then stops; the others go on
        now[0] = float(k)
        publish(0, k), publish(1, k)
        if k == 3:
            publish(2, k)
    assert len(sync) == 1
    why = sync.why_few_sets(names, topics)
    assert "stopped publishing" in why and "rear (/b/image) 6 s ago" in why and "left" not in \
        why.split("(messages")[0]

    for k in range(10, 13):  # all live again, rear's clock 0.5 s behind
        now[0] = float(k)
        publish(0, k), publish(1, k), publish(2, k - 0.5)
    assert len(sync) == 1
    why = sync.why_few_sets(names, topics)
    assert "0.500 s apart, more than slop_s 0.02" in why and "rear -0.500" not in why
    assert "left +0.500" in why and "rear +0.000" in why and "~/sync" in why


def test_why_few_sets_adds_the_frames_lost_on_the_way():
    """Scattered losses leave few sets complete on every camera: the reason given for too few
    sets says how many frames each losing camera missed, and what to do."""
    pytest.importorskip("rclpy")
    from sensor_msgs.msg import Image

    from densecalib_ros.ros.sync import MessageSynchronizer

    names, topics = ["left", "right", "rear"], ["/l/image", "/r/image", "/b/image"]
    sync = MessageSynchronizer(3, slop_s=0.02, buffer_size=10, clock=lambda: 0.0)
    for k in range(60):  # 10 fps; rear loses every fourth frame
        for stream in range(3):
            if stream == 2 and k % 4 == 3:
                continue
            msg = Image()
            msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(int(k * 1e8), 10**9)
            sync.add(stream, msg)
    why = sync.why_few_sets(names, topics)
    lost = why.split("frames were lost on the way (at least ")[1]
    assert lost.startswith("rear ") and "left" not in lost.split(")")[0]
    assert 10 <= int(lost.split()[1].rstrip(",")) <= 15, why
    assert "fastdds_large_images.xml" in why
