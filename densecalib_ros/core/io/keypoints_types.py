"""What every keypoint reader gives (core.io.keypoints): one camera's keypoints per frame,
individual and joint, in the tool's (OpenCV's) pixel convention."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np


@dataclass(frozen=True)
class CameraKeypoints:
    """One camera's keypoints. frames: int64 (F,) increasing frame indices of the camera's video;
    xy_px: float64 (F, I, J, 2) OpenCV pixels (top-left pixel centre at (0, 0)), NaN where the
    tool gave no position; likelihood: float64 (F, I, J) in [0, 1] as the tool scored it (1 for
    a person's label), NaN where none; individuals (I names, "" for a single unnamed animal) and
    joints (J names) as the file names them; image_size: (width, height) where the file says."""

    path: str
    tool: str
    frames: np.ndarray
    individuals: tuple
    joints: tuple
    xy_px: np.ndarray
    likelihood: np.ndarray
    image_size: Optional[tuple] = None
