"""`densecalib report`: what a calibration on disk says — intrinsics and fit per camera, the
camera layout, warnings — and, with --against, how it differs from another calibration of the
same cameras (a previous one, or a ground truth such as `densecalib generate`'s)."""
from __future__ import annotations

import argparse
import json
import logging
from dataclasses import asdict

from ..core.change import calibration_change, pose_agreement
from ..core.errors import InputError
from ..core.export import calibration_to_dict, read_calibration
from ..core.report import camera_centres_in_rig, rig_report

log = logging.getLogger("densecalib.report")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("calibration", metavar="CALIBRATION",
                        help="a calibration folder (as `densecalib calibrate` writes it), a node's "
                             "output_dir (its latest calibration) or a calibration.json")
    parser.add_argument("--against", metavar="OTHER",
                        help="another calibration of the same cameras (folder or JSON, e.g. the "
                             "previous one, or a ground_truth.json): report the change from it")
    parser.add_argument("--json", action="store_true",
                        help="print the report as JSON on stdout instead of text")


def run(args: argparse.Namespace) -> int:
    try:
        rig = read_calibration(args.calibration)
        against = read_calibration(args.against) if args.against else None
    except InputError as exc:
        log.error("%s", exc)
        return 2
    if not args.json:
        print(rig_report(rig, against, against_label=args.against or ""))
        return 0
    out = calibration_to_dict(rig)
    out["camera_centres_in_rig"] = {n: c.tolist() for n, c in camera_centres_in_rig(rig).items()}
    if against is not None:
        out["change"] = {n: asdict(c) for n, c in calibration_change(against, rig).items()}
        out["pose_agreement"] = pose_agreement(against, rig)
    print(json.dumps(out, indent=1))
    return 0
