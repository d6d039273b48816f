"""`densecalib calibrate`: calibrate a rig from a folder of images or videos or a rosbag2 bag.

Writes OUT/calibration.json, OUT/<camera>.yaml (ROS camera_info) and OUT/colmap/ (COLMAP model),
all or nothing: OUT is replaced only when the calibration succeeded. Progress goes to stderr
(logging), a per-camera summary to stdout. Exit status: 0 success, 1 calibration failed (the
message says what to do), 2 unusable input or options.
"""
from __future__ import annotations

import argparse
import logging
from typing import Optional

from ..core.config import DEFAULT_PIPELINE, LENS_MODELS, PIPELINES, PRESETS, make_config
from ..core.errors import CalibrationError, InputError
from ..core.method.matching import available_matchers
from ..core.products.report import camera_table, intrinsics_note
from ..core.products.scale import MAX_LENGTH_M, MIN_LENGTH_M
from .argtypes import number_in, positive, seed
from .inputs import add_input_arguments, named_numbers, parse_masks, read_input
from .keypoint_inputs import (add_keypoint_arguments, keypoint_cameras, keypoint_paths,
                              read_keypoint_input)

log = logging.getLogger("densecalib.calibrate")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_input_arguments(parser, required=False)  # or --keypoints alone
    add_keypoint_arguments(parser)
    parser.add_argument("--out", required=True, metavar="OUT",
                        help="output folder: new, empty or an earlier calibration (replaced)")
    parser.add_argument("--preset", choices=PRESETS, default="regular",
                        help="camera type: regular (RADIAL) or fisheye (OPENCV_FISHEYE)")
    parser.add_argument("--pipeline", choices=PIPELINES, default=DEFAULT_PIPELINE,
                        help=f"SfM pipeline (default: {DEFAULT_PIPELINE}; see docs/method.md)")
    parser.add_argument("--matcher", default=None,
                        help="matcher backend (default: the preset's, sift)")
    parser.add_argument("--second-matcher", default="asift",
                        choices=[*available_matchers(), "none"],
                        help="where perspective cameras matched with sift come out undetermined "
                             "(a camera not registered, runs that disagree, focal lengths "
                             "looser than 1 %% where the cameras do not all look one way), match "
                             "again with this one and keep the better-determined calibration "
                             "(default asift; none: keep sift's)")
    parser.add_argument("--max-side", type=number_in(64, integer=True), default=None, metavar="PX",
                        help="match images at most at this size (default 1024)")
    _add_camera_arguments(parser)
    parser.add_argument("--consensus-runs", type=positive(integer=True), default=5, metavar="N",
                        help="sample + SfM up to N times with different seeds and keep the run "
                             "that fits all keypoint matches best (default 5; it stops after 2 runs "
                             "that agree, 1 where its focal starts all agree and it registered "
                             "every camera; 1 = a single run)")
    parser.add_argument("--previous", metavar="PATH", default=None,
                        help="a previous calibration of these cameras (folder, a node output_dir, "
                             "or calibration.json): start from it, report what changed, and "
                             "refuse a worse result")
    parser.add_argument("--keep-intrinsics", action="store_true",
                        help="with --previous: keep its intrinsics and calibrate the extrinsics "
                             "only (mounts bumped, lenses untouched; not after a refocus or zoom)")
    parser.add_argument("--known-baseline", nargs=3, default=None,
                        metavar=("CAM_A", "CAM_B", "METRES"),
                        help="metric scale: the distance between the optical centres of two "
                             "cameras, e.g. --known-baseline cam0 cam1 0.42 (SfM alone gives the "
                             "rig up to scale). With --previous, a metric previous calibration's "
                             "baseline is used when this is not given")
    parser.add_argument("--floor", nargs="?", const="upright", choices=("upright", "top"),
                        help="find the floor in the scene points and record the floor frame "
                             "(z up, heights above the floor; anipose export uses it as world). "
                             "The cameras are upright (image up = world up; the default), or "
                             "`top`: they all look straight down onto the floor")
    parser.add_argument("--seed", type=seed, default=0, help="random seed of the sampling")
    parser.add_argument("--jobs", "--threads", dest="jobs", type=number_in(-1, integer=True),
                        default=-1, help="cores to use (-1 = all this process may run on): the "
                        "SfM's trials run side by side in worker processes; the rig is the same "
                        "with any number")


