"""`densecalib sync`: the time offsets between a rig's recordings, without calibrating
(core.io.motion_sync for videos and bags, core.io.clock_offsets for camera-trap shots): what to trim
or shift so that downstream tools (anipose triangulation, a video editor) see synchronised
cameras (`--trim` writes the videos so cut, `--restamp` a bag with the stamps moved onto one
clock), and what `--time-offset` or the node's stamp_offsets_s should be."""
from __future__ import annotations

import argparse
import dataclasses
import logging

from ..core.errors import InputError
from ..core.io.video_io import VIDEO_CODECS
from ..core.json_text import json_text

log = logging.getLogger("densecalib.sync")
TRIM_MARKERS = ("sync.json",)  # what makes a folder an earlier --trim output, to replace


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
    parser.add_argument("--json", action="store_true",
                        help="print the offsets as JSON, with what each rests on (correlations, "
                             "or shots paired)")
    parser.add_argument("--trim", metavar="OUT",
                        help="--videos: also write the videos cut to start at one moment (and, "
                             "at equal frame rates, to one length) into OUT, so that frame k "
                             "shows the same instant in every camera (anipose, Label3D); "
                             "re-encoded, with sync.json giving each cut")
    parser.add_argument("--restamp", metavar="OUT",
                        help="--bag: also write a copy of the bag into the new folder OUT with "
                             "every camera's header stamps (its image topic, other transports "
                             "and camera_info) moved onto the first camera's clock, so that "
                             "tools synchronising on stamps pair images taken together; other "
                             "topics and the log times as recorded")
    parser.add_argument("--time-offset", nargs="+", metavar="NAME=S",
                        help="--trim or --restamp: use these offsets (calibrate's convention) "
                             "instead of measuring them")
    parser.add_argument("--codec", choices=tuple(VIDEO_CODECS), default=None,
                        help="--trim: mp4v (.mp4, default), MJPG (.avi) or FFV1 (.mkv, lossless)")


def run(args: argparse.Namespace) -> int:
    try:
        if args.topics and not args.bag:
            raise InputError("--topics belongs to --bag.")
        if args.trim and not args.videos:
            raise InputError("--trim goes with --videos.")
        if args.restamp and not args.bag:
            raise InputError("--restamp goes with --bag.")
        if args.time_offset and not (args.trim or args.restamp):
            raise InputError("--time-offset gives the offsets: it goes with --trim or "
                             "--restamp.")
        if args.bag and not args.topics:
            raise InputError("--bag needs --topics: the image topic of every camera.")
        if args.max_time_gap is not None and not args.images:
            raise InputError("--max-time-gap goes with --images (EXIF-stamped shots); videos "
                             "and bag topics are paired by what moves in them.")
        if args.codec is not None and not args.trim:
            raise InputError("--codec is the --trim videos' codec: it goes with --trim.")
        args.codec = args.codec or "mp4v"
        if args.trim:
            from ..core.io.safe_write import check_output_folder
            check_output_folder(args.trim, TRIM_MARKERS, [args.videos])
        estimates, evidence, evidence_json = _offsets(args)
    except InputError as exc:
        log.error("%s", exc)
        return 2
    names = list(estimates)
    if args.trim:
        try:
            trims = _write_trimmed(args.videos, estimates, args.trim, args.codec)
        except InputError as exc:
            log.error("%s", exc)
            return 2
        if not args.json:
            residual = ", ".join(f"{n} {1000 * c['start_offset_s']:+.1f}" for n, c in trims.items())
            print(f"wrote {args.trim}: {len(trims)} videos starting together (residual start "
                  f"offsets ms: {residual}; at most half a frame)")
    if args.restamp:
        try:
            restamped = _write_restamped(args.bag, args.topics, estimates, args.restamp)
        except InputError as exc:
            log.error("%s", exc)
            return 2
        if not args.json:
            moved = "; ".join(
                f"{n} {-estimates[n].offset_s:+.4f} s ("
                + ", ".join(f"{t} {k}" for t, k in restamped[n].items()) + ")"
                for n in names[1:])
            print(f"wrote {args.restamp}: header stamps moved onto {names[0]}'s clock: {moved}; "
                  "other topics and the log times as recorded")
    if args.json:
        print(json_text({"reference": names[0], "offsets_s": {
            n: float(e.offset_s) for n, e in estimates.items()}, "evidence": evidence_json,
            **({"trimmed": trims} if args.trim else {}),
            **({"restamped": restamped} if args.restamp else {})}))
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


