"""`densecalib export`: write a calibration on disk in another tool's format (anipose's
calibration.toml, Kalibr's camchain.yaml; core.interchange)."""
from __future__ import annotations

import argparse
import logging

from ..core.errors import InputError
from ..core.export import read_calibration, write_text_atomic
from ..core.interchange import DEFAULT_TOPIC_PATTERN, FORMATS, export_text

log = logging.getLogger("densecalib.export")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("calibration", metavar="CALIBRATION",
                        help="a calibration folder (as `densecalib calibrate` writes it), a node's "
                             "output_dir (its latest calibration) or a calibration.json")
    parser.add_argument("--format", required=True, choices=FORMATS,
                        help="anipose: aniposelib calibration.toml; kalibr: Kalibr camchain.yaml")
    parser.add_argument("--out", required=True, metavar="FILE", help="file to write (replaced)")
    parser.add_argument("--topic-pattern", default=DEFAULT_TOPIC_PATTERN, metavar="PATTERN",
                        help="kalibr: each camera's rostopic, {name} = camera name "
                             f"(default {DEFAULT_TOPIC_PATTERN})")


def run(args: argparse.Namespace) -> int:
    try:
        rig = read_calibration(args.calibration)
        options = {"topic_pattern": args.topic_pattern} if args.format == "kalibr" else {}
        text = export_text(rig, args.format, **options)
    except InputError as exc:
        log.error("%s", exc)
        return 2
    write_text_atomic(args.out, text)
    print(f"wrote {args.out} ({args.format}, {len(rig.cameras)} cameras)")
    return 0
