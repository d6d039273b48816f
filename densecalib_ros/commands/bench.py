"""`densecalib bench`: accuracy benchmark of our pipelines against COLMAP (incremental) and GLOMAP
(global) on generated rigs and real images with reference cameras.

Prints a table per scene and a summary per lens type and method; writes OUT/bench.json."""
from __future__ import annotations

import argparse
import logging
import os
import time

from ..core.errors import CalibrationError

log = logging.getLogger("densecalib.bench")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    from ..eval.bench import ALL_METHODS, METHODS

    which = parser.add_mutually_exclusive_group()
    which.add_argument("--quick", action="store_true",
                       help="3 scenes (6-camera pinhole, 4-camera fisheye, Strecha at 768 px): "
                            "a few minutes on 2 cores")
    which.add_argument("--heldout", action="store_true",
                       help="27 scenes never used to develop the method (22 generated pinhole "
                            "rigs with other seeds, camera counts and gaps, 2 fisheye rigs, 5, 8 "
                            "and 10 frames of the fox): how results carry over")
    which.add_argument("--mixed", action="store_true",
                       help="6 generated rigs of 3-8 cameras mixing fisheye and pinhole lenses "
                            "(each camera calibrated with its lens's model; peers get each "
                            "camera's model too)")
    which.add_argument("--forward", action="store_true",
                       help="6 generated rigs of 3-8 pinhole cameras side by side on a bar, "
                            "looking the same way (a stereo head, a camera array): focal "
                            "lengths weakly determined; does the calibration say so")
    which.add_argument("--few", action="store_true",
                       help="8 generated rigs as users build them: 3-4 cameras 45-140 deg apart "
                            "around a plain room a person or animal walks through, 20 frame "
                            "sets at 1280x720, pinhole and fisheye, mixed lenses or units of "
                            "one model, mounted high or low, blurred, noisy, JPEG-compressed; "
                            "one a head of four 220 deg fisheye units facing out")
    which.add_argument("--real", action="store_true",
                       help="the real scenes of the full set only: Strecha entry-P10 (ten "
                            "cameras, one camera; also at 1536 and 3072 px), the fox, "
                            "Caliscope's 4 webcams and Pose2Sim's 4-camera ring (8 frame sets "
                            "of their videos), MEVA's 6 surveillance cameras")
    parser.add_argument("--out", default="bench_out", help="folder for bench.json")
    parser.add_argument("--scenes", nargs="+", default=None, metavar="PATTERN",
                        help="only scenes whose name contains one of these (e.g. fisheye, "
                             "strecha, 10cam); see --list")
    parser.add_argument("--methods", nargs="+", default=list(METHODS), choices=ALL_METHODS,
                        help="methods to run (default: all but densecalib-given-intrinsics, "
                             "which holds each camera's reference intrinsics: extrinsics only)")
    parser.add_argument("--threads", type=int, default=0,
                        help="threads per method (default: all cores)")
    parser.add_argument("--data-dir", default=None,
                        help="folder holding strecha_entry_p10/ (default: $DENSECALIB_DATA, else "
                             "../shared/data beside the repository)")
    parser.add_argument("--list", action="store_true", help="list the scenes and exit")


def run(args: argparse.Namespace) -> int:
    from ..eval.bench import (forward_scenes, full_scenes, heldout_scenes, mixed_scenes,
                              quick_scenes, real_scenes, run_bench)
    from ..eval.few_rigs import few_scenes

    specs = (quick_scenes() if args.quick else heldout_scenes() if args.heldout
             else mixed_scenes() if args.mixed else forward_scenes() if args.forward
             else few_scenes() if args.few
             else real_scenes() if args.real else full_scenes())
    if args.scenes:
        specs = [s for s in specs if any(p in s.name for p in args.scenes)]
        if not specs:
            log.error("No scene matches %s: run with --list to see the names.", args.scenes)
            return 2
    if args.list:
        for s in specs:
            print(s.name)
        return 0
    threads = args.threads if args.threads > 0 else (os.cpu_count() or 1)
    import cv2

    cv2.setNumThreads(threads)
    t0 = time.perf_counter()
    try:
        run_bench(specs, args.methods, num_threads=threads, data_dir=args.data_dir,
                  out_dir=args.out)
    except CalibrationError as exc:
        log.error("%s", exc)
        return 2
    log.info("Benchmark of %d scenes x %d methods took %.0f s; results in %s/bench.json",
             len(specs), len(args.methods), time.perf_counter() - t0, args.out)
    return 0