def _add_camera_arguments(parser: argparse.ArgumentParser) -> None:
    """What the user knows of the cameras: lenses, units, focal lengths, intrinsics, EXIF."""
    parser.add_argument("--lens", nargs="+", default=None, metavar="NAME=LENS",
                        help="cameras whose lens differs from the preset's, for a rig mixing "
                             "lenses: --lens cam3=fisheye (or NAME=pinhole under --preset "
                             "fisheye); each camera is then calibrated with its lens's model")
    parser.add_argument("--share-intrinsics", action="store_true",
                        help="one set of intrinsics for cameras of the same image size: use it "
                             "when the cameras are identical units (same model, lens and zoom)")
    parser.add_argument("--separate-intrinsics", action="store_true",
                        help="the cameras are of different models: never calibrate them as units "
                             "of one model (tried, where they could be, when the calibration "
                             "runs disagree)")
    parser.add_argument("--focal-px", nargs="+", default=None, metavar="PX|NAME=PX",
                        help="known focal lengths in pixels, one for all cameras (--focal-px 800) "
                             "or per camera (--focal-px cam0=800 cam1=760): the calibration "
                             "starts from them instead of estimating them, and still refines "
                             "them. From a datasheet: focal_mm / pixel_pitch_mm, or "
                             "(width / 2) / tan(horizontal_fov / 2)")
    parser.add_argument("--intrinsics", nargs="+", default=None, metavar="PATH|NAME=PATH",
                        help="intrinsics to keep, for cameras calibrated before (in the lab with "
                             "a target, or a previous calibration whose lenses were not touched): "
                             "ROS camera_info YAML files (camera = the file's camera_name, or "
                             "NAME=PATH), a folder of them, a densecalib calibration, an anipose "
                             "calibration.toml, a Kalibr camchain or an OpenCV calibration "
                             "file (a stereo file's two cameras named in order: "
                             "left,right=PATH); those "
                             "cameras keep them exactly and only the extrinsics (and the other "
                             "cameras' intrinsics) are calibrated")
    parser.add_argument("--bag-camera-info", action="store_true",
                        help="with --bag: keep the intrinsics the bag's CameraInfo topics carry "
                             "(<image topic namespace>/camera_info, first message), like "
                             "--intrinsics for every camera")
    parser.add_argument("--ignore-exif", action="store_true",
                        help="do not start from the focal lengths in the images' EXIF (use it "
                             "when the images were cropped, or taken with digital zoom)")


def _exif_focals(paths, frame_sets, names) -> dict:
    """{camera: focal px} from the EXIF of the images used (core.io.exif), logged."""
    from ..core.io.exif import camera_exif_focals

    sizes = [(int(im.shape[1]), int(im.shape[0])) for im in frame_sets[0]]
    focals = camera_exif_focals(paths, names, sizes)
    if focals:
        log.info("EXIF focal lengths (a start; --ignore-exif to skip them): %s", ", ".join(
            f"{n}={f:.0f} px" for n, f in focals.items()))
    return focals


def parse_focal_px(values: Optional[list[str]]) -> dict:
    """--focal-px values -> {camera name or '*': px}; InputError on a malformed value."""
    return named_numbers(values, "--focal-px", "a number of pixels (800) or NAME=PX (cam0=800)",
                         unnamed="*")


