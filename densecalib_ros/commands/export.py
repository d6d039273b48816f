"""`densecalib export`: write a calibration on disk in another tool's format (anipose's
calibration.toml, Kalibr's camchain.yaml, OpenCV FileStorage files, DANNCE's and JARVIS's per-camera
files, a rectified stereo pair for ROS's stereo_image_proc or OpenCV; core.products.interchange,
core.products.stereo)."""
from __future__ import annotations

import argparse
import logging
from pathlib import Path

from ..core.errors import InputError
from ..core.io.export import calibration_folder, check_output_files, read_calibration
from ..core.io.safe_write import write_files_atomic
from ..core.products.interchange import (DEFAULT_TOPIC_PATTERN, FOLDER_FORMATS, FORMATS,
                                         STEREO_FORMATS, dannce_files, export_text, jarvis_files,
                                         opencv_files, opencv_stereo_yaml, ros_stereo_files)
from ..core.products.stereo import stereo_pair

log = logging.getLogger("densecalib.export")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("calibration", metavar="CALIBRATION",
                        help="a calibration folder (as `densecalib calibrate` writes it), a node's "
                             "output_dir (its latest calibration) or a calibration.json")
    parser.add_argument("--format", required=True, choices=FORMATS,
                        help="anipose: aniposelib calibration.toml; kalibr: Kalibr camchain.yaml; "
                             "opencv: one OpenCV FileStorage <camera>.yml per camera "
                             "(camera_matrix, distortion_coefficients, image size, "
                             "fisheye_model, R and T of cam_from_rig); dannce: DANNCE / Label3D "
                             "hires_cam<i>_params.mat per camera (MATLAB convention, mm, world = "
                             "the floor frame if any); jarvis: JARVIS-MoCap <camera>.yaml per "
                             "camera (transposed K and R, T in mm, world as dannce); ros-stereo: "
                             "the rectified "
                             "camera_info YAMLs of a stereo pair (<left>.yaml, <right>.yaml) for "
                             "camera_info_manager and stereo_image_proc; opencv-stereo: one "
                             "FileStorage file of a pair (K1 D1 K2 D2 R T E F R1 R2 P1 P2 Q); "
                             "ply: the cameras as coloured pyramids and the scene points of the "
                             "saved COLMAP model, for CloudCompare, MeshLab or Blender (world "
                             "as dannce)")
    parser.add_argument("--out", required=True, metavar="FILE|DIR",
                        help="file to write (replaced); opencv, dannce, jarvis, ros-stereo: the "
                             "folder for the files")
    parser.add_argument("--pair", nargs=2, metavar=("LEFT", "RIGHT"),
                        help="ros-stereo, opencv-stereo: the two cameras, left one first "
                             "(default for a two-camera rig: its cameras, ordered left to right)")
    parser.add_argument("--alpha", type=float, default=0.0,
                        help="ros-stereo, opencv-stereo: rectified view, 0 = only valid pixels "
                             "(as ROS's stereo calibrator), 1 = every source pixel "
                             "(cv2.stereoRectify's alpha, the fisheye balance; default 0)")
    parser.add_argument("--topic-pattern", default=DEFAULT_TOPIC_PATTERN, metavar="PATTERN",
                        help="kalibr: each camera's rostopic, {name} = camera name "
                             f"(default {DEFAULT_TOPIC_PATTERN})")


def run(args: argparse.Namespace) -> int:
    try:
        rig = read_calibration(args.calibration)
        options = {"topic_pattern": args.topic_pattern} if args.format == "kalibr" else {}
        if args.pair and args.format not in STEREO_FORMATS:
            raise InputError(f"--pair names a stereo pair; it goes with --format "
                             f"{' or '.join(STEREO_FORMATS)}, not {args.format}.")
        if args.format in STEREO_FORMATS:
            rect = stereo_pair(rig, args.pair, args.alpha,
                               left_to_right=args.format == "ros-stereo")
            files = (ros_stereo_files(rig, rect) if args.format == "ros-stereo"
                     else {None: opencv_stereo_yaml(rig, rect)})
        elif args.format in ("dannce", "jarvis"):
            if args.format == "dannce":
                files = dannce_files(rig)
            else:
                files, ignored = jarvis_files(rig)
                if ignored:
                    log.warning("JARVIS projects with k1 and k2 only: the tangential and k3 "
                                "distortion of %s are left out of its projections",
                                ", ".join(ignored))
            if not rig.metric_scale:
                log.warning("the calibration has no metric scale: %s works in millimetres "
                            "(give a known baseline, or `densecalib scale` it first)",
                            args.format.upper())
        elif args.format in FOLDER_FORMATS:
            files = opencv_files(rig)
        elif args.format == "ply":
            files = {None: _scene_ply(args.calibration, rig)}
        else:
            files = {None: export_text(rig, args.format, **options)}
        if args.format in FOLDER_FORMATS and Path(args.out).is_file():
            raise InputError(f"{args.out} is a file; --format {args.format} writes one file "
                             "per camera into a folder: give a folder.")
        if not str(args.out).strip():
            raise InputError("--out is empty (''): give the file or folder to write.")
        check_output_files([args.out if name is None else Path(args.out) / name
                            for name in files], calibration_dir=calibration_folder(
                                args.calibration))
        # name None: the one file of a single-file format; the files of a folder format are
        # written whole before any replaces an earlier export's (all or nothing)
        write_files_atomic({args.out if name is None else Path(args.out) / name: text
                            for name, text in files.items()})
    except InputError as exc:
        log.error("%s", exc)
        return 2
    if args.format in FOLDER_FORMATS:
        _warn_about_stale_files(Path(args.out), files)
    listed = ", ".join(name for name in files if name)
    if args.format in STEREO_FORMATS:
        print(f"wrote {args.out} ({args.format}: {rect.left} left, {rect.right} right, baseline "
              f"{rect.baseline:.6g} {'m' if rect.metric else 'rig units (not metric)'}"
              f"{'; ' + listed if listed else ''})")
    else:
        print(f"wrote {args.out} ({args.format}, {len(rig.cameras)} cameras"
              f"{': ' + listed if listed else ''})")
    return 0


def _warn_about_stale_files(out: Path, written: dict) -> None:
    """Name the files of the same kind in `out` that this export did not write (a camera
    renamed or dropped since an earlier export): tools that load every file of a folder would
    take them for cameras of the rig. They are the user's to remove; nothing is deleted."""
    kinds = {Path(name).suffix for name in written}
    stale = sorted(p.name for p in out.iterdir()
                   if p.is_file() and p.suffix in kinds and p.name not in written)
    if stale:
        log.warning("%s also holds %s, not written by this export (an earlier export's "
                    "camera?): remove %s if your tool reads every file of the folder",
                    out, ", ".join(stale), "it" if len(stale) == 1 else "them")


def _scene_ply(calibration, rig) -> str:
    from ..core.products.floor import saved_scene_points
    from ..core.products.scene_ply import scene_ply

    scene = saved_scene_points(calibration_folder(calibration), rig)
    if scene is None:
        log.warning("no saved COLMAP model beside the calibration: the PLY has the cameras "
                    "without scene points")
        return scene_ply(rig)
    return scene_ply(rig, *scene)
