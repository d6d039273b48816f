"""`densecalib export`: write a calibration on disk in another tool's format (anipose's
calibration.toml, Kalibr's camchain.yaml, OpenCV FileStorage files; core.interchange)."""
from __future__ import annotations

import argparse
import logging
from pathlib import Path

from ..core.errors import InputError
from ..core.export import read_calibration, write_text_atomic
from ..core.interchange import (DEFAULT_TOPIC_PATTERN, FOLDER_FORMATS, FORMATS, export_text,
                                opencv_files)

log = logging.getLogger("densecalib.export")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("calibration", metavar="CALIBRATION",
                        help="a calibration folder (as `densecalib calibrate` writes it), a node's "
                             "output_dir (its latest calibration) or a calibration.json")
    parser.add_argument("--format", required=True, choices=FORMATS,
                        help="anipose: aniposelib calibration.toml; kalibr: Kalibr camchain.yaml; "
                             "opencv: one OpenCV FileStorage <camera>.yml per camera "
                             "(camera_matrix, distortion_coefficients, image size, "
                             "fisheye_model, R and T of cam_from_rig)")
    parser.add_argument("--out", required=True, metavar="FILE|DIR",
                        help="file to write (replaced); opencv: the folder for the files")
    parser.add_argument("--topic-pattern", default=DEFAULT_TOPIC_PATTERN, metavar="PATTERN",
                        help="kalibr: each camera's rostopic, {name} = camera name "
                             f"(default {DEFAULT_TOPIC_PATTERN})")


def run(args: argparse.Namespace) -> int:
    try:
        rig = read_calibration(args.calibration)
        options = {"topic_pattern": args.topic_pattern} if args.format == "kalibr" else {}
        if args.format in FOLDER_FORMATS:
            files = opencv_files(rig)
            if Path(args.out).is_file():
                raise InputError(f"{args.out} is a file; --format {args.format} writes one file "
                                 "per camera into a folder: give a folder.")
        else:
            files = {None: export_text(rig, args.format, **options)}
    except InputError as exc:
        log.error("%s", exc)
        return 2
    for name, text in files.items():  # name None: the one file of a single-file format
        write_text_atomic(args.out if name is None else Path(args.out) / name, text)
    listed = ", ".join(name for name in files if name)
    print(f"wrote {args.out} ({args.format}, {len(rig.cameras)} cameras"
          f"{': ' + listed if listed else ''})")
    return 0
