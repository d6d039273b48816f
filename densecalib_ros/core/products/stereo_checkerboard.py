"""The real fisheye stereo set held against its own checkerboard (`densecalib bench-stereo`).

`ros_fisheye_stereo_checkerboard/stereo` holds 46 synchronised-ish pairs of an office with a
hand-held 6x8-corner checkerboard, and two target-based calibrations made from them
(`cam_stereo.yml` by cv::fisheye::stereoCalibrate; `left.yaml`/`right.yaml` by ROS's calibrator,
their lens model mislabelled plumb_bob). The bag beside it holds pairs 0, 2, ..., 38, so the odd
pairs are never seen by a calibration made from the bag. On those held-out pairs, a calibration is
judged by what its users do with a stereo pair:
- rectification: the board's corners, undistorted and rectified with the pair's R and P, should
  share a row; the row error is in units of the rectified focal length (mrad), so calibrations
  rectifying to different focals compare;
- measurement: the corners triangulated with the rig should be one board square apart;
- its own uncertainty: each camera's intrinsics against each target-based calibration's, over
  the sigmas the calibration gives (|error| / sigma), beside how far the two references stand
  apart from each other (about 1 % in focal length: neither is exact).
Medians over pairs of each pair's median: the board is hand-held, and in a few pairs the two
images were not taken together (every calibration shows those alike).
"""
from __future__ import annotations

from pathlib import Path
from typing import Optional

import cv2
import numpy as np

from ..errors import InputError
from ..metrics import mean_focal_px, principal_point_px
from ..method.uncertainty import intrinsics_error_sigma_ratios
from ..types import CameraIntrinsics, RigCalibration, RigCamera
from .stereo import rectify_pair
from .triangulation import triangulate

BOARD_CORNERS = (6, 8)  # inner corners per row, rows (as cv2.findChessboardCorners takes them)
NUM_PAIRS = 46
LEFT, RIGHT = "stereo_left", "stereo_right"