def parse_camera_lens(values: Optional[list[str]]) -> dict:
    """--lens values -> {camera name: lens}; InputError on a malformed value."""
    out = {}
    for value in values or []:
        name, _, lens = value.rpartition("=")
        if not name or lens not in LENS_MODELS:
            raise InputError(f"--lens {value!r}: expected NAME=LENS with LENS "
                             f"{' or '.join(LENS_MODELS)} (e.g. --lens cam3=fisheye).")
        out[name] = lens
    return out


def parse_known_baseline(values: Optional[list[str]], names: list[str]) -> Optional[tuple]:
    """--known-baseline CAM_A CAM_B METRES -> (cam_a, cam_b, metres) or None; InputError when the
    cameras are not two different ones of `names` or the distance is not a length scale.py
    takes (checked before the calibration runs, not after it)."""
    if not values:
        return None
    cam_a, cam_b, metres = values
    try:
        baseline_m = float(metres)
    except ValueError:
        baseline_m = float("nan")
    if cam_a == cam_b or cam_a not in names or cam_b not in names or \
            not MIN_LENGTH_M <= baseline_m <= MAX_LENGTH_M:
        raise InputError(f"--known-baseline {' '.join(values)}: expected two different cameras "
                         f"of {', '.join(names)} and their distance in metres ({MIN_LENGTH_M:g} "
                         f"to {MAX_LENGTH_M:g}), e.g. --known-baseline {names[0]} {names[-1]} "
                         "0.5.")
    return cam_a, cam_b, baseline_m


def _bag_intrinsics(args: argparse.Namespace, names: list[str], given: dict) -> dict:
    """`given` plus the intrinsics of the bag's CameraInfo topics (--bag-camera-info)."""
    from ..core.io.bag import camera_info_topic, read_camera_infos
    from ..core.method.known_intrinsics import intrinsics_from_camera_info

    twice = sorted(set(given) & set(names))
    if twice:
        raise InputError(f"Intrinsics of {', '.join(twice)} given twice (by --intrinsics or "
                         "--keep-intrinsics, and by --bag-camera-info): give each camera once.")
    infos = read_camera_infos(args.bag, args.topics)
    return {**given, **{name: intrinsics_from_camera_info(info, camera_info_topic(topic))
                        for name, topic, info in zip(names, args.topics, infos)}}


def run(args: argparse.Namespace) -> int:
    from ..core.io.export import CALIBRATION_MARKERS, calibration_entries, write_calibration_files
    from ..core.io.safe_write import check_output_folder, replace_directory_atomic
    from ..core.job import run_job
    from .interrupts import finishing_write, stopping_calibration
    from .progress_line import terminal_progress

    inputs = [p for p in (args.images, args.videos, args.bag) if p] + keypoint_paths(args)
    try:
        check_output_folder(args.out, CALIBRATION_MARKERS, inputs)  # before minutes of work
        with terminal_progress(getattr(args, "verbose", False)) as progress:
            request = _request(args)
            with stopping_calibration(progress.stop):
                job = run_job(request, progress)
        replace_directory_atomic(lambda tmp: write_calibration_files(
            job.rig, tmp, job.calibration.reconstruction, reference_views=job.reference_views),
            args.out, CALIBRATION_MARKERS, inputs, owned=calibration_entries,
            commit_guard=finishing_write)
    except InputError as exc:
        log.error("%s", exc)
        return 2
    except CalibrationError as exc:
        log.error("Calibration failed: %s", exc)
        return 1
    _print_summary(job.rig, args.out)
    return 0


