"""Where a rig's frame sets come from, for the commands that read them (calibrate, check): a folder
of images (one per camera, or camera subfolders paired by name, position or EXIF time), one video
per camera, or a rosbag2 bag, and the masks of what in the images is not scene. Each source is
recorded as it was used (quality.input)."""
from __future__ import annotations

import argparse
import logging
from pathlib import Path
from typing import Optional

import numpy as np

from ..core.errors import InputError
from ..core.io.image_io import ALIGNMENTS, DEFAULT_MAX_TIME_GAP_S
from ..core.io.sync import DEFAULT_MAX_FRAME_SETS, evenly_spaced
from ..core.io.video_io import DEFAULT_VIDEO_FRAME_SETS
from ..core.method.frame_checks import camera_sizes
from ..core.named_values import split_named

log = logging.getLogger("densecalib.inputs")

DEFAULT_SLOP_S = 0.02


def add_input_arguments(parser: argparse.ArgumentParser, required: bool = True) -> None:
    """The options of read_input; required=False: the command checks for a source itself
    (calibrate: --keypoints alone)."""
    src = parser.add_mutually_exclusive_group(required=required)
    src.add_argument("--images", metavar="DIR",
                     help="one image per camera (file stem = camera name) or one subfolder per "
                          "camera with time-aligned images (see --align)")
    src.add_argument("--videos", metavar="DIR",
                     help="one video per camera (file stem = camera name) on one timeline; "
                          f"--max-frame-sets (default {DEFAULT_VIDEO_FRAME_SETS}) frame sets are "
                          "taken at evenly spaced times")
    src.add_argument("--bag", metavar="PATH", help="rosbag2 bag (sqlite3 or mcap)")
    parser.add_argument("--topics", nargs="+", metavar="TOPIC",
                        help="image topics of the bag, one per camera (with --bag)")
    parser.add_argument("--slop", type=float, default=None, metavar="S",
                        help="with --bag: the most the stamps of a synchronised frame set may "
                             f"differ (s, default {DEFAULT_SLOP_S:g})")
    parser.add_argument("--max-frame-sets", type=int, default=None, metavar="N",
                        help="use at most N evenly spaced frame sets (default "
                             f"{DEFAULT_MAX_FRAME_SETS}; {DEFAULT_VIDEO_FRAME_SETS} from videos)")
    parser.add_argument("--align", choices=ALIGNMENTS, default="auto",
                        help="with --images and camera subfolders: pair images by file name, "
                             "sorted position, or EXIF capture time (default auto: the names "
                             "every camera has when that is at least half of them, else "
                             "position when the counts agree)")
    parser.add_argument("--max-time-gap", type=float, default=None,
                        metavar="S", help="with --align time: the most a frame set's capture "
                                          f"times may differ (default {DEFAULT_MAX_TIME_GAP_S:g})")
    parser.add_argument("--without", nargs="+", default=(), metavar="CAMERA",
                        help="with --images: leave these cameras out (their subfolders or "
                             "files are not read). A camera subfolder without images is "
                             "refused unless named here: the rig would lose that camera")
    parser.add_argument("--time-offset", nargs="+", default=None, metavar="NAME=S|auto",
                        help="how far this camera's time runs ahead of the others' (s): with "
                             "--videos, a camera that started recording 0.4 s early is NAME=0.4; "
                             "with --align time, a trail camera whose clock is 60 s fast is "
                             "NAME=60; with --bag, a topic whose stamping clock runs 0.4 s "
                             "ahead is NAME=0.4. `auto` finds them: with --videos and --bag from "
                             "what moves in their first 2 minutes, with --align time from which "
                             "capture times pair up")
    parser.add_argument("--start", type=float, default=None, metavar="S",
                        help="with --videos: take frames from this common time on (s)")
    parser.add_argument("--end", type=float, default=None, metavar="S",
                        help="with --videos: take frames up to this common time (s)")
    parser.add_argument("--mask", nargs="+", default=None, metavar="PATH|NAME=PATH",
                        help="image of a camera's size, black where matches are not used (the "
                             "rig's own structure, a lens hood, an info strip): one PATH for "
                             "every camera or NAME=PATH per camera")
    parser.add_argument("--keep-info-strips", action="store_true",
                        help="do not look for burnt-in info strips (a trail camera's bar of "
                             "date and temperature along the top or bottom edge), whose rows "
                             "are otherwise ignored in cameras without a --mask")
    parser.add_argument("--match-whole-frames", action="store_true",
                        help="calibrate: match every frame set's whole images; by default asift "
                             "(--matcher or the second matcher) matches frame sets after the first "
                             "only where a camera's image shows what its earlier ones did not "
                             "(the static scene was matched in the first). sift, checks and "
                             "recalibrations always match them whole")


