"""`densecalib bench-node`: does densecalib_node keep up with a rig's image streams on this
computer? Plays a rig of cameras from driver processes to a fresh node process per run and
prints, per run, the frames the node received of those published, the frames it counted lost
from the gaps in the stamps, the frame sets it matched and its CPU time (see
densecalib_ros.ros.intake_bench). Give it your rig's numbers (cameras, image size, encoding,
rate, one driver process or one per camera) and `--driver-profile` to see what the drivers' Fast
DDS profile changes."""
from __future__ import annotations

import argparse
import json
import logging
from pathlib import Path

from ..core.errors import InputError

log = logging.getLogger("densecalib.bench_node")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--cameras", type=int, default=4, help="cameras (default 4)")
    parser.add_argument("--size", default="768x512", metavar="WxH",
                        help="image size in px (default 768x512)")
    parser.add_argument("--encoding", default="mono8",
                        help="mono8, rgb8, bgr8 (sensor_msgs/Image) or jpeg, png "
                             "(CompressedImage on <topic>/compressed); default mono8")
    parser.add_argument("--rate", type=float, default=15.0,
                        help="frames a second per camera (default 15)")
    parser.add_argument("--seconds", type=float, default=10.0,
                        help="how long each run publishes (default 10)")
    parser.add_argument("--qos", choices=("sensor", "reliable"), default="sensor",
                        help="the drivers' QoS: sensor (best effort, as most camera drivers; "
                             "default) or reliable")
    parser.add_argument("--sync-window-s", type=float, default=0.0,
                        help="the node's sync_window_s (motion tracking for ~/sync: a decode of "
                             "every image); default 0 = off")
    parser.add_argument("--driver-profile", default=None, metavar="XML",
                        help="Fast DDS profile for the drivers' process (what "
                             "FASTRTPS_DEFAULT_PROFILES_FILE gives a camera driver), e.g. "
                             "config/fastdds_large_images.xml; the node keeps this shell's "
                             "environment")
    parser.add_argument("--drivers", choices=("one", "per-camera"), default="one",
                        help="driver processes: one publishing every camera (default; a "
                             "multi-camera driver) or one per camera")
    parser.add_argument("--runs", type=int, default=1,
                        help="runs, each against a newly started node (default 1)")
    parser.add_argument("--domain-id", type=int, default=None,
                        help="ROS domain of the bench (default: one from 50-99, off a live "
                             "rig's; discovery is kept on this machine unless "
                             "ROS_AUTOMATIC_DISCOVERY_RANGE says otherwise)")
    parser.add_argument("--json", default=None, metavar="PATH", help="also write the figures here")


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise InputError(f"--size {text!r}: give WIDTHxHEIGHT in pixels, e.g. 1280x720.") from None
    return w, h


def run(args: argparse.Namespace) -> int:
    try:
        from ..ros.intake_bench import IntakeBenchSpec, format_report, run_bench
    except ImportError as exc:
        log.error("bench-node needs ROS 2 (rclpy, sensor_msgs, diagnostic_msgs): %s. Install them "
                  "as the README's set-up does, or source your ROS 2 installation.", exc)
        return 2
    try:
        width, height = _size(args.size)
        spec = IntakeBenchSpec(cameras=args.cameras, width=width, height=height,
                               encoding=args.encoding, rate_hz=args.rate, seconds=args.seconds,
                               qos=args.qos, sync_window_s=args.sync_window_s)
        report = run_bench(spec, runs=args.runs, drivers=args.drivers, domain_id=args.domain_id,
                           driver_profile=args.driver_profile, log=log.info)
    except InputError as exc:
        log.error("%s", exc)
        return 2
    except RuntimeError as exc:  # the node did not start, subscribe or report
        log.error("%s", exc)
        return 1
    print(format_report(report))
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=2) + "\n")
        print(f"figures: {args.json}")
    return 0
