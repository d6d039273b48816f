"""The node's calibration in the terms of the one calibration job (core.job): the request its
settings and buffered frame sets make, and the ~/calibrate reply of a calibration written."""
from __future__ import annotations

from pathlib import Path
from typing import Optional

from ..core.method.known_intrinsics import with_previous_intrinsics
from ..core.products.report import info_strips_line
from ..core.types import RigCalibration
from .settings import Settings, pipeline_config


def calibration_request(s: Settings, sets: list, images: list,
                        previous: Optional[RigCalibration], previous_dir: Optional[Path],
                        matcher):
    """The job of calibrating the decoded `images` of the frame sets `sets` with the settings `s`,
    from the published calibration `previous` (stored in previous_dir) where there is one."""
    from ..core.io.reference_view_files import read_reference_views
    from ..core.job import CalibrationRequest

    config = pipeline_config(s)
    if s.keep_intrinsics and previous is not None:
        config = config.with_options(cameras__known_intrinsics=with_previous_intrinsics(
            config.cameras.known_intrinsics, previous, s.camera_names))
    previous_views = (read_reference_views(previous_dir, s.camera_names)
                      if previous is not None and previous_dir is not None else {})
    offsets = ({"stamp_offsets_s": dict(zip(s.camera_names, s.stamp_offsets_s))}
               if any(s.stamp_offsets_s) else {})
    source = {"source": "topics", "topics": list(s.image_topics),
              "camera_names": list(s.camera_names), **offsets,
              "frame_set_stamps_ns": [  # as the headers had them
                  [int(t) + int(round(o * 1e9)) for t, o in zip(fs.stamps_ns, s.stamp_offsets_s)]
                  for fs in sets]}
    return CalibrationRequest(
        images, list(s.camera_names), config, source,
        previous=previous,  # start from it; a worse result is refused
        previous_views=previous_views,
        known_baseline=((*s.baseline_cameras, s.known_baseline_m)
                        if s.known_baseline_m > 0 else None),
        floor=s.floor or None, floor_hint="set the floor parameter (upright or top) to find it",
        matcher=matcher)


# What a calibration without metric scale means for whoever reads /tf_static (said at WARN when it
# is published, in the ~/calibrate reply and on /diagnostics: consumers of tf take metres).
UNSCALED = ("no metric scale: /tf_static and the files are in rig units, not metres (the median "
            "distance of the other cameras from the reference camera is 1); set "
            "known_baseline_m and baseline_cameras, or give the calibration metres with "
            "`densecalib scale` and call ~/reload")


def scale_said(rig: RigCalibration) -> str:
    """The calibration's scale in a word or two: where its metres came from, or "rig units"."""
    if not rig.metric_scale:
        return "no (rig units)"
    baseline, points = rig.quality.scale_from_baseline, rig.quality.scale_from_points
    if baseline:
        return f"yes ({'-'.join(baseline['cameras'])} = {baseline['baseline_m']} m)"
    return "yes (a measured length in the scene)" if points else "yes"


def calibrated_message(s: Settings, rig: RigCalibration, num_sets: int, elapsed: float,
                       out: Path, removed: list, stereo_problem: Optional[str],
                       set_camera_info: Optional[str]) -> str:
    """The ~/calibrate reply for a calibration written to `out`: what was calibrated, from
    what, how well, its warnings and what became of the stored and the drivers' calibrations."""
    rms = rig.quality.fit_rms_px()
    failed = f", failed: {', '.join(rig.failed_cameras)}" if rig.failed_cameras else ""
    scale = (f", metric scale from {'-'.join(s.baseline_cameras)} = {s.known_baseline_m} m"
             if rig.metric_scale else "")
    message = (f"calibrated {len(rig.cameras)}/{len(s.camera_names)} cameras "
               f"({', '.join(rig.cameras)}{failed}) from {num_sets} frame sets, reprojection "
               f"RMS {rms:.2f} px, {elapsed:.1f} s{scale}; files in {out}")
    if rig.quality.change_summary is not None:
        message += f"; {rig.quality.change_summary} (started {rig.quality.init})"
    if rig.quality.frame_sets_before_change:
        message += (f"; the {rig.quality.frame_sets_before_change} older frame sets "
                    "still fitted the previous calibration and were left out: the rig "
                    "changed after them")
    if rig.quality.info_strips:  # found in the images (detect_info_strips)
        message += f"; {info_strips_line(rig.quality)}"
    for warning in rig.quality.warnings:
        message += f"; warning: {warning}"
    if not rig.metric_scale:
        message += f"; warning: {UNSCALED}"
    if stereo_problem:
        message += f"; warning: {stereo_problem}"
    if set_camera_info is not None:
        message += "; set_camera_info: " + set_camera_info
    if removed:
        message += (f"; removed the {len(removed)} oldest calibration(s) "
                    f"(keep_calibrations {s.keep_calibrations})")
    return message
