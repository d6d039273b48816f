"""ROS-free calibration core. Must import without rclpy; heavy models load explicitly, never here.

The public API (docs/library.md), importable from here (each name loads its module on first use,
so importing a part of the core costs no more than that part):

    make_config, PipelineConfig          the options (frozen; resolved and checked at the start)
    run_calibration, calibrate_rig       frame sets -> CalibrationResult / RigCalibration
    recalibrate, run_job, CalibrationRequest, JobResult
                                         what the command and the node run
    match_frame_sets                     the matching stage alone (a check of a calibration)
    calibrate_from_tracks, Tracks        a calibration from correspondences you have
    Progress, StopToken, ProgressState   watch a calibration, stop it (CalibrationCancelled)
    read_calibration, write_calibration_files
    RigCalibration, RigCamera, CameraIntrinsics, RigQuality, CalibrationResult
    CalibrationError, InputError, CalibrationCancelled
    generate_rig, RigSpec                generated rigs with ground truth

Rooms, each importing only from those before it and from the shared modules here:
    io        images, video, bags, calibration folders
    method    the paper's stages' mathematics (matching ... bundle adjustment, refinement)
    robust    consensus runs, a second matcher, focal hops, camera placement
    monitor   is a calibration still right (check, reference views, change)
    products  scale, floor, stereo, undistortion, triangulation, report, interchange
    synthetic generated rigs and images for tests and the bench
Shared here: types, errors, config, progress, parallel, compiled, metrics (and small helpers).
Above the rooms, and using any of them: stages (a calibration's stages, one module each),
pipeline (run_calibration: the stages in one sequence), recalibration, job (run_job) and
calibration_result (what they return).

Pixel convention inside the core: COLMAP's (the centre of the top-left pixel is (0.5, 0.5)).
Conversion to the OpenCV/ROS convention (centre at (0, 0)) happens only at the export boundary.
"""
from __future__ import annotations

import importlib

_PUBLIC = {
    "make_config": "config", "PipelineConfig": "config",
    "run_calibration": "pipeline", "calibrate_rig": "pipeline",
    "recalibrate": "recalibration",
    "run_job": "job", "CalibrationRequest": "job", "JobResult": "job",
    "match_frame_sets": "stages.matching", "calibrate_from_tracks": "stages.runs",
    "Tracks": "types",
    "Progress": "progress", "StopToken": "progress", "ProgressState": "progress",
    "read_calibration": "io.export", "write_calibration_files": "io.export",
    "RigCalibration": "types", "RigCamera": "types", "CameraIntrinsics": "types",
    "RigQuality": "types", "CalibrationResult": "calibration_result",
    "CalibrationError": "errors", "InputError": "errors", "CalibrationCancelled": "errors",
    "generate_rig": "synthetic", "RigSpec": "synthetic",
}
__all__ = sorted(_PUBLIC)


def __getattr__(name: str):
    if name not in _PUBLIC:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}: the public API is "
                             f"{', '.join(__all__)}")
    value = getattr(importlib.import_module(f"{__name__}.{_PUBLIC[name]}"), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
