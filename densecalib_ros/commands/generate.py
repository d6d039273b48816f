"""`densecalib generate`: render a synthetic rig and write its images and exact ground truth.

Output: OUT/<camera>/<t:04d>.png (one folder per camera, time-aligned file names) and
OUT/ground_truth.json (calibration.json format + "cam_from_world")."""
from __future__ import annotations

import argparse
import logging
import time
from typing import Optional

from ..core.errors import CalibrationError
from .argtypes import seed

log = logging.getLogger("densecalib.generate")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--out", required=True, help="output folder (created if missing)")
    parser.add_argument("--cameras", type=int, default=6, help="number of cameras, 3..10")
    parser.add_argument("--model", default="RADIAL", choices=["RADIAL", "OPENCV_FISHEYE"],
                        help="camera model of every camera")
    parser.add_argument("--fisheye-cameras", type=int, nargs="+", default=(), metavar="INDEX",
                        help="a rig mixing lenses: these cameras (0-based) are OPENCV_FISHEYE, "
                             "the others --model")
    parser.add_argument("--width", type=int, default=1024)
    parser.add_argument("--height", type=int, default=768)
    parser.add_argument("--time-steps", type=int, default=1,
                        help="frame sets; objects move between them, the rig does not")
    parser.add_argument("--seed", type=seed, default=0)
    parser.add_argument("--fov-deg", type=float, default=None,
                        help="horizontal field of view of every camera (default: random: "
                             "pinhole per --lenses, fisheye 150-190)")
    parser.add_argument("--noise-std", type=float, default=2.0, help="sensor noise, 8-bit levels")
    parser.add_argument("--gap-deg", type=float, default=None,
                        help="azimuth between neighbouring cameras on their arc (wider = less "
                             "alike views; default 20)")
    parser.add_argument("--max-arc-deg", type=float, default=None,
                        help="largest arc spanned by all cameras (360 = a ring around the "
                             "scene; default 140)")
    parser.add_argument("--layout", default="arc", choices=["arc", "bar", "outward"],  # LAYOUTS
                        help="arc: cameras around the scene looking at its centre (--gap-deg, "
                             "--max-arc-deg); bar: side by side on a bar looking the same way "
                             "(axes parallel to within 3 deg; --bar-spacing-m); outward: one "
                             "head near the room's centre facing out, yaws 360/N deg apart")
    parser.add_argument("--bar-spacing-m", type=float, default=None,
                        help="distance between neighbouring cameras of --layout bar (default "
                             "0.3)")
    parser.add_argument("--lenses", default="real", choices=["real", "ideal"],  # LENS_PROFILES
                        help="real: intrinsics as real lenses have them (principal points up "
                             "to 2 %% off-centre, focal 0.5-2.2x the width, fy != fx by up to "
                             "0.5 %%); ideal: centred principal points, fx = fy, 55-75 deg")
    users = parser.add_argument_group("rigs as users build them (issue 81)")
    users.add_argument("--room", default="textured", choices=["textured", "plain"],  # ROOMS
                       help="textured: every surface textured, objects in the middle moving "
                            "between time steps; plain: plain walls and floor, a few textured "
                            "things at the walls")
    users.add_argument("--walker", default="none", choices=["none", "person", "animal"],
                       help="a person or four-legged animal walking a loop through the plain "
                            "room over the time steps")
    users.add_argument("--mount", default="any", choices=["any", "high", "low"],
                       help="camera heights: any 1-2 m; high 1.7-2.4 m looking down (a mocap "
                            "ring); low 0.4-1.1 m about level (camera traps, desk webcams)")
    users.add_argument("--lens-mix", default="rig", choices=["rig", "mixed", "identical"],
                       help="rig: one lens type, each camera within 5 %%; mixed: each camera "
                            "its own lens (pinhole 56-83 deg); identical: units of one model")
    users.add_argument("--blur-sigma-px", type=float, default=0.0,
                       help="Gaussian optical blur before the noise (0: none)")
    users.add_argument("--jpeg-quality", type=int, default=0,
                       help="JPEG compression of every image, 10-100 (0: none)")


def _conflicting_options(args: argparse.Namespace) -> Optional[str]:
    """What is wrong where two options ask for different rigs (one would be ignored unsaid)."""
    if args.lens_mix == "mixed" and args.fov_deg is not None:
        return ("--fov-deg gives every camera one field of view; --lens-mix mixed gives each "
                "its own: give one of them.")
    if args.layout != "arc" and (args.gap_deg is not None or args.max_arc_deg is not None):
        return f"--gap-deg and --max-arc-deg place cameras on an arc, not --layout {args.layout}."
    if args.layout != "bar" and args.bar_spacing_m is not None:
        return f"--bar-spacing-m spaces cameras on a bar, not --layout {args.layout}."
    return None


def run(args: argparse.Namespace) -> int:
    from ..core.io.safe_write import replace_directory_atomic
    from ..core.synthetic import RigSpec, generate_rig, write_rig

    conflict = _conflicting_options(args)
    if conflict:
        log.error("%s", conflict)
        return 2
    fisheye = set(args.fisheye_cameras)
    if not fisheye <= set(range(args.cameras)):
        log.error("--fisheye-cameras %s: the cameras are 0..%d.", sorted(fisheye),
                  args.cameras - 1)
        return 2
    models = tuple("OPENCV_FISHEYE" if c in fisheye else args.model
                   for c in range(args.cameras)) if fisheye else ()
    spec = RigSpec(num_cameras=args.cameras, camera_model=args.model, camera_models=models,
                   width=args.width,
                   height=args.height, num_time_steps=args.time_steps, seed=args.seed,
                   fov_deg=args.fov_deg, noise_std=args.noise_std,
                   **{field: value for field, value in (
                       ("gap_deg", args.gap_deg), ("max_arc_deg", args.max_arc_deg),
                       ("bar_spacing_m", args.bar_spacing_m)) if value is not None},
                   layout=args.layout, lenses=args.lenses, room=args.room,
                   walker=args.walker, mount=args.mount, lens_mix=args.lens_mix,
                   blur_sigma_px=args.blur_sigma_px, jpeg_quality=args.jpeg_quality)
    try:
        t0 = time.perf_counter()
        rig = generate_rig(spec)
        replace_directory_atomic(lambda tmp: write_rig(rig, tmp), args.out,
                                 ("ground_truth.json",))
    except CalibrationError as exc:
        log.error("%s", exc)
        return 2
    log.info("Wrote %d cameras x %d time steps (%dx%d, %s) to %s in %.1f s", len(rig.names),
             len(rig.images), spec.width, spec.height,
             ", ".join(sorted(set(spec.camera_models or (spec.camera_model,)))), args.out,
             time.perf_counter() - t0)
    return 0
