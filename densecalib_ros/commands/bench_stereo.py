"""`densecalib bench-stereo`: the real fisheye stereo set held against its own checkerboard
(core.products.stereo_checkerboard): the pair calibrated target-free from the bag, then judged on
the pairs the bag does not hold by how well its rectification lines the board's corners up and how
long it measures the board's squares, beside the set's two target-based calibrations. Prints a
table; writes OUT/bench_stereo.json."""
from __future__ import annotations

import argparse
import logging
import time
from pathlib import Path

from ..core.errors import CalibrationError, InputError
from ..core.json_text import json_text

log = logging.getLogger("densecalib.bench_stereo")

BAG = "ros2bag_fisheye_stereo_derived/fisheye_stereo_bag"
STEREO = "ros_fisheye_stereo_checkerboard/stereo"
TOPICS = ["/stereo/left/image_raw", "/stereo/right/image_raw"]


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", default="bench_out", help="folder for bench_stereo.json")
    parser.add_argument("--data-dir", default=None,
                        help="folder holding the set and its bag (default: $DENSECALIB_DATA, "
                             "else ../shared/data beside the repository)")
    parser.add_argument("--calibration", default=None, metavar="OUT",
                        help="judge this calibration of the pair instead of calibrating the bag")


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from ..core.io.bag import read_frame_sets
    from ..core.config import make_config
    from ..eval.datasets import default_data_dir
    from ..core.io.export import read_calibration
    from ..core import run_calibration
    from ..core.products.scale import with_known_baseline
    from ..core.products.stereo_checkerboard import evaluate, target_calibration

    data = Path(args.data_dir) if args.data_dir else default_data_dir()
    folder = data / STEREO
    try:
        if not (folder.is_dir() and (data / BAG).exists()):
            raise InputError(f"{folder} or {data / BAG} not found: set --data-dir or "
                             "$DENSECALIB_DATA to the folder holding them.")
        t0 = time.perf_counter()
        if args.calibration:
            rig = read_calibration(args.calibration)
        else:  # metric with the target-based baseline, so the squares compare in one unit
            baseline = float(np.linalg.norm(
                target_calibration(folder).cameras["stereo_right"].cam_from_rig[:3, 3]))
            frame_sets, names = read_frame_sets(data / BAG, TOPICS)
            result = run_calibration(frame_sets, names, make_config("fisheye"))
            rig = with_known_baseline(result, names[0], names[1], baseline).rig
        seconds = time.perf_counter() - t0
        figures = evaluate(folder, rig)
    except (InputError, CalibrationError) as exc:
        log.error("%s", exc)
        return 2
    figures["calibration_s"] = seconds
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "bench_stereo.json").write_text(json_text(figures) + "\n")
    print(f"real fisheye stereo set, {figures['pairs']} held-out pairs (not in the bag); "
          f"calibration {seconds:.0f} s; square size in 1e-3 of the baseline's unit "
          f"{'(cam_stereo.yml |T|)' if not args.calibration else ''}")
    print(f"{'calibration':18s} {'row error mrad':>15s} {'square size':>12s} {'corner px':>10s}")
    for name in ("ours", "cam_stereo.yml", "left/right.yaml"):
        size = figures["square_size"].get(name)
        px = figures["corner_reprojection_px"].get(name)
        print(f"{name:18s} {figures['row_error_mrad'][name]:15.2f} "
              f"{'-' if size is None else f'{1000 * size:.2f}':>12s} "
              f"{'-' if px is None else f'{px:.2f}':>10s}")
    _print_error_sigma_ratios(figures)
    return 0


def _print_error_sigma_ratios(figures: dict) -> None:
    """Our intrinsics against each reference over our sigmas, and the references' own spread."""
    print("our intrinsics against each target-based calibration, |error| / own sigma per camera "
          "(focal, principal point, projection):")
    for reference, ratios in figures["error_sigma_ratios"].items():
        print(f"  {reference:16s} " + "; ".join(
            f"{kind.replace('_', ' ')} " + (", ".join(f"{z:.2f}" for z in values) or "-")
            for kind, values in ratios.items()))
    print("  the two references apart: " + "; ".join(
        f"{name} focal {apart['focal_pct']:.2f} %, principal point {apart['pp_px']:.1f} px"
        for name, apart in figures["references_apart"].items()))
