"""What users make from a calibration: metric scale, floor, stereo rectification, undistortion,
triangulation, overlays and plots, the report, files for other tools (interchange)."""
