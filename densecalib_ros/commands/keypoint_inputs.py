"""`densecalib calibrate --keypoints`: pose keypoints the user has (DeepLabCut, SLEAP, OpenPose /
RTMPose / Pose2Sim) as correspondences by identity (core.io.keypoints,
core.method.identity_tracks), beside the images, videos or bag, or alone."""
from __future__ import annotations

import argparse
import logging
from pathlib import Path
from typing import Optional

from ..core.errors import InputError
from ..core.method.identity_tracks import MIN_LIKELIHOOD
from ..core.named_values import split_named

log = logging.getLogger("densecalib.keypoints")


def add_keypoint_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--keypoints", nargs="+", default=None, metavar="PATH|NAME=PATH",
                        help="2D keypoints per camera as correspondences: DeepLabCut .h5/.csv, "
                             "SLEAP .slp/.analysis.h5, or a folder of OpenPose/RTMPose/Pose2Sim "
                             "JSON per camera; files named after the cameras (a DeepLabCut "
                             "file's video name), a folder of them, or NAME=PATH. Frame k of "
                             "every camera is one instant. With --images/--videos/--bag, or "
                             "alone (then --image-size where the files do not say it)")
    parser.add_argument("--keypoint-min-likelihood", type=float, default=None,
                        metavar="L", help="use keypoints the tool scored at least this "
                        f"(default {MIN_LIKELIHOOD:g}, DeepLabCut's pcutoff)")
    parser.add_argument("--keypoint-frame-offset", nargs="+", default=None,
                        metavar="NAME=FRAMES", help="a camera whose video started this many "
                        "frames before the others' (its frame k + FRAMES is their frame k); "
                        "with --videos, --time-offset gives it from each video's frame rate")
    parser.add_argument("--image-size", nargs="+", default=None, metavar="WxH|NAME=WxH",
                        help="with --keypoints alone: the cameras' image size in pixels, one "
                             "for all (1280x720) or per camera")


def keypoint_cameras(args: argparse.Namespace) -> list[str]:
    """The cameras --keypoints alone names, in the order given (a calibration without images)."""
    from ..core.io.keypoints import keypoint_sources

    if not args.keypoints:
        raise InputError("Give the images: --images DIR, --videos DIR or --bag BAG (or "
                         "--keypoints to calibrate from pose keypoints).")
    image_only = [option for option, given in (
        ("--topics", args.topics), ("--slop", args.slop is not None),
        ("--max-frame-sets", args.max_frame_sets is not None), ("--align", args.align != "auto"),
        ("--max-time-gap", args.max_time_gap is not None), ("--without", args.without),
        ("--time-offset", args.time_offset), ("--start", args.start is not None),
        ("--end", args.end is not None), ("--mask", args.mask)) if given]
    if image_only:
        raise InputError(f"{', '.join(image_only)} belong(s) to the images (--images, --videos or "
                         "--bag); with --keypoints alone, frames pair by number "
                         "(--keypoint-frame-offset NAME=FRAMES for a camera that started early).")
    return list(keypoint_sources(args.keypoints))


def read_keypoint_input(args: argparse.Namespace, names: list[str], frame_sets: list,
                        source: dict):
    """The --keypoints as core.method.identity_tracks.IdentityTracks for the cameras `names`
    (None without --keypoints); the image sizes are the frame sets', else --image-size's, else
    the files'."""
    from ..core.io.keypoints import keypoint_sources, read_keypoints
    from ..core.method.identity_tracks import identity_tracks

    given = [opt for opt, v in (("--keypoint-frame-offset", args.keypoint_frame_offset),
                                ("--image-size", args.image_size),
                                ("--keypoint-min-likelihood",
                                 args.keypoint_min_likelihood is not None)) if v]
    if not args.keypoints:
        if given:
            raise InputError(f"{', '.join(given)} belong(s) to --keypoints.")
        return None
    if args.image_size and frame_sets:
        raise InputError("--image-size is for --keypoints alone: with images, their size is "
                         "used.")
    min_likelihood = MIN_LIKELIHOOD if args.keypoint_min_likelihood is None \
        else args.keypoint_min_likelihood
    if not 0 <= min_likelihood <= 1:
        raise InputError(f"--keypoint-min-likelihood {min_likelihood:g}: give a likelihood "
                         "from 0 to 1.")
    files = keypoint_sources(args.keypoints, names)
    sizes = [(im.shape[1], im.shape[0]) for im in frame_sets[0]] if frame_sets else \
        parse_image_sizes(args.image_size, names)
    read = {}
    for name, path in files.items():
        read[name] = read_keypoints(path)
        log.info("keypoints of %s: %s (%s, %d frames)", name, path, read[name].tool,
                 len(read[name].frames))
    found = identity_tracks(read, names, sizes, min_likelihood,
                            _frame_offsets(args, names, source))
    log.info("%d keypoint tracks (joints seen by two or more cameras at likelihood >= %g) from "
             "%d frames", found.tracks.num_tracks, min_likelihood,
             found.record["frames_used"])
    return found


def parse_image_sizes(values: Optional[list[str]], names: list[str]) -> list:
    """--image-size values -> (width, height) or None per camera of `names`."""
    sizes: dict = {}
    for value in values or []:
        name, sep, size = split_named(value, names)
        width, x, height = (size if sep else value).lower().partition("x")
        if not (width.isdigit() and height.isdigit() and x) or (sep and name not in names):
            raise InputError(f"--image-size {value}: expected WIDTHxHEIGHT in pixels (1280x720) "
                             f"or NAME=WIDTHxHEIGHT with NAME one of {', '.join(names)}.")
        for n in ([name] if sep else names):
            sizes[n] = (int(width), int(height))
    return [sizes.get(n) for n in names]


def _frame_offsets(args: argparse.Namespace, names: list[str], source: dict) -> dict:
    """{camera: frames} from --keypoint-frame-offset, else from the videos' time offsets."""
    from .inputs import named_numbers

    given = named_numbers(args.keypoint_frame_offset, "--keypoint-frame-offset",
                          "NAME=FRAMES (cam1=12)")
    if any(v != int(v) for v in given.values()):
        raise InputError("--keypoint-frame-offset: give whole frames (cam1=12).")
    if given or not args.videos or not source.get("time_offsets_s"):
        return {n: int(v) for n, v in given.items()}
    from ..core.io.video_io import list_video_folder, probe_video

    paths, video_names = list_video_folder(args.videos)
    fps = {n: probe_video(p).fps for p, n in zip(paths, video_names)}
    offsets = {n: int(round(s * fps[n])) for n, s in source["time_offsets_s"].items() if n in fps}
    log.info("keypoint frame offsets from the videos' time offsets: %s", ", ".join(
        f"{n}={v:+d}" for n, v in offsets.items()))
    return offsets


def keypoint_paths(args: argparse.Namespace) -> list[str]:
    """The paths --keypoints reads (what the output folder must not replace)."""
    return [str(Path(split_named(v)[2] if not Path(v).exists() and "=" in v else v))
            for v in args.keypoints or []]
