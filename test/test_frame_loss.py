"""Frames lost on the way to the node, told from header stamp gaps (ros.frame_loss; ROS-free)."""
import os
from pathlib import Path
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from densecalib_ros.ros.frame_loss import WARN_LOSS_FRACTION, StampGaps


def _feed(gaps, stamps_s):
    for t in stamps_s:
        gaps.add(int(round(t * 1e9)))
    return gaps


def test_lost_frames_are_counted_at_a_steady_rate_with_jitter():
    """15 fps stamped on arrival (+-4 ms), every third frame lost, and one run of 8 lost."""
    rng = np.random.default_rng(3)
    frames = [k for k in range(300) if k % 3 != 2 and not 200 <= k < 208]
    stamps = np.array(frames) / 15.0 + rng.uniform(-0.004, 0.004, len(frames))
    gaps = _feed(StampGaps(), stamps)
    lost = 300 - len(frames)
    assert gaps.period_s() == pytest.approx(1 / 15, rel=0.02)
    # the first MIN_INTERVALS intervals come before the period is known (5 frames lost in them)
    assert gaps.lost == lost - 5
    assert gaps.recent_loss() == pytest.approx(1 / 3, abs=0.03)


def test_half_the_frames_lost_is_not_taken_for_a_slower_camera():
    frames = [k for k in range(600) if k % 4 in (0, 1)]  # intervals 1, 3, 1, 3 ... periods
    gaps = _feed(StampGaps(), np.array(frames) / 30.0)
    assert gaps.period_s() == pytest.approx(1 / 30)
    assert gaps.recent_loss() == pytest.approx(0.5, abs=0.02)


def test_every_frame_received_counts_nothing():
    gaps = _feed(StampGaps(), np.arange(100) / 25.0)
    assert gaps.lost == 0 and gaps.recent_loss() == 0.0 < WARN_LOSS_FRACTION


def test_triggered_cameras_and_pauses_are_not_judged():
    """A camera trap fires at random times: no period, nothing lost. A steady camera that pauses
    for 3 s stopped (sync says so); it did not lose 45 frames."""
    rng = np.random.default_rng(5)
    trap = _feed(StampGaps(), np.cumsum(rng.exponential(2.0, 80)))
    assert trap.period_s() is None and trap.lost == 0
    stamps = np.concatenate([np.arange(50) / 15.0, 50 / 15.0 + 3.0 + np.arange(50) / 15.0])
    paused = _feed(StampGaps(), stamps)
    assert paused.lost == 0 and paused.period_s() == pytest.approx(1 / 15)


def test_stamps_jumping_back_start_over():
    """A bag replayed again: the stamps restart; the jump is no gap, and the period is found
    again from the new intervals."""
    gaps = _feed(StampGaps(), np.arange(60) / 10.0)
    _feed(gaps, np.arange(5) / 10.0)
    assert gaps.lost == 0 and gaps.period_s() is None  # 4 intervals since the jump
    _feed(gaps, 0.5 + np.arange(20) / 10.0)
    assert gaps.period_s() == pytest.approx(0.1) and gaps.lost == 0


def test_the_large_images_profile_gives_a_publisher_a_16_mb_segment(tmp_path):
    """config/fastdds_large_images.xml, as docs/ros.md 'Lost frames' tells drivers to load it: Fast DDS
    accepts it and the publishing process maps a 16 MB shared-memory segment (512 kB without)."""
    pytest.importorskip("rclpy", reason="needs rclpy (ROS 2 Jazzy)")
    if not Path("/dev/shm").is_dir():
        pytest.skip("no /dev/shm: Fast DDS's shared-memory transport is not available here")
    script = textwrap.dedent("""
        import os, rclpy
        from sensor_msgs.msg import Image
        rclpy.init(domain_id=int(os.environ["DOMAIN"]))
        node = rclpy.create_node("profile_probe")
        node.create_publisher(Image, "/probe/image_raw", 1).publish(Image())
        sizes = set()
        for line in open("/proc/self/maps"):
            path = line.split()[-1]
            if path.startswith("/dev/shm/fastrtps_") and not path.endswith("_el"):
                sizes.add(os.path.getsize(path))
        print(max(sizes, default=0))
        node.destroy_node()
        rclpy.shutdown()
        """)
    profile = Path(__file__).resolve().parents[1] / "config" / "fastdds_large_images.xml"
    largest = {}
    for name, env in (("default", {}),
                      ("profile", {"FASTRTPS_DEFAULT_PROFILES_FILE": str(profile)})):
        done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                              timeout=60, env={**os.environ, "DOMAIN": str(90 + os.getpid() % 20),
                                               "ROS_AUTOMATIC_DISCOVERY_RANGE": "LOCALHOST", **env})
        assert done.returncode == 0, done.stderr
        assert "Error" not in done.stderr, done.stderr  # Fast DDS's XML parser reports there
        largest[name] = int(done.stdout.split()[-1])
    assert 0 < largest["default"] < 1 << 20 and largest["profile"] >= 16 << 20, largest
