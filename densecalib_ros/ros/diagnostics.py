"""The node's /diagnostics status: calibrated or not, the last failure and check, the frames
received, lost and malformed per camera, the calibration's fit and warnings."""
from __future__ import annotations

import time
from pathlib import Path
from typing import Optional

from diagnostic_msgs.msg import DiagnosticStatus, KeyValue

from ..core.types import RigCalibration
from .calibrating import scale_said
from .frame_loss import WARN_LOSS_FRACTION
from .settings import Settings


def rig_diagnostic_status(name: str, settings: Settings, stats: dict, last_malformed: list,
                          state: str, status_text: str, calibration: Optional[RigCalibration],
                          calibration_dir: Optional[Path], calibrated_at: Optional[float],
                          last_failure: Optional[str], last_check
                          ) -> tuple[DiagnosticStatus, list[str]]:
    """The node's /diagnostics status (level, message, values) and the cameras losing frames
    lately ("cam1 (12 %)"), from what the node holds: its synchroniser's stats, its state
    ("idle", "calibrating", ...) and status line, the published calibration, the last failure
    and the last check (shown while it judged the published calibration)."""
    status = DiagnosticStatus(name=name, hardware_id=settings.rig_frame)
    if calibration is None:
        status.level, status.message = DiagnosticStatus.WARN, "not calibrated"
    elif last_failure:
        status.level = DiagnosticStatus.WARN
        status.message = "last calibration failed; previous one still published"
    else:
        status.level, status.message = DiagnosticStatus.OK, "calibrated"
    if last_failure and calibration is None:
        status.level = DiagnosticStatus.ERROR
    values = {"state": state,
              "status": status_text,
              "buffered_frame_sets": str(stats["buffered"]),
              "received_per_camera": ", ".join(
                  f"{n}={k}" for n, k in zip(settings.camera_names, stats["received"])),
              "matched_frame_sets": str(stats["matched"]),
              "dropped_oldest_frame_sets": str(stats["dropped_oldest"])}
    if any(settings.stamp_offsets_s):
        values["stamp_offsets_s"] = ", ".join(
            f"{n}={o:+.4f}" for n, o in zip(settings.camera_names,
                                            settings.stamp_offsets_s))
    if calibration is not None:
        _add_calibration(values, status, calibration, calibration_dir, calibrated_at)
    check = last_check  # shown while the calibration it judged is the current one
    if (check is not None and calibration_dir is not None
            and check.calibration_dir == calibration_dir):
        values.update(last_check=check.message,
                      last_check_age_s=f"{time.time() - check.at:.1f}")
        if check.fits is False:  # before any other warning: the rig is not as published
            status.level = DiagnosticStatus.WARN
            status.message = ("the calibration no longer fits the latest images: a camera "
                              "moved or changed (last check)" +
                              ("; the last calibration failed" if last_failure else ""))
    if last_failure:
        values["last_failure"] = last_failure
    values["lost_frames_per_camera"] = ", ".join(
        f"{n}={k} ({100 * r:.0f} % lately, "
        + (f"{1 / p:.1f} fps)" if p else "rate not steady)")
        for n, k, r, p in zip(settings.camera_names, stats["lost"],
                              stats["recent_loss"], stats["period_s"]))
    if any(stats["malformed"]):  # frames that reach the node but do not decode
        values["malformed_frames_per_camera"] = ", ".join(
            f"{n}={k}" + (f" ({r})" if r else "") for n, k, r in
            zip(settings.camera_names, stats["malformed"], last_malformed))
        status.level = max(status.level, DiagnosticStatus.WARN)
        status.message += "; frames that do not decode from " + ", ".join(
            n for n, k in zip(settings.camera_names, stats["malformed"]) if k)
    losing = [f"{n} ({100 * r:.0f} %)" for n, r in zip(settings.camera_names,
                                                      stats["recent_loss"])
              if r > WARN_LOSS_FRACTION]
    if losing:  # after the others: it adds to their message
        status.level = max(status.level, DiagnosticStatus.WARN)
        status.message += f"; frames lost on the way from {', '.join(losing)}"
    status.values = [KeyValue(key=k, value=v) for k, v in values.items()]
    return status, losing


def _add_calibration(values: dict, status: DiagnosticStatus, calibration: RigCalibration,
                     calibration_dir: Optional[Path], calibrated_at: Optional[float]) -> None:
    """The published calibration's fit, sigmas, failed cameras and warnings, into values (and
    the status: warnings make it WARN)."""
    values.update(
        reprojection_rms_px=f"{calibration.quality.fit_rms_px():.3f}",
        metric_scale=scale_said(calibration),
        cameras=", ".join(calibration.cameras),
        age_s=f"{time.time() - calibrated_at:.1f}",
        files=str(calibration_dir))
    for key, fmt in (("focal_std_px", ".1f"), ("projection_std_px", ".2f")):
        per_camera = [f"{n}={getattr(c.quality, key):{fmt}}"
                      for n, c in calibration.cameras.items()
                      if c.quality is not None and getattr(c.quality, key) is not None]
        if per_camera:
            values[key] = ", ".join(per_camera)
    if calibration.failed_cameras:
        values["failed_cameras"] = ", ".join(calibration.failed_cameras)
    warnings = calibration.quality.warnings
    if warnings:  # e.g. the consensus runs disagree: the rig may be wrong
        values["warnings"] = " | ".join(warnings)
        if status.level == DiagnosticStatus.OK:
            status.level = DiagnosticStatus.WARN
            status.message = "calibrated, with warnings"
