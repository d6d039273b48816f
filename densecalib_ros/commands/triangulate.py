"""`densecalib triangulate`: 3D points from their pixels in two or more cameras of a calibration
(core.products.triangulation), with their uncertainty and the distances between them."""
from __future__ import annotations

import argparse
import logging

import numpy as np

from ..core.errors import InputError
from ..core.io.export import read_calibration
from ..core.json_text import json_text
from ..core.products.triangulation import DEFAULT_PIXEL_SIGMA, distance, triangulate

log = logging.getLogger("densecalib.triangulate")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("calibration", metavar="CALIBRATION",
                        help="a calibration folder, a node's output_dir or a calibration.json")
    parser.add_argument("--point", action="append", nargs="+", required=True,
                        metavar="CAMERA=X,Y",
                        help="one point: its pixel in each camera that sees it (at least two; "
                             "OpenCV/ROS pixels of the original image, top-left pixel centre at "
                             "(0, 0)), e.g. --point cam0=512.5,300 cam2=640,310.2; repeat for "
                             "more points")
    parser.add_argument("--pixel-sigma", type=float, default=DEFAULT_PIXEL_SIGMA, metavar="PX",
                        help="assumed pixel error (1 sigma, each coordinate) for the points' "
                             f"standard deviations (default {DEFAULT_PIXEL_SIGMA:g})")
    parser.add_argument("--json", action="store_true",
                        help="print the points, and their distances with 1-sigma, as JSON")


def parse_observations(values: list[str], option: str = "--point") -> dict:
    """["cam0=512.5,300", "cam2=640,310.2"] -> {camera: (x, y)}; InputError naming `option`."""
    out = {}
    for value in values:
        name, sep, xy = value.rpartition("=")  # X,Y holds no '=': a camera name may
        try:
            x, y = (float(v) for v in xy.split(","))
        except ValueError:
            x = y = float("nan")
        if not sep or not name or not (np.isfinite(x) and np.isfinite(y)):
            raise InputError(f"{option} {value!r}: expected CAMERA=X,Y (e.g. cam0=512.5,300).")
        if name in out:
            raise InputError(f"{option} names camera {name} twice.")
        out[name] = (x, y)
    return out


def run(args: argparse.Namespace) -> int:
    try:
        if not args.pixel_sigma > 0:
            raise InputError(f"--pixel-sigma {args.pixel_sigma:g}: give a positive pixel error.")
        rig = read_calibration(args.calibration)
        points = [triangulate(rig, parse_observations(values), args.pixel_sigma)
                  for values in args.point]
    except InputError as exc:
        log.error("%s", exc)
        return 2
    unit = "m" if rig.metric_scale else "rig units"
    if args.json:
        print(json_text({"units": unit, "points": [
            {"xyz_rig": p.xyz_rig.tolist(), "std_rig": p.std.tolist(),
             **({"xyz_floor": p.xyz_floor.tolist()} if p.xyz_floor is not None else {}),
             "residuals_px": p.residuals_px, "parallax_deg": p.parallax_deg,
             "warnings": p.warnings} for p in points],
            "distances": [[distance(a, b)[0] for b in points] for a in points],
            "distance_sigmas": [[distance(a, b)[1] for b in points] for a in points]}, indent=2))
        return 0
    floor = points[0].xyz_floor is not None
    print(f"point  x y z in the rig frame ({unit}; reference camera {rig.reference_camera})"
          + ("  |  in the floor frame (z = height)" if floor else "")
          + "  |  1-sigma  |  parallax  |  reprojection error per camera")
    for i, p in enumerate(points):
        where = " ".join(f"{v:.4g}" for v in p.xyz_rig)
        if floor:
            where += "  |  " + " ".join(f"{v:.4g}" for v in p.xyz_floor)
        errors = ", ".join(f"{n} {e:.2f} px" for n, e in p.residuals_px.items())
        print(f"{i:5d}  {where}  |  {' '.join(f'{s:.2g}' for s in p.std)}  |  "
              f"{p.parallax_deg:.1f} deg  |  {errors}")
        for warning in p.warnings:
            print(f"       warning: {warning}")
    for i in range(len(points)):
        for j in range(i + 1, len(points)):
            dist, sigma = distance(points[i], points[j])
            print(f"distance {i}-{j}: {dist:.4g} {unit} (1-sigma {sigma:.2g})")
    return 0
