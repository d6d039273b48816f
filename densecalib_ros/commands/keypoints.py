"""`densecalib keypoints`: person keypoints in every camera's frames (core.method.person_keypoints:
BlazePose's 33 body landmarks per person), read as calibrate reads its input (commands.inputs),
written as OpenPose JSON, the format OpenPose and Pose2Sim write and `calibrate --keypoints` reads:

    KP_DIR/<camera>/<camera>_<12-digit frame number>_keypoints.json
        {"version": 1.3, "people": [{"person_id": [-1], "pose_keypoints_2d": [x, y, c, ...], ...}]}
    KP_DIR/keypoints_source.yaml   what was read, the landmark names, the frame numbers

x, y: OpenCV pixels of the original image ((0, 0) = the top-left pixel's centre); c: the
landmark's score; a landmark outside the image is 0, 0, 0 (OpenPose's "not found"). The frame
number is, with --videos, the frame's index in its camera's video, as OpenPose numbers a video's
frames (cameras that started apart: the same --time-offset given to calibrate pairs them); with
--images and --bag, the frame set's position among the sets read, the same in every camera. The
source file is not JSON, so that KP_DIR reads as one folder per camera.
"""
from __future__ import annotations

import argparse
import logging
import time
from pathlib import Path

import numpy as np

from ..core.errors import InputError
from ..core.json_text import json_text, jsonable
from ..core.method.person_keypoints import (DEFAULT_MAX_PERSONS, DEFAULT_MIN_DETECTION_SCORE,
                                            DEFAULT_MIN_POSE_PRESENCE, LANDMARK_NAMES,
                                            PersonKeypointDetector, PersonKeypointOptions)
from .inputs import add_input_arguments, read_input, refuse_calibrate_only

log = logging.getLogger("densecalib.keypoints")

# The file by which a later run knows KP_DIR as this command's own output (safe to replace).
SOURCE_FILE = "keypoints_source.yaml"
# OpenPose's JSON version field (its 1.3+ layout: people[].pose_keypoints_2d and the rest).
OPENPOSE_JSON_VERSION = 1.3


def add_arguments(parser: argparse.ArgumentParser) -> None:
    add_input_arguments(parser)
    parser.add_argument("--out", required=True, metavar="KP_DIR",
                        help="folder to write: <camera>/<camera>_<frame>_keypoints.json "
                             f"(OpenPose JSON) and {SOURCE_FILE}")
    parser.add_argument("--max-persons", type=int, default=DEFAULT_MAX_PERSONS, metavar="N",
                        help=f"most persons per image, best first (default "
                             f"{DEFAULT_MAX_PERSONS})")
    parser.add_argument("--min-detection-score", type=float,
                        default=DEFAULT_MIN_DETECTION_SCORE, metavar="S",
                        help="the person detector's threshold in [0, 1) (default "
                             f"{DEFAULT_MIN_DETECTION_SCORE:g}, MediaPipe's)")
    parser.add_argument("--min-pose-presence", type=float, default=DEFAULT_MIN_POSE_PRESENCE,
                        metavar="S", help="the landmark model's body-present threshold in "
                                          f"[0, 1) (default {DEFAULT_MIN_POSE_PRESENCE:g})")
    parser.add_argument("--detector-model", metavar="PATH",
                        help="pose_detection.tflite (default: the installed mediapipe "
                             "0.10.21 wheel's)")
    parser.add_argument("--landmark-model", metavar="PATH",
                        help="pose_landmark_full.tflite (default: the installed mediapipe "
                             "0.10.21 wheel's)")
    parser.add_argument("--threads", type=int, default=None, metavar="N",
                        help="the models' CPU threads (default: the runtime's choice)")


def run(args: argparse.Namespace) -> int:
    from ..core.io.safe_write import check_output_folder, replace_directory_atomic
    from .interrupts import finishing_write

    inputs = [p for p in (args.images, args.videos, args.bag) if p]
    try:
        _check_options(args)
        check_output_folder(args.out, [SOURCE_FILE], inputs)  # before the frames are read
        detector = PersonKeypointDetector(PersonKeypointOptions(
            detector_model=args.detector_model, landmark_model=args.landmark_model,
            max_persons=args.max_persons, min_detection_score=args.min_detection_score,
            min_pose_presence=args.min_pose_presence, num_threads=args.threads)).load()
        frame_sets, names, record, _ = read_input(args)
        numbers = frame_numbers(args, names, record, len(frame_sets))
        persons, seconds = detect_frame_sets(detector, frame_sets, names)
        source = {"model": "BlazePose (pose_detection + pose_landmark_full, mediapipe 0.10.21)",
                  "keypoints": list(LANDMARK_NAMES), "cameras": names, "input": record,
                  "frame_numbers": numbers, "seconds_per_image": seconds}
        replace_directory_atomic(lambda tmp: write_openpose_folder(
            tmp, names, numbers, persons, source), args.out, [SOURCE_FILE], inputs,
            commit_guard=finishing_write)
    except InputError as exc:
        log.error("%s", exc)
        return 2
    found = sum(len(p) > 0 for row in persons for p in row)
    log.info("wrote %s: %d frame sets x %d cameras, a person in %d of %d images, %.0f ms per "
             "image", args.out, len(frame_sets), len(names), found, len(frame_sets) * len(names),
             1000 * seconds)
    return 0


