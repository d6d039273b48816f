"""Stereo rectification of a camera pair of a calibrated rig, as the stereo tools that consume it
compute and read it.

ROS's stereo_image_proc (and image_geometry's StereoCameraModel) take two CameraInfo whose
rectification matrix R rotates each camera into a common rectified frame and whose projection
matrix P projects from that frame; the right camera's P carries Tx = -fx' * baseline. ROS's own
stereo calibrator (camera_calibration) fills them with cv2.stereoRectify (cv2.fisheye.stereoRectify
for equidistant lenses) and CALIB_ZERO_DISPARITY; so do we, with the rig's relative pose, so the
files are what that tool would have written for this pair. OpenCV's stereo samples keep the same
quantities (K1 D1 K2 D2 R T R1 R2 P1 P2 Q) in one FileStorage file.

Conventions: OpenCV/ROS pixels (top-left pixel centre at (0, 0)); R, T = right_from_left
(x_right = R x_left + T), as stereoCalibrate returns them; rectification matrices rect_from_cam.
Translations and the baseline are in the rig's units: metres only when a known baseline set the
scale.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Optional, Sequence

import cv2
import numpy as np

from ..errors import InputError
from ..io.camera_info import opencv_intrinsics
from ..types import RigCalibration
from .scale import HOW_TO_SCALE
from .undistort import DEFAULT_MAX_FOV_DEG as FALLBACK_MAX_FOV_DEG  # widest rectified view

log = logging.getLogger("densecalib.stereo")

# Beyond this rotation into the rectified frame the pair is far from parallel: rectified images
# lose much of their field of view and disparities near the border get unreliable.
LARGE_RECTIFYING_ROTATION_DEG = 20.0


@dataclass(frozen=True)
class StereoRectification:
    left: str
    right: str
    width: int
    height: int
    fisheye: bool
    k_left: np.ndarray  # 3x3, OpenCV pixel convention
    d_left: np.ndarray  # OpenCV (k1 k2 p1 p2 k3 [k4 k5 k6]) or fisheye (k1..k4) coefficients
    k_right: np.ndarray
    d_right: np.ndarray
    right_from_left: np.ndarray  # 4x4: x_right = R x_left + T
    rect_from_left: np.ndarray  # 3x3 (OpenCV R1, ROS left rectification_matrix)
    rect_from_right: np.ndarray  # 3x3 (R2)
    projection_left: np.ndarray  # 3x4 (P1)
    projection_right: np.ndarray  # 3x4 (P2): [:, 3] = (-fx' * baseline, 0, 0) for a left-right pair
    disparity_to_depth: np.ndarray  # 4x4 (Q)
    baseline: float  # distance between the two optical centres, rig units
    metric: bool

    @property
    def horizontal(self) -> bool:
        """True when rectification lines the pair up along image rows (OpenCV chooses rows when
        the baseline is more horizontal than vertical in the left camera)."""
        return bool(abs(self.projection_right[0, 3]) >= abs(self.projection_right[1, 3]))

    @property
    def right_is_right(self) -> bool:
        """True when the second camera lies to the right of the first in the rectified frame
        (positive disparities, ROS's Tx < 0)."""
        return self.horizontal and bool(self.projection_right[0, 3] < 0)

    def rectifying_rotation_deg(self) -> tuple[float, float]:
        """How far each camera is turned into the rectified frame [deg]."""
        return tuple(float(np.degrees(np.linalg.norm(cv2.Rodrigues(r)[0])))
                     for r in (self.rect_from_left, self.rect_from_right))


def _pose(rig: RigCalibration, name: str) -> np.ndarray:
    if name not in rig.cameras:
        raise InputError(f"The calibration has no camera {name!r}: its cameras are "
                         f"{', '.join(rig.cameras)}.")
    return np.asarray(rig.cameras[name].cam_from_rig, dtype=np.float64)


def rectify_pair(rig: RigCalibration, left: str, right: str, alpha: float = 0.0
                 ) -> StereoRectification:
    """The rectification of cameras (left, right) of rig. alpha in [0, 1]: 0 keeps only valid
    pixels in the rectified images, 1 keeps every source pixel (cv2.stereoRectify's alpha; the
    fisheye `balance`). Raises InputError for a pair OpenCV cannot rectify together."""
    if left == right:
        raise InputError(f"A stereo pair needs two different cameras; both are {left!r}.")
    if not 0.0 <= alpha <= 1.0:
        raise InputError(f"alpha must lie in [0, 1] (0: only valid pixels, 1: all pixels), "
                         f"not {alpha}.")
    pose_left, pose_right = _pose(rig, left), _pose(rig, right)
    lens_left, lens_right = rig.cameras[left].intrinsics, rig.cameras[right].intrinsics
    (k1, d1, fisheye), (k2, d2, fisheye_right) = map(opencv_intrinsics, (lens_left, lens_right))
    if fisheye != fisheye_right:
        raise InputError(f"Cameras {left} ({lens_left.model}) and {right} ({lens_right.model}) "
                         "mix a fisheye and a pinhole lens model; OpenCV rectifies a pair of one "
                         "kind. Run `densecalib undistort` first (it writes pinhole cameras) and "
                         "export the pair from its output.")
    size = (int(lens_left.width), int(lens_left.height))
    if size != (int(lens_right.width), int(lens_right.height)):
        raise InputError(f"Cameras {left} ({size[0]}x{size[1]}) and {right} "
                         f"({lens_right.width}x{lens_right.height}) have "
                         "different image sizes; stereo rectification needs one size. Resize one "
                         "camera's images and calibrate again, or pick another pair.")
    d1, d2 = d1.reshape(-1, 1), d2.reshape(-1, 1)
    right_from_left = pose_right @ np.linalg.inv(pose_left)
    rot, t = right_from_left[:3, :3].copy(), right_from_left[:3, 3].reshape(3, 1).copy()
    baseline = float(np.linalg.norm(t))
    if baseline <= 1e-9 * max(1.0, float(np.abs(pose_left[:3, 3]).max())):
        raise InputError(f"Cameras {left} and {right} share one optical centre (no baseline): "
                         "such a pair sees no depth and cannot be rectified for stereo.")
    if fisheye:
        r1, r2, p1, p2, q = cv2.fisheye.stereoRectify(
            k1, d1, k2, d2, size, rot, t, flags=cv2.CALIB_ZERO_DISPARITY, newImageSize=size,
            balance=alpha, fov_scale=1.0)
    else:
        r1, r2, p1, p2, q, _, _ = cv2.stereoRectify(
            k1, d1, k2, d2, size, rot, t, flags=cv2.CALIB_ZERO_DISPARITY, alpha=alpha)
    focal = float(np.mean([k1[0, 0], k1[1, 1], k2[0, 0], k2[1, 1]]))
    if not _usable_view(p1, p2, size, focal):
        # OpenCV fits the rectified view to the undistorted image border; for a lens that sees
        # beyond 180 deg that border is at infinity and the fit degenerates (seen with
        # cv2.fisheye.stereoRectify). Its rotations stay right; take a centred view instead.
        log.warning("OpenCV's rectified view of %s and %s is degenerate (focal %.3g px, "
                    "principal point (%.4g, %.4g)); using a centred view of at most %g deg "
                    "across.", left, right, p1[0, 0], p1[0, 2], p1[1, 2], FALLBACK_MAX_FOV_DEG)
        p1, p2, q = _centred_view(r2 @ t, size, focal)
    return StereoRectification(
        left=left, right=right, width=int(size[0]), height=int(size[1]), fisheye=fisheye,
        k_left=k1, d_left=d1.ravel(), k_right=k2, d_right=d2.ravel(),
        right_from_left=right_from_left, rect_from_left=np.asarray(r1, np.float64),
        rect_from_right=np.asarray(r2, np.float64), projection_left=np.asarray(p1, np.float64),
        projection_right=np.asarray(p2, np.float64), disparity_to_depth=np.asarray(q, np.float64),
        baseline=baseline, metric=bool(rig.metric_scale))


def _usable_view(p1: np.ndarray, p2: np.ndarray, size: tuple[int, int], focal: float) -> bool:
    """Whether rectified projections are usable: finite, a focal within a factor 4 of the
    cameras' own, principal points inside the image."""
    w, h = size
    for p in (p1, p2):
        if not np.isfinite(p).all() or not focal / 4 <= p[0, 0] <= 4 * focal:
            return False
        if not (0 <= p[0, 2] <= w and 0 <= p[1, 2] <= h):
            return False
    return True


def _centred_view(t_rect: np.ndarray, size: tuple[int, int], focal: float
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """P1, P2, Q of a rectified view with the principal point at the image centre and the
    cameras' focal, widened to show at most FALLBACK_MAX_FOV_DEG across the width. t_rect: the
    right camera's translation in the rectified frame (along x, or y for a vertical pair)."""
    w, h = size
    f = max(focal, (w / 2.0) / np.tan(np.radians(FALLBACK_MAX_FOV_DEG) / 2.0))
    cx, cy = (w - 1) / 2.0, (h - 1) / 2.0
    p1 = np.array([[f, 0.0, cx, 0.0], [0.0, f, cy, 0.0], [0.0, 0.0, 1.0, 0.0]])
    p2 = p1.copy()
    t_rect = np.asarray(t_rect, dtype=np.float64).ravel()
    axis = 0 if abs(t_rect[0]) >= abs(t_rect[1]) else 1
    p2[axis, 3] = f * t_rect[axis]
    # Q maps (x, y, disparity, 1) to the point in the left rectified frame (homogeneous)
    q = np.array([[1.0, 0.0, 0.0, -cx], [0.0, 1.0, 0.0, -cy], [0.0, 0.0, 0.0, f],
                  [0.0, 0.0, -1.0 / t_rect[axis], 0.0]])
    return p1, p2, q


def stereo_pair(rig: RigCalibration, pair: Optional[Sequence[str]], alpha: float = 0.0,
                left_to_right: bool = True) -> StereoRectification:
    """Rectify the pair named (left, right), or, with pair None, the two cameras of a two-camera
    rig in left-to-right order. left_to_right: refuse a named pair whose second camera is not to
    the right of the first (ROS's stereo_image_proc takes only such pairs)."""
    if pair is None:
        if len(rig.cameras) != 2:
            raise InputError(f"The rig has {len(rig.cameras)} cameras "
                             f"({', '.join(rig.cameras)}): name the stereo pair with "
                             "--pair LEFT RIGHT.")
        a, b = rig.cameras
        rect = rectify_pair(rig, a, b, alpha)
        if rect.horizontal and not rect.right_is_right:
            rect = rectify_pair(rig, b, a, alpha)
        log.info("stereo pair: %s left, %s right", rect.left, rect.right)
    else:
        if len(pair) != 2:
            raise InputError(f"--pair takes two camera names (LEFT RIGHT), not {list(pair)}.")
        rect = rectify_pair(rig, pair[0], pair[1], alpha)
    if left_to_right and not rect.horizontal:
        raise InputError(f"Cameras {rect.left} and {rect.right} lie one above the other; ROS's "
                         "stereo_image_proc takes side-by-side pairs only. Use --format "
                         "opencv-stereo (OpenCV rectifies vertical pairs along columns).")
    if left_to_right and not rect.right_is_right:
        raise InputError(f"Camera {rect.right} lies to the left of {rect.left}: give the pair "
                         f"left camera first: --pair {rect.right} {rect.left} (node: "
                         f"stereo_pairs [{rect.right}, {rect.left}]).")
    turned = rect.rectifying_rotation_deg()
    if max(turned) > LARGE_RECTIFYING_ROTATION_DEG:
        log.warning("Rectification turns %s by %.1f deg and %s by %.1f deg: the two cameras are "
                    "far from parallel, so the rectified images keep little of their view.",
                    rect.left, turned[0], rect.right, turned[1])
    if not rect.metric:
        log.warning("The rig has no metric scale: the baseline (%.4g) and depths from this pair "
                    "are in arbitrary units. For metres: %s.", rect.baseline, HOW_TO_SCALE)
    return rect
