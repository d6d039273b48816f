"""The ROS 2 layer (the only package that imports rclpy): the calibration node, message
synchronisation, message conversions and bag replay."""
