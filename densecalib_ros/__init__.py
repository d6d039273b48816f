"""densecalib_ros: target-free calibration of rigid multi-camera rigs from scene images.

`densecalib_ros.core` is ROS-free (importable without rclpy); `densecalib_ros.ros` holds the node.
"""

# OpenCV must be loaded before pycolmap: both wheels bundle zlib, and when pycolmap's copy is bound
# first, cv2's PNG encoder (imwrite/imencode) frees with the wrong allocator and aborts the whole
# process (pycolmap 4.2.1 + opencv-python-headless 5.0.0). Every entry point imports this package
# first, so loading cv2 here fixes the order for the CLI, the node and the library.
import sys
import warnings

# Too late to fix the order when pycolmap came first: say so now, and the PNG writers refuse
# (InputError) instead of aborting the process; what writes no PNG (e.g. eval.peers) still works.
PNG_ABORTS = "pycolmap" in sys.modules and "cv2" not in sys.modules
WRONG_IMPORT_ORDER = (
    "pycolmap was imported before densecalib_ros (or cv2): writing a PNG would abort the process "
    "(both bundle zlib). Restart Python (the notebook kernel) and import densecalib_ros, or cv2, "
    "before pycolmap.")
if PNG_ABORTS:
    warnings.warn(WRONG_IMPORT_ORDER, RuntimeWarning, stacklevel=2)

import cv2  # noqa: E402,F401  (import order matters, see above)

__version__ = "0.1.0"
