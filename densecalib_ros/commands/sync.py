"""`densecalib sync`: the time offsets between a rig's recordings, without calibrating
(core.motion_sync for videos and bags, core.clock_offsets for camera-trap shots): what to trim
or shift so that downstream tools (anipose triangulation, a video editor) see synchronised
cameras, and what `--time-offset` or the node's stamp_offsets_s should be."""
from __future__ import annotations

import argparse
import json
import logging

from ..core.errors import InputError

log = logging.getLogger("densecalib.sync")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    src = parser.add_mutually_exclusive_group(required=True)
    src.add_argument("--videos", metavar="DIR", help="one video per camera (file stem = name)")
    src.add_argument("--bag", metavar="PATH", help="rosbag2 bag (with --topics)")
    src.add_argument("--images", metavar="DIR",
                     help="one subfolder of EXIF-stamped shots per camera (camera traps)")
    parser.add_argument("--topics", nargs="+", metavar="TOPIC", help="the bag's image topics")
    parser.add_argument("--max-time-gap", type=float, default=None, metavar="S",
                        help="--images: how far apart shots taken together may be stamped "
                             "(default as calibrate's --max-time-gap)")
    parser.add_argument("--json", action="store_true", help="print the offsets as JSON")


def run(args: argparse.Namespace) -> int:
    try:
        if args.topics and not args.bag:
            raise InputError("--topics belongs to --bag.")
        if args.videos:
            from ..core.motion_sync import estimate_video_offsets
            from ..core.video_io import list_video_folder
            estimates = estimate_video_offsets(*list_video_folder(args.videos))
            evidence = {n: f"correlation {e.correlation:.2f}" for n, e in estimates.items()}
        elif args.bag:
            if not args.topics:
                raise InputError("--bag needs --topics: the image topic of every camera.")
            from ..core.bag import camera_names_from_topics
            from ..core.motion_sync import bag_offsets
            estimates = bag_offsets(args.bag, args.topics, camera_names_from_topics(args.topics))
            evidence = {n: f"correlation {e.correlation:.2f}" for n, e in estimates.items()}
        else:
            from ..core.clock_offsets import estimate_clock_offsets
            from ..core.image_io import DEFAULT_MAX_TIME_GAP_S, capture_times_by_camera
            gap = DEFAULT_MAX_TIME_GAP_S if args.max_time_gap is None else args.max_time_gap
            estimates = estimate_clock_offsets(capture_times_by_camera(args.images), gap)
            evidence = {n: f"{e.paired_shots} shots paired" for n, e in estimates.items()}
    except InputError as exc:
        log.error("%s", exc)
        return 2
    names = list(estimates)
    if args.json:
        print(json.dumps({"reference": names[0], "offsets_s": {
            n: float(e.offset_s) for n, e in estimates.items()}}, indent=2))
        return 0
    print(f"time offsets from {names[0]} (s; positive: the camera's time runs ahead, e.g. it "
          "started recording earlier)")
    for n, e in estimates.items():
        print(f"  {n:20s} {e.offset_s:+10.3f}   {'reference' if n == names[0] else evidence[n]}")
    option = " ".join(f"{n}={e.offset_s:.3f}" for n, e in estimates.items() if n != names[0])
    print(f"calibrate with: --time-offset {option}")
    if args.bag:  # the same clocks stamp the live topics: the node takes them as they are
        print("densecalib_node (image_topics in this order): stamp_offsets_s:=["
              + ", ".join(f"{e.offset_s:.4f}" for e in estimates.values()) + "]")
    return 0
