"""densecalib_ros: target-free calibration of rigid multi-camera rigs from scene images.

`densecalib_ros.core` is ROS-free (importable without rclpy); `densecalib_ros.ros` holds the node.
"""

__version__ = "0.1.0"
