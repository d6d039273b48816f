"""`densecalib floor`: find the floor of a calibration already written (core.products.floor) and
record it in its calibration.json, as `calibrate --floor` would have: no new calibration is needed
to add a floor frame, or to look for it again with `--view top`."""
from __future__ import annotations

import argparse
import logging

from ..core.errors import InputError
from ..core.io.export import (calibration_folder, node_reload_hint, read_calibration,
                              write_calibration_json)
from ..core.products.floor import VIEWS, find_floor_of_saved_calibration, set_floor
from ..core.products.report import format_floor

log = logging.getLogger("densecalib.floor")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("calibration", metavar="CALIBRATION",
                        help="a calibration folder (with the colmap/ model calibrate wrote beside "
                             "calibration.json) or a node's output_dir")
    parser.add_argument("--view", choices=VIEWS, default="upright",
                        help="upright (default): the cameras are mounted upright; top: they all "
                             "look straight down onto the floor")
    parser.add_argument("--dry-run", action="store_true",
                        help="print the floor found, leave calibration.json as it is")


def run(args: argparse.Namespace) -> int:
    folder = calibration_folder(args.calibration)
    try:
        rig = read_calibration(folder)
        floor = find_floor_of_saved_calibration(folder, rig, args.view)
    except InputError as exc:
        log.error("%s calibration.json is unchanged.", exc)
        return 2
    replaced = rig.quality.floor is not None
    set_floor(rig, floor)
    print(format_floor(rig))
    if args.dry_run:
        return 0
    path = write_calibration_json(rig, folder)
    log.info("%s the floor frame in %s; files exported from it before (anipose, stereo, ...) "
             "are unchanged: export them again%s", "replaced" if replaced else "recorded",
             path.resolve(), node_reload_hint(folder))
    return 0