def _config(args: argparse.Namespace):
    """The configuration the options select (before the images are read)."""
    if args.keep_intrinsics and not args.previous:
        raise InputError("--keep-intrinsics keeps the intrinsics of the --previous calibration: "
                         "give --previous OLD_OUT, or the files with --intrinsics.")
    if args.share_intrinsics and args.separate_intrinsics:
        raise InputError("--share-intrinsics says the cameras are units of one model and "
                         "--separate-intrinsics that they differ: give one of them.")
    if args.bag_camera_info and not args.bag:
        raise InputError("--bag-camera-info reads the CameraInfo topics of a bag: use it with "
                         "--bag, or give camera_info YAML files with --intrinsics.")
    overrides = {"sampling__seed": args.seed, "sfm__num_threads": args.jobs,
                 "sfm__share_intrinsics": args.share_intrinsics,
                 "cameras__units_from_images": not args.separate_intrinsics,
                 "consensus_runs": args.consensus_runs,
                 "second_matcher": None if args.second_matcher == "none" else args.second_matcher,
                 "cameras__initial_focal_px": parse_focal_px(args.focal_px),
                 "cameras__lens": parse_camera_lens(args.lens),
                 "detect_info_strips": not args.keep_info_strips}
    if args.max_side is not None:
        overrides["max_image_side_px"] = args.max_side
    if args.match_whole_frames:
        overrides["new_content_matchers"] = ()
    return make_config(args.preset, args.pipeline, args.matcher, **overrides)


def _request(args: argparse.Namespace):
    """The calibration job the options and the input ask for (core.job)."""
    from ..core.io.export import read_calibration, reference_views_of
    from ..core.job import CalibrationRequest
    from ..core.method.known_intrinsics import read_known_intrinsics, with_previous_intrinsics

    config = _config(args)
    if args.images or args.videos or args.bag:
        frame_sets, names, source, paths = read_input(args)
    else:
        frame_sets, names, source, paths = [], keypoint_cameras(args), {"source": "keypoints"}, []
    keypoints = read_keypoint_input(args, names, frame_sets, source)
    if keypoints is not None:
        source = {**source, "keypoints": keypoints.record}
    previous = read_calibration(args.previous) if args.previous else None
    if previous is not None and not set(previous.cameras) & set(names):
        raise InputError(f"--previous {args.previous} calibrated the cameras "
                         f"{', '.join(previous.cameras)}; these images are of "
                         f"{', '.join(names)}: no camera is named as before. Name each camera's "
                         "images as before (file stems, folders, topics), or calibrate without "
                         "--previous.")
    known = read_known_intrinsics(args.intrinsics or [], names)
    if args.keep_intrinsics:
        known = with_previous_intrinsics(known, previous, names)
    if args.bag_camera_info:
        known = _bag_intrinsics(args, names, known)
    if known:
        log.info("intrinsics given and kept for %s", ", ".join(sorted(known)))
    exif = _exif_focals(paths, frame_sets, names) if args.images and not args.ignore_exif else {}
    config = config.with_options(cameras__known_intrinsics=known,
                                 cameras__masks=parse_masks(args.mask, names),
                                 cameras__exif_focal_px=exif)
    log.info("%d camera(s) (%s), %d frame set(s); preset %s%s, %s pipeline, matcher %s",
             len(names), ", ".join(names), len(frame_sets), config.preset,
             "".join(f", {n} {lens}" for n, lens in config.cameras.lens.items()),
             config.pipeline, config.matcher)
    return CalibrationRequest(
        frame_sets, names, config, source, previous=previous,
        previous_views=reference_views_of(args.previous, names) if previous else {},
        known_baseline=parse_known_baseline(args.known_baseline, names), floor=args.floor,
        floor_hint="add --floor, or run `densecalib floor` on the result (exports use the "
                   "floor frame as world)", keypoints=keypoints)


def _print_summary(rig, out: str) -> None:
    """The per-camera table and what the user needs to know of the result, on stdout."""
    print(camera_table(rig))
    note = intrinsics_note(rig)
    if note:
        print(note)
    if rig.failed_cameras:
        print("not registered: " + ", ".join(rig.failed_cameras))
    if rig.quality.change_summary is not None:
        print(f"{rig.quality.change_summary} (started {rig.quality.init})")
    print(f"reference camera {rig.reference_camera}; wrote {out}")
