"""`densecalib report`: what a calibration on disk says — intrinsics and fit per camera, the
camera layout, warnings — and, with --against, how it differs from another calibration of the
same cameras (a previous one, or a ground truth such as `densecalib generate`'s); with --history,
the calibrations a node's output_dir keeps, one line each."""
from __future__ import annotations

import argparse
import logging
from dataclasses import asdict

from ..core.errors import InputError
from ..core.io.export import calibration_to_dict, read_calibration
from ..core.json_text import json_text
from ..core.monitor.change import calibration_change, pose_agreement
from ..core.products.report import camera_centres_in_rig, history_report, history_rows, rig_report

log = logging.getLogger("densecalib.report")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("calibration", metavar="CALIBRATION",
                        help="a calibration folder (as `densecalib calibrate` writes it), a node's "
                             "output_dir (its latest calibration) or a calibration.json")
    parser.add_argument("--against", metavar="OTHER",
                        help="another calibration of the same cameras (folder or JSON, e.g. the "
                             "previous one, or a ground_truth.json): report the change from it")
    parser.add_argument("--history", action="store_true",
                        help="CALIBRATION is a node's output_dir: one line per calibration it "
                             "keeps, oldest first, with what changed since the one before (which "
                             "camera turned, whose focal changed)")
    parser.add_argument("--json", action="store_true",
                        help="print the report as JSON on stdout instead of text")
    parser.add_argument("--plot", metavar="PNG",
                        help="also draw the rig seen from above and from the side (cameras, "
                             "their optical axes and fields of view, the scene points of the "
                             "saved COLMAP model; axes in metres or rig units, a legend; with "
                             "--against, where its cameras were, as grey rings) into this PNG "
                             "file")


def run(args: argparse.Namespace) -> int:
    if args.history:
        return _history(args)
    try:
        rig = read_calibration(args.calibration)
        against = read_calibration(args.against) if args.against else None
    except InputError as exc:
        log.error("%s", exc)
        return 2
    if against is not None and not set(rig.cameras) & set(against.cameras):
        log.error("%s and %s share no camera name (%s vs %s): --against compares calibrations "
                  "of the same cameras.", args.calibration, args.against,
                  ", ".join(rig.cameras), ", ".join(against.cameras))
        return 2
    if args.plot:
        try:
            _write_plot(args.calibration, rig, args.plot, against)
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
    print(json_text(out, indent=1))
    return 0


def _history(args: argparse.Namespace) -> int:
    if args.against or args.plot:
        log.error("--history lists the calibrations of an output_dir: give --against or --plot "
                  "one calibration instead (a folder of the list).")
        return 2
    rows = history_rows(args.calibration)
    if not rows:
        log.error("%s holds no calibrations as the node stores them (<UTC time>Z/ folders): "
                  "give a densecalib_node's output_dir.", args.calibration)
        return 2
    print(json_text(rows, indent=1) if args.json else history_report(rows))
    return 0


def _write_plot(calibration, rig, path, against=None) -> None:
    """The layout picture (core.products.layout_plot) of the calibration, with its saved scene
    points (and where `against`'s cameras were)."""
    import cv2

    from ..core.io.export import calibration_folder
    from ..core.io.safe_write import write_text_atomic
    from ..core.products.floor import saved_scene_points
    from ..core.products.layout_plot import draw_layout, render

    if not str(path).lower().endswith(".png"):
        raise InputError(f"--plot {path}: give a .png file name.")
    scene = saved_scene_points(calibration_folder(calibration), rig)
    points = None if scene is None else scene[0]
    if scene is None:
        log.warning("no saved COLMAP model beside the calibration: the plot shows the cameras "
                    "without scene points")
    try:
        plot = draw_layout(rig, points, against=against)
    except ModuleNotFoundError as exc:
        if not (exc.name or "").startswith("matplotlib"):
            raise
        raise InputError("--plot draws with matplotlib, which is not installed: pip install "
                         "the version requirements.txt pins (bash scripts/setup_env.sh).") from None
    ok, png = cv2.imencode(".png", render(plot))
    if not ok:
        raise InputError(f"Could not encode the plot for {path}.")
    write_text_atomic(path, png.tobytes())
    log.info("wrote %s: %d cameras, %d scene points%s", path, len(rig.cameras),
             0 if points is None else len(points),
             f" ({plot.num_stray_points} stray ones drawn at the edge of the view)"
             if plot.num_stray_points else "")
