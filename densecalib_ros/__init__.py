"""densecalib_ros: target-free calibration of rigid multi-camera rigs from scene images.

`densecalib_ros.core` is ROS-free (importable without rclpy); `densecalib_ros.ros` holds the node.
"""

# OpenCV must be loaded before pycolmap: both wheels bundle zlib, and when pycolmap's copy is bound
# first, cv2's PNG encoder (imwrite/imencode) frees with the wrong allocator and aborts the whole
# process (pycolmap 4.2.1 + opencv-python-headless 5.0.0). Every entry point imports this package
# first, so loading cv2 here fixes the order for the CLI, the node and the library.
import sys

if "pycolmap" in sys.modules and "cv2" not in sys.modules:
    # too late to fix the order: say so now, not with a process abort at the first PNG written
    raise ImportError(
        "pycolmap was imported before densecalib_ros (or cv2): the first PNG written would abort "
        "the process (both bundle zlib). Restart Python (the notebook kernel) and import "
        "densecalib_ros, or cv2, before pycolmap.")

import cv2  # noqa: E402,F401  (import order matters, see above)

__version__ = "0.1.0"