def _check_options(args: argparse.Namespace) -> None:
    """InputError naming the option that is out of range or belongs to calibrate."""
    refuse_calibrate_only(args, "keypoints are found in the whole images")
    if args.max_persons < 1:
        raise InputError(f"--max-persons {args.max_persons}: give at least 1.")
    for option, value in (("--min-detection-score", args.min_detection_score),
                          ("--min-pose-presence", args.min_pose_presence)):
        if not 0.0 <= value < 1.0:
            raise InputError(f"{option} {value:g}: give a score from 0 up to (not including) 1.")
    if args.threads is not None and args.threads < 1:
        raise InputError(f"--threads {args.threads}: give at least 1.")


def frame_numbers(args: argparse.Namespace, names: list[str], record: dict, count: int
                  ) -> dict[str, list[int]]:
    """{camera: the file number of each frame set} (module docstring)."""
    if not args.videos:
        return {name: list(range(count)) for name in names}
    from ..core.io.video_io import list_video_folder, probe_video

    paths, listed = list_video_folder(args.videos)
    offsets = record.get("time_offsets_s") or {}
    out = {}
    for path, name in zip(paths, listed):
        info = probe_video(path)
        # the frame read_video_frame_sets reads at each set's time
        out[name] = [int(np.clip(np.floor((t + float(offsets.get(name, 0.0))) * info.fps), 0,
                                 info.num_frames - 1)) for t in record["frame_set_times_s"]]
    return {name: out[name] for name in names}


def detect_frame_sets(detector: PersonKeypointDetector, frame_sets: list, names: list[str]
                      ) -> tuple[list[list[list[np.ndarray]]], float]:
    """(persons[t][c] = the (33, 3) arrays of frame set t's camera c, seconds per image)."""
    persons, start = [], time.perf_counter()
    for t, frame_set in enumerate(frame_sets):
        persons.append([detector.detect(image) for image in frame_set])
        log.info("frame set %d/%d: persons per camera %s", t + 1, len(frame_sets),
                 " ".join(f"{n}={len(p)}" for n, p in zip(names, persons[-1])))
    images = max(1, sum(len(s) for s in frame_sets))
    return persons, (time.perf_counter() - start) / images


def openpose_json(persons: list[np.ndarray]) -> str:
    """OpenPose's per-image JSON of `persons` ((K, 3) x, y, score each; score 0 -> 0, 0, 0)."""
    people = []
    for points in persons:
        values = np.where(points[:, 2:3] > 0, points, 0.0)
        people.append({"person_id": [-1],
                       "pose_keypoints_2d": [round(float(v), 3) for v in values.ravel()],
                       "face_keypoints_2d": [], "hand_left_keypoints_2d": [],
                       "hand_right_keypoints_2d": [], "pose_keypoints_3d": [],
                       "face_keypoints_3d": [], "hand_left_keypoints_3d": [],
                       "hand_right_keypoints_3d": []})
    return json_text({"version": OPENPOSE_JSON_VERSION, "people": people}, indent=None)


def openpose_file_name(camera: str, number: int) -> str:
    return f"{camera}_{number:012d}_keypoints.json"


def write_openpose_folder(folder: Path, names: list[str], numbers: dict[str, list[int]],
                          persons: list, source: dict) -> None:
    """folder/<camera>/<camera>_<number>_keypoints.json for every frame set and camera, and
    folder/SOURCE_FILE."""
    import yaml

    folder = Path(folder)
    for c, name in enumerate(names):
        (folder / name).mkdir(parents=True, exist_ok=True)
        for number, row in zip(numbers[name], persons):
            (folder / name / openpose_file_name(name, number)).write_text(openpose_json(row[c]))
    (folder / SOURCE_FILE).write_text(yaml.safe_dump(jsonable(source), sort_keys=False))
