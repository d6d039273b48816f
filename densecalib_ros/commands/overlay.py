"""`densecalib overlay`: draw each camera's reprojection residuals on its image
(core.products.overlay), from a calibration folder's COLMAP model, to see where the points are and
how well each lens model fits them."""
from __future__ import annotations

import argparse
import logging
from pathlib import Path

import cv2
import numpy as np

from ..core.errors import InputError
from ..core.io.export import (calibration_folder, check_output_files, read_calibration,
                              read_saved_model)
from .argtypes import positive
from .inputs import (add_input_arguments, read_input, refuse_calibrate_only,
                     require_calibrated_cameras, topics_from_calibration)

log = logging.getLogger("densecalib.overlay")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("calibration", metavar="CALIBRATION",
                        help="a calibration folder (as `densecalib calibrate` writes it) or a "
                             "node's output_dir (its latest calibration)")
    add_input_arguments(parser)  # as for calibrate; the first frame set is drawn on
    parser.add_argument("--out", required=True, metavar="DIR", help="folder for <camera>.png")
    parser.add_argument("--scale", type=positive(), default=10.0,
                        help="residual lines are drawn this many times their length (default 10)")


def run(args: argparse.Namespace) -> int:
    from ..core.products.overlay import camera_residuals, draw_residuals

    try:
        rig = read_calibration(args.calibration)
        folder = calibration_folder(args.calibration)
        rec = read_saved_model(folder)
        if rec is None:
            raise InputError(f"No COLMAP model in {folder}/colmap: overlay needs the folder that "
                             "`densecalib calibrate` (or the node) wrote, colmap/ included.")
        args.max_frame_sets = args.max_frame_sets or 1
        refuse_calibrate_only(args, "the residuals drawn are the calibration's own")
        topics_from_calibration(args, rig)
        frame_sets, names, _, _ = read_input(args)
        require_calibrated_cameras(rig, names, frame_sets[0], at_least=1)
        out = Path(args.out)
        if out.exists() and not out.is_dir():
            raise InputError(f"{args.out} is a file: give a folder for the <camera>.png images.")
        check_output_files([out / f"{name}.png" for name in rig.cameras],
                           calibration_dir=folder,
                           input_dir=args.images or args.videos)
        out.mkdir(parents=True, exist_ok=True)
        for name in rig.cameras:
            if name not in names:
                log.warning("No image of camera %s in the input: skipped.", name)
                continue
            image = frame_sets[0][names.index(name)]
            observed, reprojected = camera_residuals(rec, name)
            drawn = draw_residuals(image, observed, reprojected, args.scale, name)
            cv2.imwrite(str(out / f"{name}.png"), cv2.cvtColor(drawn, cv2.COLOR_RGB2BGR))
            err = np.linalg.norm(reprojected - observed, axis=1)
            print(f"{name}: {len(err)} points, residual median "
                  f"{np.median(err) if len(err) else float('nan'):.2f} px -> {out / name}.png")
    except InputError as exc:
        log.error("%s", exc)
        return 2
    return 0