def _offsets(args: argparse.Namespace) -> tuple[dict, dict, dict]:
    """(camera -> offset estimate, camera -> evidence said, camera -> evidence for --json): the
    given offsets, else measured from the videos' motion, the bag's, or the images' times."""
    if args.time_offset:
        estimates = _given_offsets(args)
        from .inputs import parse_time_offsets
        named = parse_time_offsets(args.time_offset)
        evidence = {n: "given" if n in named else "not given: 0" for n in estimates}
        evidence_json = {n: {"given": n in named} for n in estimates}
    elif args.videos:
        from ..core.io.motion_sync import estimate_video_offsets
        from ..core.io.video_io import list_video_folder
        estimates = estimate_video_offsets(*list_video_folder(args.videos))
        evidence = {n: f"correlation {e.correlation:.2f}" for n, e in estimates.items()}
        evidence_json = _measured_evidence(estimates)
    elif args.bag:
        from ..core.io.bag import camera_names_from_topics
        from ..core.io.motion_sync import bag_offsets
        estimates = bag_offsets(args.bag, args.topics, camera_names_from_topics(args.topics))
        evidence = {n: f"correlation {e.correlation:.2f}" for n, e in estimates.items()}
        evidence_json = _measured_evidence(estimates)
    else:
        from ..core.io.clock_offsets import estimate_clock_offsets
        from ..core.io.image_io import DEFAULT_MAX_TIME_GAP_S, capture_times_by_camera
        gap = DEFAULT_MAX_TIME_GAP_S if args.max_time_gap is None else args.max_time_gap
        estimates = estimate_clock_offsets(capture_times_by_camera(args.images), gap)
        evidence = {n: f"{e.paired_shots} shots paired" for n, e in estimates.items()}
        evidence_json = _measured_evidence(estimates)
    return estimates, evidence, evidence_json


def _measured_evidence(estimates: dict) -> dict:
    """What each measured offset rests on, for --json: the peak's correlation and the best one
    elsewhere (motion), or the shots paired at the offset and at any other (camera-trap clocks);
    a low first or a close second means an unsure offset."""
    return {n: {k: v for k, v in dataclasses.asdict(e).items() if k != "offset_s"}
            for n, e in estimates.items()}


def _write_trimmed(video_dir, estimates: dict, out, codec: str) -> dict:
    """Write the videos of video_dir cut to one start (core.io.video_io.synchronising_trims) into
    out (replaced as a whole, with sync.json); returns the cuts by camera."""
    from ..core.io.safe_write import replace_directory_atomic
    from ..core.io.video_io import (list_video_folder, probe_video, synchronising_trims,
                                    transcode_video)

    paths, names = list_video_folder(video_dir)
    infos = [probe_video(p) for p in paths]
    offsets = [estimates[n].offset_s for n in names]
    trims = synchronising_trims(infos, offsets)
    if len({info.fps for info in infos}) > 1:
        log.warning("the videos have different frame rates (%s): they start together but frame k "
                    "is not the same instant in all; tools that index frames need one rate",
                    ", ".join(f"{n} {i.fps:g}" for n, i in zip(names, infos)))
    record = {"source": str(video_dir), "offsets_s": dict(zip(names, offsets)), "cameras": {}}

    def build(tmp):
        for name, info, trim in zip(names, infos, trims):
            dest = tmp / f"{name}{VIDEO_CODECS[codec]}"
            written = transcode_video(info, dest, codec, trim.first_frame, trim.num_frames)
            record["cameras"][name] = {"file": dest.name, "first_frame": trim.first_frame,
                                       "frames": written, "fps": info.fps,
                                       "start_offset_s": trim.start_s - trims[0].start_s}
            log.info("%s: frames %d..%d of %s (%d)", name, trim.first_frame,
                     trim.first_frame + written - 1, info.path.name, written)
        (tmp / "sync.json").write_text(json_text(record) + "\n")

    replace_directory_atomic(build, out, TRIM_MARKERS, [video_dir])
    return record["cameras"]


def _given_offsets(args) -> dict:
    """--time-offset NAME=S ... as estimates for the cameras of --videos or --topics (0 for the
    cameras not named)."""
    from ..core.io.motion_sync import OffsetEstimate
    from .inputs import parse_time_offsets

    if args.videos:
        from ..core.io.video_io import list_video_folder
        names, what = list_video_folder(args.videos)[1], "videos"
    else:
        from ..core.io.bag import camera_names_from_topics
        names, what = camera_names_from_topics(args.topics), "topics"
    given = parse_time_offsets(args.time_offset)
    unknown = sorted(set(given) - set(names))
    if unknown:
        raise InputError(f"--time-offset names unknown camera(s) {', '.join(unknown)}: the "
                         f"{what} are of {', '.join(names)}.")
    return {n: OffsetEstimate(float(given.get(n, 0.0)), float("nan"), float("nan"))
            for n in names}


def _write_restamped(bag, topics: list[str], estimates: dict, out) -> dict:
    """Copy the bag into out with each camera's clock topics (core.io.bag.clock_topics) restamped
    by its offset; returns camera -> {topic: messages restamped}."""
    from ..core.io.bag import clock_topics, recorded_topics, restamp_bag

    recorded = recorded_topics(bag)
    by_camera, offsets_ns, owner = {}, {}, {}
    for name, topic in zip(estimates, topics):
        by_camera[name] = clock_topics(recorded, topic)
        for t in by_camera[name]:
            if t in owner:
                raise InputError(f"{t} belongs to the camera of {owner[t]} and to that of "
                                 f"{topic}: it cannot be moved onto both clocks. Restamping "
                                 "needs each camera's topics in a namespace of its own "
                                 "(/cam0/image_raw, /cam0/camera_info).")
            owner[t] = topic
            offsets_ns[t] = int(round(estimates[name].offset_s * 1e9))
    note = json_text({"restamped_by": "densecalib sync --restamp", "source": str(bag),
                       "offsets_s": {n: e.offset_s for n, e in estimates.items()},
                       "topics": by_camera}, indent=None)
    counts = restamp_bag(bag, out, {t: o for t, o in offsets_ns.items() if o}, note)
    return {n: {t: counts.get(t, 0) for t in ts} for n, ts in by_camera.items()}
