"""The node's calibrations on disk: output_dir checked at start-up, each calibration written as a
new folder with `latest` swapped onto it (core.io.calibration_store), and the one to publish at
start-up and on ~/reload."""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Optional

from ..core.errors import InputError
from ..core.io.calibration_store import LATEST, stored_calibrations, write_new_calibration
from ..core.io.camera_info import camera_info_yaml
from ..core.io.export import read_calibration, write_calibration_files, write_calibration_json
from ..core.io.safe_write import write_text_atomic
from ..core.types import RigCalibration


def check_output_dir(output_dir: Path) -> None:
    """InputError at start-up when the calibrations could not be written (found only after the
    first calibration's minutes otherwise)."""
    try:
        output_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"output_dir {output_dir} cannot be created: {exc.strerror or exc}; "
                         "give a folder the node may write.") from None
    if not os.access(output_dir, os.W_OK | os.X_OK):
        raise InputError(f"output_dir {output_dir} is not writable by this user; give a folder "
                         "the node may write.")


def write_calibration(output_dir: Path, rig: RigCalibration, rectified: dict, reconstruction=None,
                      reference_views: Optional[dict] = None) -> Path:
    """Write output_dir/<UTC time>/ atomically, then swap the `latest` symlink onto it. The
    cameras of `rectified` ({camera: (rect_from_cam, projection)}: the stereo pairs') get their
    pair's rectification in their YAML files, as in the CameraInfo the node publishes."""
    def write(folder: Path) -> None:
        write_calibration_files(rig, folder, reconstruction, reference_views=reference_views)
        for name, (rect_from_cam, projection) in rectified.items():
            write_text_atomic(folder / f"{name}.yaml", camera_info_yaml(
                name, rig.cameras[name].intrinsics, rect_from_cam, projection))
    return write_new_calibration(output_dir, write)


@dataclass
class StoredCalibration:
    folder: Path  # resolved: the folder `latest` pointed at, or the one published instead
    rig: RigCalibration
    made_at: float  # time.time() its calibration.json was written
    instead: Optional[str] = None  # why `latest` itself was not the one

    def published_line(self, floor_on: bool) -> str:
        """What the node says when it publishes this calibration (floor_on: the floor parameter
        is on, so its floor, where it has one, is published too)."""
        rig = self.rig
        extras = [x for x, on in (("metric", rig.metric_scale),
                                  ("with its floor", bool(rig.quality.floor) and floor_on))
                  if on]
        return (f"published {self.folder}: {len(rig.cameras)} cameras ({', '.join(rig.cameras)}), "
                f"reprojection RMS {rig.quality.fit_rms_px():.2f} px"
                + (f", {' and '.join(extras)}" if extras else ""))


def latest_calibration(output_dir: Path, camera_names: list[str],
                       fall_back: bool = False) -> StoredCalibration:
    """The calibration under output_dir/latest; InputError saying why there is none to publish
    ("no calibration under ..." when there is none at all). fall_back (start-up): where `latest`
    is missing its target or does not read, the newest kept calibration that reads cleanly."""
    latest = output_dir / LATEST
    if not latest.exists() and not latest.is_symlink():
        raise InputError(f"no calibration under {latest}")
    try:
        rig = read_calibration(latest) if latest.exists() else None
        problem = None if rig is not None else f"{latest} points at nothing"
    except InputError as exc:
        rig, problem = None, str(exc)
    instead = None
    if rig is None:
        older = _newest_readable_calibration(output_dir, camera_names) if fall_back else None
        if older is None:
            raise InputError(f"not loaded: {problem}")
        instead = (f"{problem}; the newest kept calibration that reads cleanly, {older[0]}, is "
                   f"published instead (calibrate again, or point {latest} at the one to use "
                   "and call ~/reload)")
        latest, rig = older
    unknown = [c for c in rig.cameras if c not in camera_names]
    if unknown:
        raise InputError(f"not loaded: the calibration in {latest.resolve()} has cameras "
                         f"{unknown}, which are not among camera_names {camera_names}")
    return StoredCalibration(latest.resolve(), rig, (latest / "calibration.json").stat().st_mtime,
                             instead)


def _newest_readable_calibration(output_dir: Path, camera_names: list[str]
                                 ) -> Optional[tuple[Path, RigCalibration]]:
    """(folder, calibration) of the newest calibration under output_dir that reads cleanly and
    has only known cameras, or None."""
    for folder in reversed(stored_calibrations(output_dir)):
        try:
            rig = read_calibration(folder)
        except InputError:
            continue
        if all(c in camera_names for c in rig.cameras):
            return folder, rig
    return None


def save_found_floor(folder: Path, rig: RigCalibration, floor) -> str:
    """Record `floor` (core.products.floor.Floor, found in the saved scene points of the
    calibration `rig` stored in `folder`) in `rig` and its calibration.json, so that it is
    published now and after a restart; what was done."""
    from ..core.products.floor import set_floor

    set_floor(rig, floor)
    write_calibration_json(rig, folder)
    return (f"floor: found in {folder.name} ({floor.num_points} points) and recorded in its "
            "calibration.json")
