"""How much a rig calibration differs from another one of the same cameras: a previous calibration
(recalibration: which camera was bumped or refocused) or a ground truth (`densecalib report
--against`). Poses are compared gauge-free, on relative poses between cameras, so the two
calibrations may use different reference cameras and scales."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from ..metrics import auc, mean_focal_px, projection_map_error, relative_pose_errors
from ..types import RigCalibration


@dataclass
class CameraChange:
    focal_change_pct: float  # (new - previous) / previous, percent
    rotation_change_deg: float  # median over the camera's pairs of the relative-rotation change
    translation_dir_change_deg: float  # same for the relative translation direction
    # Mean distance (px) between where the two intrinsics project the same rays over the image:
    # focal, principal point and distortion together (a refocused lens). None when the image
    # sizes differ.
    projection_change_px: Optional[float] = None


def calibration_change(previous: RigCalibration, new: RigCalibration) -> dict[str, CameraChange]:
    """How much each camera in both calibrations changed. Pose changes are measured on relative
    poses between cameras (gauge-free): a bumped camera changes in all its pairs, the others in
    one pair only, so the per-camera median over pairs points at the camera that moved."""
    names = [n for n in new.cameras if n in previous.cameras]
    pairs = relative_pose_errors({n: new.cameras[n].cam_from_rig for n in names},
                                 {n: previous.cameras[n].cam_from_rig for n in names})
    out = {}
    for name in names:
        mine = [p for p in pairs if name in (p.i, p.j)]  # PairError.i/.j are camera names
        old_cam, new_cam = previous.cameras[name].intrinsics, new.cameras[name].intrinsics
        f_new, f_old = mean_focal_px(new_cam), mean_focal_px(old_cam)
        projection = None
        if (old_cam.width, old_cam.height) == (new_cam.width, new_cam.height):
            mean_px = projection_map_error(old_cam, new_cam)["mean_px"]
            projection = float(mean_px) if np.isfinite(mean_px) else None
        out[name] = CameraChange(
            focal_change_pct=100.0 * (f_new - f_old) / f_old,
            rotation_change_deg=float(np.median([p.rot_err_deg for p in mine])) if mine else 0.0,
            translation_dir_change_deg=(float(np.median([p.trans_dir_err_deg for p in mine]))
                                        if mine else 0.0),
            projection_change_px=projection)
    return out


def change_summary(change: dict[str, CameraChange], prefix: str = "change vs previous: ") -> str:
    """One line: the largest changes and the camera they belong to."""
    if not change:
        return "no camera in common with the previous calibration"
    f = max(change.items(), key=lambda kv: abs(kv[1].focal_change_pct))
    r = max(change.items(), key=lambda kv: kv[1].rotation_change_deg)
    return (f"{prefix}focal up to {f[1].focal_change_pct:+.2f} % ({f[0]}), "
            f"rotation up to {r[1].rotation_change_deg:.2f} deg ({r[0]})")


def pose_agreement(other: RigCalibration, rig: RigCalibration) -> dict:
    """The paper's pose metric of `rig` against `other` over the cameras of `other`: AUC@3 and
    AUC@30 (percent) of the relative-pose errors of every camera pair, a pair with a camera
    missing from `rig` counting as a failure. Against a ground truth this is the accuracy."""
    pairs = relative_pose_errors({n: c.cam_from_rig for n, c in rig.cameras.items()
                                  if n in other.cameras},
                                 {n: c.cam_from_rig for n, c in other.cameras.items()})
    return {"auc3": auc(pairs, 3), "auc30": auc(pairs, 30), "num_pairs": len(pairs)}
