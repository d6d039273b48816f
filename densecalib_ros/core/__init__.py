"""ROS-free calibration core. Must import without rclpy; heavy models load explicitly, never here.

Pixel convention inside the core: COLMAP's (the centre of the top-left pixel is (0.5, 0.5)).
Conversion to the OpenCV/ROS convention (centre at (0, 0)) happens only at the export boundary.
"""
