"""`densecalib scale`: give a written calibration its metric scale afterwards (core.products.scale),
from a known distance between two scene points or between two cameras; every length in it (camera
positions, the floor frame, the saved COLMAP model) is multiplied by one factor."""
from __future__ import annotations

import argparse
import logging

from ..core.errors import InputError
from ..core.io.export import (calibration_folder, node_reload_hint, read_calibration,
                              read_saved_model, write_calibration_json, write_colmap_model)
from ..core.io.safe_write import replace_directory_atomic
from ..core.products.scale import (apply_known_baseline, apply_known_distance,
                                   rig_units_per_model_unit, scale_reconstruction)
from ..core.products.triangulation import DEFAULT_PIXEL_SIGMA
from .triangulate import parse_observations

log = logging.getLogger("densecalib.scale")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("calibration", metavar="CALIBRATION",
                        help="a calibration folder or a node's output_dir")
    how = parser.add_mutually_exclusive_group(required=True)
    how.add_argument("--distance", type=float, metavar="METRES",
                     help="the measured distance between the two --point's")
    how.add_argument("--baseline", nargs=3, metavar=("CAM_A", "CAM_B", "METRES"),
                     help="the measured distance between two cameras' optical centres (as "
                          "calibrate --known-baseline)")
    parser.add_argument("--point", action="append", nargs="+", metavar="CAMERA=X,Y",
                        help="with --distance, twice: one end of the measured length, by its "
                             "pixel in each camera that sees it (at least two; OpenCV/ROS "
                             "pixels of the original images), e.g. --point cam0=512.5,300 "
                             "cam2=640,310.2")
    parser.add_argument("--pixel-sigma", type=float, default=None, metavar="PX",
                        help="assumed pixel error (1 sigma) for the scale's standard deviation "
                             f"(default {DEFAULT_PIXEL_SIGMA:g})")
    parser.add_argument("--dry-run", action="store_true",
                        help="print the scale found, leave the calibration as it is")


def _scaled(args, rig):
    if args.baseline:
        for option, given in (("--point", args.point), ("--pixel-sigma", args.pixel_sigma)):
            if given is not None:
                raise InputError(f"{option} goes with --distance (a length in the scene); "
                                 "--baseline names two cameras instead.")
        cam_a, cam_b, metres = args.baseline
        try:
            baseline_m = float(metres)
        except ValueError:
            raise InputError(f"--baseline {' '.join(args.baseline)}: the distance must be a "
                             "number of metres, e.g. --baseline cam0 cam1 0.5.") from None
        return apply_known_baseline(rig, cam_a, cam_b, baseline_m)
    if not args.point or len(args.point) != 2:
        raise InputError("--distance needs the two ends of the measured length: --point "
                         "CAM=X,Y CAM=X,Y ... twice.")
    pixel_sigma = DEFAULT_PIXEL_SIGMA if args.pixel_sigma is None else args.pixel_sigma
    if not pixel_sigma > 0:
        raise InputError(f"--pixel-sigma {pixel_sigma:g}: give a positive pixel error.")
    return apply_known_distance(rig, *(parse_observations(p) for p in args.point),
                                args.distance, pixel_sigma)


def run(args: argparse.Namespace) -> int:
    folder = calibration_folder(args.calibration)
    try:
        rig = read_calibration(folder)
        scaled = _scaled(args, rig)
    except InputError as exc:
        log.error("%s The calibration is unchanged.", exc)
        return 2
    record = scaled.quality.scale_from_points or scaled.quality.scale_from_baseline
    factor = record["factor"]
    sure = (f" (1 sigma {100 * record['relative_std']:.2g} %)" if "relative_std" in record
            else "")
    now = "would be" if args.dry_run else "are now"
    print(f"scale: x {factor:.6g}{sure}: the rig's lengths {now} metres"
          + ("" if not rig.metric_scale else
             f" (it was metric before: that scale {'would be' if args.dry_run else 'is'} "
             "replaced)") + ("; --dry-run: nothing written" if args.dry_run else ""))
    if args.dry_run:
        return 0
    reconstruction = read_saved_model(folder)
    # calibration.json first: it is the calibration. The model's unit is read against the rig's
    # (rig_units_per_model_unit) wherever densecalib uses it, so a model left in its old unit if
    # the second write fails is still read right; scaling it is for other tools.
    path = write_calibration_json(scaled, folder)
    if reconstruction is not None:
        scale_reconstruction(reconstruction, factor * rig_units_per_model_unit(reconstruction, rig))
        try:
            replace_directory_atomic(lambda tmp: write_colmap_model(reconstruction, tmp),
                                     folder / "colmap")
        except InputError as exc:
            log.warning("%s calibration.json is scaled; %s keeps its earlier unit (densecalib's "
                        "commands correct for it; for other tools run the scale again once the "
                        "folder is writable).", exc, folder / "colmap")
    log.info("wrote %s; files exported from it before (anipose, stereo, ...) keep the old scale: "
             "export them again%s", path.resolve(), node_reload_hint(folder))
    return 0