def _alignment(args) -> tuple[dict, dict]:
    """(list_image_folder's alignment arguments, the estimated offsets' record for
    quality.input when --time-offset auto found them)."""
    record = {}
    if args.time_offset == ["auto"]:
        offsets, record = _estimated_clock_offsets(args)
    else:
        offsets = parse_time_offsets(args.time_offset)
    return ({"align": args.align, "time_offsets_s": offsets,
             "max_time_gap_s": _max_time_gap_s(args)}, record)


def _max_time_gap_s(args) -> float:
    return DEFAULT_MAX_TIME_GAP_S if args.max_time_gap is None else args.max_time_gap


def _estimated_clock_offsets(args) -> tuple[dict, dict]:
    """--align time --time-offset auto: ({camera: clock offset s}, its record) from the capture
    times (core.io.clock_offsets)."""
    from ..core.io.clock_offsets import estimate_clock_offsets
    from ..core.io.image_io import capture_times_by_camera

    estimates = estimate_clock_offsets(capture_times_by_camera(args.images), _max_time_gap_s(args))
    offsets = {name: round(est.offset_s, 3) for name, est in estimates.items()}
    log.info("clock offsets from the capture times (s, from %s): %s", next(iter(offsets)),
             ", ".join(f"{n}={o:+.2f} ({estimates[n].paired_shots} shots paired)"
                       for n, o in offsets.items()))
    return offsets, {"time_offsets_estimated": {
        name: {"offset_s": offsets[name], "paired_shots": est.paired_shots}
        for name, est in estimates.items()}}


def _frame_sets(args, default: int) -> int:
    if args.max_frame_sets is None:
        return default
    if args.max_frame_sets < 1:
        raise InputError(f"--max-frame-sets {args.max_frame_sets}: give at least 1.")
    return args.max_frame_sets


