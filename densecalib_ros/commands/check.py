"""`densecalib check`: does a calibration still fit the rig? Matches new images and holds every
match against the calibration's epipolar geometry (core.monitor.consistency); names the cameras that
no longer fit (bumped, refocused). Frame sets in time order are judged since the last change among
them (core.monitor.consistency.check_latest). With the calibration's reference views, each camera is
also held against its own view (core.monitor.reference_views); they alone judge when no pair shares
enough matches. Exit status: 0 the calibration fits, 1 it does not, 2 unusable input or nothing
could tell."""
from __future__ import annotations

import argparse
import logging

from ..core.errors import InputError
from ..core.monitor.consistency import (DEFAULT_TOLERANCE_PX, MIN_PAIR_MATCHES,
                                        best_transfer_per_camera, check_latest)
from .argtypes import positive
from .inputs import (add_input_arguments, parse_masks, read_input, require_calibrated_cameras,
                     topics_from_calibration)

log = logging.getLogger("densecalib.check")
MAX_FAILING_SHOWN = 10  # failing transfer figures listed beside each camera's best


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("calibration", metavar="CALIBRATION",
                        help="a calibration folder, a node's output_dir or a calibration.json")
    add_input_arguments(parser)
    parser.add_argument("--tolerance-px", type=positive(), default=DEFAULT_TOLERANCE_PX,
                        metavar="PX",
                        help="a camera pair fits when its median epipolar error is at most this "
                             f"(default {DEFAULT_TOLERANCE_PX:g} px)")
    parser.add_argument("--matcher", default="sift", help="matcher backend (default sift)")


def run(args: argparse.Namespace) -> int:
    from ..core.config import make_config
    from ..core.io.export import read_calibration, reference_views_of
    from ..core.monitor.reference_views import check_verdict, compare_with_reference_views
    from ..core import match_frame_sets

    try:
        rig = read_calibration(args.calibration)
        topics_from_calibration(args, rig)
        frame_sets, names, record, _ = read_input(args)
        require_calibrated_cameras(rig, names, frame_sets[0], at_least=2)
        config = make_config(matcher=args.matcher, cameras__masks=parse_masks(args.mask, names),
                             detect_info_strips=not args.keep_info_strips)
        match_sets = match_frame_sets(frame_sets, config, camera_names=names,
                                      each_on_its_own=True)
    except InputError as exc:
        log.error("%s", exc)
        return 2
    report = check_latest(rig, names, match_sets, args.tolerance_px)
    if k := report.frame_sets_before_change:
        print(f"frame sets 1-{k} of {len(match_sets)} fit the calibration one by one and the "
              "later ones do not: the figures below are from the frame sets since the change, "
              f"the first of them frame set {k + 1}{_frame_set_label(record, k)}")
    tol = args.tolerance_px
    if report.pairs:
        print(f"{'pair':<24} {'matches':>8} {'median epipolar error px':>25}")
    else:
        print(f"no camera pair had {MIN_PAIR_MATCHES} matches: no epipolar figures")
    for c in report.pairs:
        print(f"{c.cameras[0] + ' - ' + c.cameras[1]:<24} {c.num_matches:>8} "
              f"{c.median_error_px:>25.2f}{'' if c.fits(tol) else '  does not fit'}")
    if report.transfers:
        print(f"\n{'camera':<12} {'points':>7} {'median transfer error px':>25}  from (best)")
        def row(c) -> str:
            return (f"{c.target:<12} {c.num_points:>7} {c.median_error_px:>25.2f}  "
                    f"{c.sources[0]} + {c.sources[1]}")

        best = best_transfer_per_camera(report.transfers)
        for c in best:
            print(row(c) + ("" if c.fits(tol) else "  does not fit"))
        failing = sorted((c for c in report.transfers if not c.fits(tol) and c not in best),
                         key=lambda c: -c.median_error_px)
        if failing:  # the verdict counts them: show them
            print(f"and {len(failing)} more transfer figure(s) that do not fit:")
            for c in failing[:MAX_FAILING_SHOWN]:
                print(row(c))
            if len(failing) > MAX_FAILING_SHOWN:
                print(f"... and {len(failing) - MAX_FAILING_SHOWN} more")
    views = None
    references = reference_views_of(args.calibration, names)
    if references:
        views = compare_with_reference_views(rig, names, frame_sets, references,
                                             args.tolerance_px)
        print(f"\n{'camera':<12} {'inliers':>8} {'turned deg':>11} {'px':>6} {'focal %':>8} "
              f"{'px':>6}  (since the calibration: the last frame set against its view)")
        for t in views.turns:
            print(f"{t.camera:<12} {t.num_inliers:>8} {t.rotation_deg:>11.3f} {t.shift_px:>6.2f} "
                  f"{100.0 * (t.focal_scale - 1.0):>+8.2f} {t.zoom_px:>6.2f}"
                  + ("  turned" if t.turned(tol) else "") + ("  zoomed" if t.zoomed(tol) else ""))
        for name in views.not_judged:
            print(f"{name:<12} too few matches with its reference view: not judged")
    fits, verdict = check_verdict(report, views, cameras=[n for n in names if n in rig.cameras],
                                  absent=[n for n in rig.cameras if n not in names])
    if fits is None:  # neither the epipolar figures nor the reference views could tell
        log.error("the calibration could not be checked with these images: %s", verdict)
        return 2
    print(verdict + ("" if fits else "; recalibrate, e.g. densecalib calibrate "
                     f"... --previous {args.calibration}"))
    return 0 if fits else 1


def _frame_set_label(record: dict, k: int) -> str:
    """Where frame set k (0-based) of read_input's input came from, for the user to find it."""
    if "frame_set_times_s" in record:  # a common time: each video's own is t + its offset
        t = record["frame_set_times_s"][k]
        shifted = [f"{n} at {t + o:.2f} s" for n, o in (record.get("time_offsets_s") or {}).items()
                   if o]
        return (f" (at {t:.2f} s of the videos" + (f"; {', '.join(shifted)} of its own"
                                                     if shifted else "") + ")")
    if "frame_set_stamps_ns" in record:
        return f" (stamped {min(record['frame_set_stamps_ns'][k]) * 1e-9:.3f} s)"
    if "frame_sets" in record:
        return f" ({', '.join(record['frame_sets'][k])})"
    return ""
