"""ROS-free calibration core. Must import without rclpy; heavy models load explicitly, never here.

Rooms, each importing only from those before it and from the shared modules here:
    io        images, video, bags, calibration folders
    method    the paper's stages (matching ... bundle adjustment, refinement)
    robust    consensus runs, focal hops, camera placement
    monitor   is a calibration still right (check, reference views, change)
    products  scale, floor, stereo, undistortion, triangulation, report, interchange
    synthetic generated rigs and images for tests and the bench
Shared here: types, errors, config, progress, parallel, compiled, metrics (and small helpers).
Above the rooms, and using any of them: pipeline (run_calibration), recalibration, job (run_job:
what the command and the node run) and calibration_result (what they return).

Public API (docs/library.md):
    from densecalib_ros.core.config import make_config
    from densecalib_ros.core.pipeline import run_calibration, calibrate_rig
    from densecalib_ros.core.job import CalibrationRequest, run_job
    from densecalib_ros.core.io.export import write_calibration_files, read_calibration

Pixel convention inside the core: COLMAP's (the centre of the top-left pixel is (0.5, 0.5)).
Conversion to the OpenCV/ROS convention (centre at (0, 0)) happens only at the export boundary.
"""
