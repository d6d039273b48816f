"""`densecalib overlay`: draw each camera's reprojection residuals on its image (core.overlay), from
a calibration folder's COLMAP model, to see where the points are and how well each lens model fits
them."""
from __future__ import annotations

import argparse
import logging
from pathlib import Path

import cv2
import numpy as np

from ..core.errors import InputError
from ..core.export import calibration_folder, read_calibration

log = logging.getLogger("densecalib.overlay")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("calibration", metavar="CALIBRATION",
                        help="a calibration folder (as `densecalib calibrate` writes it) or a "
                             "node's output_dir (its latest calibration)")
    parser.add_argument("--images", required=True, metavar="DIR",
                        help="the cameras' images, as given to calibrate (the first image of each "
                             "camera is drawn on)")
    parser.add_argument("--out", required=True, metavar="DIR", help="folder for <camera>.png")
    parser.add_argument("--scale", type=float, default=10.0,
                        help="residual lines are drawn this many times their length (default 10)")


def run(args: argparse.Namespace) -> int:
    import pycolmap

    from ..core.image_io import list_image_folder, read_image
    from ..core.overlay import camera_residuals, draw_residuals

    try:
        rig = read_calibration(args.calibration)
        model = calibration_folder(args.calibration) / "colmap"
        if not (model / "images.bin").exists():
            raise InputError(f"No COLMAP model in {model}: overlay needs the folder that "
                             "`densecalib calibrate` (or the node) wrote, colmap/ included.")
        rec = pycolmap.Reconstruction(str(model))
        paths, names = list_image_folder(args.images, align="order")
        out = Path(args.out)
        out.mkdir(parents=True, exist_ok=True)
        for name, cam in rig.cameras.items():
            if name not in names:
                log.warning("No image of camera %s in %s: skipped.", name, args.images)
                continue
            image = read_image(paths[0][names.index(name)])
            size = (cam.intrinsics.width, cam.intrinsics.height)
            if (image.shape[1], image.shape[0]) != size:
                raise InputError(f"{paths[0][names.index(name)]} is {image.shape[1]}x"
                                 f"{image.shape[0]}, but camera {name} was calibrated at "
                                 f"{size[0]}x{size[1]}: give the images it was calibrated on.")
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
