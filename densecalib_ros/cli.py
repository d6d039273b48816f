"""`densecalib`: the offline command. Subcommands live in densecalib_ros.commands, one per module,
listed explicitly here and imported only when used (so `densecalib bench` never imports rclpy)."""
from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys
from typing import Optional

from .commands import interrupts
from .core.colmap_logging import show_colmap_log
from .core.errors import CalibrationError

# name -> (module, one-line help), in the order --help lists them: users' commands first
SUBCOMMANDS = {
    "calibrate": ("densecalib_ros.commands.calibrate",
                  "calibrate a rig from a folder of images or videos, or a rosbag2 bag"),
    "keypoints": ("densecalib_ros.commands.keypoints",
                  "person keypoints (BlazePose) in every camera's frames, as OpenPose JSON for "
                  "calibrate --keypoints"),
    "demo": ("densecalib_ros.commands.demo",
             "generate a rig, calibrate it through the ROS node (or --offline) and compare to truth"),
    "generate": ("densecalib_ros.commands.generate",
                 "write a generated rig's images and ground truth to a folder"),
    "report": ("densecalib_ros.commands.report",
               "print a calibration's intrinsics, fit and camera layout, or its change from another; "
               "--plot draws the rig from above and the side"),
    "check": ("densecalib_ros.commands.check",
              "does a calibration still fit new images of the rig? names cameras that moved"),
    "overlay": ("densecalib_ros.commands.overlay",
                "draw each camera's reprojection residuals on its image"),
    "undistort": ("densecalib_ros.commands.undistort",
                  "resample images to distortion-free pinhole cameras, with their calibration"),
    "sync": ("densecalib_ros.commands.sync",
             "time offsets between the cameras' videos, bag topics or camera-trap shots; videos cut "
             "to start together (--trim), a bag restamped onto one clock (--restamp)"),
    "scale": ("densecalib_ros.commands.scale",
              "give a written calibration metric scale from a measured distance between two "
              "scene points (or two cameras)"),
    "floor": ("densecalib_ros.commands.floor",
              "find the floor in a written calibration's scene points and record the floor frame"),
    "triangulate": ("densecalib_ros.commands.triangulate",
                    "3D points (and distances) from their pixels in two or more cameras"),
    "export": ("densecalib_ros.commands.export",
               "write a calibration for other tools: anipose, Kalibr, OpenCV, DANNCE, JARVIS, a "
               "rectified stereo pair (ROS, OpenCV), or a PLY of the cameras and scene"),
    "bench-node": ("densecalib_ros.commands.bench_node",
                   "does densecalib_node keep up with a rig's image streams here? frames "
                   "received and lost, node CPU"),
    # for developers of densecalib, listed last
    "bench": ("densecalib_ros.commands.bench",
              "(development) accuracy benchmark against COLMAP/GLOMAP on generated rigs and "
              "real images"),
    "bench-sampling": ("densecalib_ros.commands.bench_sampling",
                       "(development) matcher + cycle-sampling quality per backend on generated "
                       "rigs"),
    "bench-stereo": ("densecalib_ros.commands.bench_stereo",
                     "(development) the real fisheye stereo pair against its own checkerboard: "
                     "rectified rows and measured squares vs its target-based calibrations"),
}


def _parsed(argv: list[str]) -> Optional[argparse.Namespace]:
    """The arguments, the subcommand's module imported to parse them; None (help printed) without
    a subcommand."""
    parser = argparse.ArgumentParser(
        prog="densecalib",
        description="Target-free calibration of multi-camera rigs from scene images.")
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    # Parse the subcommand name first so only that module is imported.
    name = next((a for a in argv if not a.startswith("-")), None)
    for cmd, (module, help_text) in SUBCOMMANDS.items():
        p = sub.add_parser(cmd, help=help_text)
        if cmd == name:
            importlib.import_module(module).add_arguments(p)
    args = parser.parse_args(argv)
    if args.command is None:
        parser.print_help()
        return None
    return args


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    previous = []
    try:
        # The stop signals wait until our handler is in place: a Ctrl-C while the subcommand's
        # modules import (pycolmap's C++ part among them) ended in pycolmap's 'reinstall me'
        # traceback, and importing pycolmap installs glog's SIGTERM handler (a crash report).
        with interrupts.held():
            args = _parsed(argv)
            if args is None:
                return 2
            logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO,
                                format="[%(asctime)s %(levelname)s %(name)s] %(message)s",
                                datefmt="%H:%M:%S", stream=sys.stderr)
            show_colmap_log(args.verbose)
            previous = interrupts.install()
        return int(importlib.import_module(SUBCOMMANDS[args.command][0]).run(args) or 0)
    except CalibrationError as exc:  # one a command did not expect: its message, not a traceback
        logging.getLogger("densecalib").error("%s", exc)
        return 2
    except interrupts.WrittenThenInterrupted as exc:
        logging.getLogger("densecalib").error("%s after the calibration was written: the output "
                                              "holds the new calibration", exc)
        return exc.exit_code
    except interrupts.Interrupted as exc:  # files half written are removed on the way out
        logging.getLogger("densecalib").error("%s: what was written before stays as it was",
                                              exc)
        return exc.exit_code
    except KeyboardInterrupt:  # Ctrl-C before the handler was in place
        logging.getLogger("densecalib").error("interrupted")
        return 130
    except BrokenPipeError:  # `densecalib report ... | head`: the reader had enough
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())  # no error at exit
        return 141
    finally:
        interrupts.restore(previous)


if __name__ == "__main__":
    sys.exit(main())
