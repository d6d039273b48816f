"""densecalib_ros: target-free calibration of rigid multi-camera rigs from scene images.

`densecalib_ros.core` is ROS-free (importable without rclpy); `densecalib_ros.ros` holds the node.
"""

# OpenCV must be loaded before pycolmap: both wheels bundle zlib, and when pycolmap's copy is bound
# first, cv2's PNG encoder (imwrite/imencode) frees with the wrong allocator and aborts the whole
# process (pycolmap 4.2.1 + opencv-python-headless 5.0.0). Every entry point imports this package
# first, so loading cv2 here fixes the order for the CLI, the node and the library.
import cv2  # noqa: F401  (import order matters, see above)

__version__ = "0.1.0"