def board_corners(path: Path) -> Optional[np.ndarray]:
    """(48, 2) sub-pixel inner corners of the board in an image, or None."""
    img = cv2.imread(str(path), cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise InputError(f"Cannot read {path}.")
    found, corners = cv2.findChessboardCorners(
        img, BOARD_CORNERS, cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
    if not found:
        return None
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-3)
    return cv2.cornerSubPix(img, corners, (5, 5), (-1, -1), criteria).reshape(-1, 2)


def corner_pairs(folder: Path, indices) -> list[tuple[np.ndarray, np.ndarray]]:
    """(left corners, right corners) of the pairs `indices` where both images show the board,
    in the same corner order."""
    out = []
    for i in indices:
        left = board_corners(folder / f"left-{i:04d}.png")
        right = board_corners(folder / f"right-{i:04d}.png")
        if left is None or right is None:
            continue
        if np.dot(left[-1] - left[0], right[-1] - right[0]) < 0:
            right = right[::-1]  # the detector may start from the other end
        out.append((left, right))
    return out


def _target_file(folder: Path):
    """A reader of cam_stereo.yml's entries (matrices, or plain sequences such as D1)."""
    fs = cv2.FileStorage(str(folder / "cam_stereo.yml"), cv2.FILE_STORAGE_READ)
    if not fs.isOpened():
        raise InputError(f"Cannot open {folder / 'cam_stereo.yml'}.")

    def node(key):
        n = fs.getNode(key)
        return np.array([n.at(i).real() for i in range(n.size())]) if n.isSeq() else n.mat()
    return node


def target_calibration(folder: Path) -> RigCalibration:
    """cam_stereo.yml as a metric rig (its T is in the board's units)."""
    node = _target_file(folder)

    right_from_left = np.eye(4)
    right_from_left[:3, :3], right_from_left[:3, 3] = node("R"), node("T").ravel()
    return RigCalibration(LEFT, {
        LEFT: RigCamera(LEFT, _fisheye(node("K1"), node("D1")), np.eye(4)),
        RIGHT: RigCamera(RIGHT, _fisheye(node("K2"), node("D2")), right_from_left)},
        metric_scale=True)


def _fisheye(k, d) -> CameraIntrinsics:
    """A camera of the set from OpenCV's K and fisheye D (COLMAP's pixels: cx, cy + 0.5)."""
    return CameraIntrinsics("OPENCV_FISHEYE", 800, 503,
                            np.array([k[0, 0], k[1, 1], k[0, 2] + 0.5, k[1, 2] + 0.5, *d]))


def reference_intrinsics(folder: Path, target: RigCalibration
                         ) -> dict[str, dict[str, CameraIntrinsics]]:
    """The two target-based calibrations' intrinsics (target: cam_stereo.yml's,
    target_calibration): reference name -> camera -> intrinsics."""
    ros = {cam: _fisheye(*ros_yaml_camera(folder / f"{side}.yaml")[:2])
           for cam, side in ((LEFT, "left"), (RIGHT, "right"))}
    return {"cam_stereo.yml": {n: c.intrinsics for n, c in target.cameras.items()},
            "left/right.yaml": ros}


def references_apart(references: dict) -> dict[str, dict[str, float]]:
    """Camera -> how far the two references' intrinsics stand apart: focal (%), principal
    point (px, the larger axis)."""
    a, b = references.values()
    return {n: {"focal_pct": 100.0 * abs(mean_focal_px(a[n]) / mean_focal_px(b[n]) - 1.0),
                "pp_px": float(np.abs(principal_point_px(a[n]) - principal_point_px(b[n])).max())}
            for n in a}


def _rectify(corners: np.ndarray, k, d, r, p) -> np.ndarray:
    return cv2.fisheye.undistortPoints(corners.reshape(-1, 1, 2), np.asarray(k, float),
                                       np.asarray(d, float).reshape(-1, 1), R=np.asarray(r, float),
                                       P=np.asarray(p, float)).reshape(-1, 2)


def row_error_mrad(pairs, left: tuple, right: tuple) -> float:
    """Median over pairs of the median |row difference| of the rectified corners, over the
    rectified focal length [mrad]; left, right: (K, D, R, P) of each camera (fisheye)."""
    per_pair = [np.median(np.abs(_rectify(cl, *left)[:, 1] - _rectify(cr, *right)[:, 1]))
                for cl, cr in pairs]
    return float(np.median(per_pair) / np.asarray(left[3])[0, 0] * 1000.0)


def rig_row_error_mrad(pairs, rig: RigCalibration) -> float:
    """row_error_mrad of a rig's own stereo rectification (core.products.stereo, as exported)."""
    rect = rectify_pair(rig, LEFT, RIGHT)
    return row_error_mrad(pairs, (rect.k_left, rect.d_left, rect.rect_from_left,
                                  rect.projection_left),
                          (rect.k_right, rect.d_right, rect.rect_from_right,
                           rect.projection_right))


def square_size(pairs, rig: RigCalibration) -> tuple[float, float]:
    """(median over pairs of the median distance between neighbouring corners triangulated with
    the rig, in its units; median reprojection error [px])."""
    sizes, errors = [], []
    for cl, cr in pairs:
        points = [triangulate(rig, {LEFT: a, RIGHT: b}) for a, b in zip(cl, cr)]
        grid = np.array([p.xyz_rig for p in points]).reshape(BOARD_CORNERS[1], BOARD_CORNERS[0], 3)
        steps = np.concatenate([np.linalg.norm(np.diff(grid, axis=1), axis=2).ravel(),
                                np.linalg.norm(np.diff(grid, axis=0), axis=2).ravel()])
        sizes.append(np.median(steps))
        errors.append(np.median([max(p.residuals_px.values()) for p in points]))
    return float(np.median(sizes)), float(np.median(errors))


def ros_yaml_camera(path: Path) -> tuple:
    """(K, D, R, P) of a camera_info YAML (its distortion read as fisheye k1..k4)."""
    import yaml

    info = yaml.safe_load(Path(path).read_text())

    def mat(key, shape):
        return np.array(info[key]["data"], dtype=np.float64).reshape(shape)
    return (mat("camera_matrix", (3, 3)), mat("distortion_coefficients", (-1,)),
            mat("rectification_matrix", (3, 3)), mat("projection_matrix", (3, 4)))


def evaluate(folder: Path, rig: RigCalibration, indices=range(1, NUM_PAIRS, 2)) -> dict:
    """The figures of a calibration `rig` of the pair and of the set's two target-based
    calibrations, on the pairs `indices` (default: the odd ones, which the bag lacks)."""
    pairs = corner_pairs(folder, indices)
    if not pairs:
        raise InputError(f"No pair of {folder} shows the whole board in both images.")
    target = target_calibration(folder)
    node = _target_file(folder)  # its own rectification, as its tool wrote it
    target_rect = [(node(f"K{i}"), node(f"D{i}"), node(f"R{i}"), node(f"P{i}")) for i in (1, 2)]
    ours_size, ours_px = square_size(pairs, rig)
    target_size, target_px = square_size(pairs, target)
    references = reference_intrinsics(folder, target)
    return {
        "pairs": len(pairs),
        "row_error_mrad": {"ours": rig_row_error_mrad(pairs, rig),
                           "cam_stereo.yml": row_error_mrad(pairs, *target_rect),
                           "left/right.yaml": row_error_mrad(
                               pairs, ros_yaml_camera(folder / "left.yaml"),
                               ros_yaml_camera(folder / "right.yaml"))},
        "square_size": {"ours": ours_size, "cam_stereo.yml": target_size},
        "corner_reprojection_px": {"ours": ours_px, "cam_stereo.yml": target_px},
        "metric": bool(rig.metric_scale),
        "error_sigma_ratios": {name: intrinsics_error_sigma_ratios(rig, cams)
                               for name, cams in references.items()},
        "references_apart": references_apart(references),
    }