def read_input(args) -> tuple[list, list[str], dict, list]:
    """(frame_sets, camera names, the input's record for quality.input, image paths per set
    (--images only, else []))."""
    _check_input_options(args)
    if args.videos:
        if args.topics:
            raise InputError("--topics belongs to --bag; with --videos the camera names come "
                             "from the video file names.")
        from ..core.io.video_io import read_video_frame_sets
        record = {}
        if args.time_offset == ["auto"]:
            from ..core.io.motion_sync import estimate_video_offsets
            from ..core.io.video_io import list_video_folder
            offsets, record = _motion_offsets(
                estimate_video_offsets(*list_video_folder(args.videos)), "videos")
        else:
            offsets = parse_time_offsets(args.time_offset)
        frame_sets, names, times_s = read_video_frame_sets(
            args.videos, _frame_sets(args, DEFAULT_VIDEO_FRAME_SETS), offsets, args.start,
            args.end)
        log.info("video frame sets at %s s", ", ".join(f"{t:.2f}" for t in times_s))
        return frame_sets, names, {
            "source": "videos", "path": str(Path(args.videos).resolve()),
            "time_offsets_s": offsets, **record, "frame_set_times_s": times_s}, []
    if args.images:
        if args.topics:
            raise InputError("--topics belongs to --bag; with --images the camera names come "
                             "from the file or folder names.")
        from ..core.io.image_io import list_image_folder, read_image_files
        alignment, record = _alignment(args)
        paths, names = list_image_folder(args.images, **alignment, without=args.without)
        paths = evenly_spaced(paths, _frame_sets(args, DEFAULT_MAX_FRAME_SETS))
        root = Path(args.images)  # the listed paths are under it (symlinks not followed)
        if alignment["time_offsets_s"]:
            record = {"time_offsets_s": alignment["time_offsets_s"], **record}
        return read_image_files(paths, names), names, {
            "source": "images", "path": str(root.resolve()), **record,
            "frame_sets": [[str(p.relative_to(root)) for p in row] for row in paths]}, paths
    if not args.topics:
        raise InputError("--bag needs --topics: the image topic of every camera, e.g. "
                         "--topics /cam0/image_raw /cam1/image_raw.")
    from ..core.io.bag import camera_names_from_topics, read_frame_sets
    names = camera_names_from_topics(args.topics)
    record = {}
    if args.time_offset == ["auto"]:
        from ..core.io.motion_sync import bag_offsets
        offsets, record = _motion_offsets(bag_offsets(args.bag, args.topics, names), "topics")
    else:
        offsets = parse_time_offsets(args.time_offset)
        unknown = sorted(set(offsets) - set(names))
        if unknown:
            raise InputError(f"--time-offset names unknown camera(s) {', '.join(unknown)}: the "
                             f"bag's cameras are {', '.join(names)} (from --topics).")
    frame_sets, names, stamps = read_frame_sets(
        args.bag, args.topics, slop_s=DEFAULT_SLOP_S if args.slop is None else args.slop,
        max_frame_sets=_frame_sets(args, DEFAULT_MAX_FRAME_SETS), return_stamps=True,
        stamp_offsets_s=[float(offsets.get(n, 0.0)) for n in names])
    # a topic that switched resolution part-way: refused here for every command (check and
    # overlay would otherwise judge the camera moved); folders and videos cannot change it
    camera_sizes(frame_sets, names)
    if offsets:
        record = {"time_offsets_s": offsets, **record}
    return frame_sets, names, {"source": "bag", "path": str(Path(args.bag).resolve()),
                               "topics": list(args.topics), **record,
                               "frame_set_stamps_ns": stamps}, []


def _check_input_options(args) -> None:
    """InputError for an option given with an input it does not belong to, or out of range."""
    video_only = [opt for opt, value in (("--start", args.start), ("--end", args.end))
                  if value is not None]
    if video_only and not args.videos:
        raise InputError(f"{', '.join(video_only)} belong(s) to --videos.")
    for option, value in (("--start", args.start), ("--end", args.end)):
        if value is not None and not np.isfinite(value):
            raise InputError(f"{option} {value:g}: give a time in seconds from the videos' "
                             "start.")
    if args.time_offset and not (args.videos or args.bag or
                                 (args.images and args.align == "time")):
        raise InputError("--time-offset belongs to --videos, --bag or --images with --align "
                         "time.")
    if args.time_offset and "auto" in args.time_offset and args.time_offset != ["auto"]:
        raise InputError(f"--time-offset {' '.join(args.time_offset)}: give `auto` alone or "
                         "NAME=S values, not both.")
    if args.align != "auto" and not args.images:
        raise InputError("--align belongs to --images (camera subfolders).")
    if args.without and not args.images:
        raise InputError("--without belongs to --images; with --bag list only the topics to "
                         "use, with --videos move the video out of the folder.")
    if args.slop is not None and not args.bag:
        raise InputError("--slop belongs to --bag (how far apart the stamps of a frame set may "
                         "be); with --images use --align time --max-time-gap.")
    if args.max_time_gap is not None and not (args.images and args.align == "time"):
        raise InputError("--max-time-gap belongs to --images with --align time (EXIF capture "
                         "times); with --bag use --slop.")
    for option, value in (("--slop", args.slop), ("--max-time-gap", args.max_time_gap)):
        if value is not None and not (np.isfinite(value) and value >= 0):
            raise InputError(f"{option} {value:g}: give a time in seconds, 0 or more.")


def _motion_offsets(estimates: dict, what: str) -> tuple[dict, dict]:
    """({camera: offset s}, the record for quality.input) of core.io.motion_sync estimates."""
    offsets = {name: round(est.offset_s, 4) for name, est in estimates.items()}
    log.info("time offsets from the %s' motion (s, from %s): %s", what, next(iter(offsets)),
             ", ".join(f"{n}={o:+.3f}" for n, o in offsets.items()))
    return offsets, {"time_offsets_estimated": {
        name: {"offset_s": offsets[name], "correlation": round(est.correlation, 3)}
        for name, est in estimates.items()}}


