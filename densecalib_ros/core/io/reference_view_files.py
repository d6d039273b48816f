"""The reference views a calibration keeps (`reference_views/<camera>.jpg`): which images they are,
and writing and reading them (what they are for: core.monitor.reference_views)."""
from __future__ import annotations

from pathlib import Path
from typing import Sequence

import cv2
import numpy as np

from ..errors import InputError
from ..types import RigCalibration

REFERENCE_DIR = "reference_views"
REFERENCE_MAX_SIDE_PX = 1024  # the stored view: enough for SIFT, ~0.2-0.5 MB as JPEG
JPEG_QUALITY = 95


def reference_folder(calibration_dir: str | Path) -> Path:
    return Path(calibration_dir) / REFERENCE_DIR


def latest_views(frame_sets: Sequence[Sequence[np.ndarray]], camera_names: Sequence[str],
                 rig: RigCalibration) -> dict[str, np.ndarray]:
    """The reference views of a calibration made from `frame_sets` (in time order): each
    calibrated camera's image of the last frame set."""
    return {n: image for n, image in zip(camera_names, frame_sets[-1]) if n in rig.cameras}


def write_reference_views(calibration_dir: str | Path, views: dict[str, np.ndarray],
                          max_side_px: int = REFERENCE_MAX_SIDE_PX) -> None:
    """Store {camera: uint8 RGB or gray image} as the cameras' reference views."""
    folder = reference_folder(calibration_dir)
    folder.mkdir(parents=True, exist_ok=True)
    for name, image in views.items():
        h, w = image.shape[:2]
        scale = min(1.0, max_side_px / max(w, h))
        if scale < 1.0:
            image = cv2.resize(image, (round(w * scale), round(h * scale)),
                               interpolation=cv2.INTER_AREA)
        bgr = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_RGB2BGR)
        path = folder / f"{name}.jpg"
        if not cv2.imwrite(str(path), bgr, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY]):
            raise InputError(f"Cannot write {path}: check that the folder is writable.")


def read_reference_views(calibration_dir: str | Path,
                         camera_names: Sequence[str]) -> dict[str, np.ndarray]:
    """{camera: uint8 gray reference view} for the cameras that have one ({} for calibrations
    made before views were kept)."""
    folder = reference_folder(calibration_dir)
    views = {}
    for name in camera_names:
        path = folder / f"{name}.jpg"
        if path.is_file():
            image = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
            if image is not None:
                views[name] = image
    return views