def named_numbers(values: Optional[list[str]], option: str, expected: str,
                   unnamed: Optional[str] = None) -> dict:
    """`option` values NAME=NUMBER (or a bare NUMBER, kept under `unnamed` when given) ->
    {name: float}; InputError saying what was `expected` on a malformed value."""
    out = {}
    for value in values or []:
        name, _, number = value.rpartition("=")
        try:
            x = float(number)
        except ValueError:
            x = float("nan")
        if not np.isfinite(x) or not (name or unnamed):
            raise InputError(f"{option} {value!r}: expected {expected}.")
        out[name or unnamed] = x
    return out


def parse_time_offsets(values: Optional[list[str]]) -> dict:
    """--time-offset values -> {camera name: seconds}; InputError on a malformed value."""
    return named_numbers(values, "--time-offset", "NAME=SECONDS (cam1=0.4)")


# Input options only calibrate (and check) use: the masks of what is not scene, for matching.
CALIBRATE_ONLY = (("mask", "--mask"), ("keep_info_strips", "--keep-info-strips"),
                  ("match_whole_frames", "--match-whole-frames"))


def refuse_calibrate_only(args, why: str) -> None:
    """InputError naming the first of CALIBRATE_ONLY given to a command that does not match
    (`why` says what it does instead), rather than ignoring it unsaid."""
    for attr, option in CALIBRATE_ONLY:
        if getattr(args, attr, None):
            raise InputError(f"{option} belongs to calibrate; {why}.")


def parse_masks(values: Optional[list[str]], names: list[str]) -> dict:
    """--mask values -> {camera name: ignored pixels}: NAME=PATH for one camera (NAME one of
    `names`; a path may itself hold '='), a bare PATH for every camera."""
    from ..core.method.masks import read_mask

    out = {}
    for value in values or []:
        name, sep, path = split_named(value, names)
        if sep and name in names:
            out[name] = read_mask(path)
        elif sep and not Path(value).exists():
            raise InputError(f"--mask {value}: there is no camera {name!r} (the cameras are "
                             f"{', '.join(names)}), nor a file {value}.")
        else:
            mask = read_mask(value)
            out.update({n: mask for n in names if n not in out})
    return out


def topics_from_calibration(args, rig) -> None:
    """--bag without --topics for a command that holds a bag against a calibration: the image
    topics the calibration was made from, when it recorded them (a bag or the node)."""
    if not args.bag or args.topics:
        return
    from ..core.products.interchange import recorded_image_topics

    recorded = recorded_image_topics(rig)
    if recorded:
        args.topics = list(recorded.values())
        log.info("image topics as the calibration recorded them: %s", " ".join(args.topics))


def require_calibrated_cameras(rig, names: list[str], frame_set: list, at_least: int) -> None:
    """InputError unless at least `at_least` of the input's cameras are in the calibration `rig`,
    each with images of its calibrated size (a command that holds images against a calibration);
    the input's cameras the calibration lacks are named in a warning."""
    known = [n for n in names if n in rig.cameras]
    if len(known) < at_least:
        raise InputError(f"The images are of {', '.join(names)}; the calibration has "
                         f"{', '.join(rig.cameras)}: at least {at_least} must be in both.")
    unknown = [n for n in names if n not in rig.cameras]
    if unknown:  # a verdict that leaves a camera out says so
        log.warning("not in the calibration, so not judged: %s (its cameras: %s)",
                    ", ".join(unknown), ", ".join(rig.cameras))
    for name, image in zip(names, frame_set):
        if name in rig.cameras:
            intr = rig.cameras[name].intrinsics
            if (image.shape[1], image.shape[0]) != (intr.width, intr.height):
                raise InputError(f"Camera {name}'s images are {image.shape[1]}x{image.shape[0]}; "
                                 f"it was calibrated at {intr.width}x{intr.height}: give the "
                                 "images it was calibrated on, at their size.")
