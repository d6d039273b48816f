"""Each camera against its own view at calibration time.

A calibration keeps one image per camera (`reference_views/<camera>.jpg`, the last frame set it
was made from, at most REFERENCE_MAX_SIDE_PX). A camera of a rig that stands still sees the same
scene later: matched with its reference view, the static background lands on the same pixels,
and a camera that was bumped sees it turned. The rotation that carries the reference's rays onto
the new image's rays (RANSAC over pairs of matches, 2 px at the camera's focal; things that moved
in the scene are its outliers) is how far the camera turned, and its size in pixels (the angle
times the focal) is held against the check's tolerance.

It needs no other camera, so it sees what the epipolar check (core.consistency) cannot: a pan
along the epipolar lines, and a camera of a two-camera rig. It assumes the rig stands still, and
blames a camera only beside one that stood still: when every judged camera turned alike (the same
rotation in the rig frame), the rig moved as a whole (a rig on a vehicle, a tripod knocked over
and set up again) and the reference views say nothing about the cameras; one camera judged alone
that turned is "it or the whole rig moved". A new image too different from the reference (night against day, a
rearranged scene) gives too few matches: that camera is not judged. A camera that only slid, or
was refocused, shows as a larger residual rather than a turn; these are left to the epipolar check.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Sequence

import cv2
import numpy as np

from .errors import InputError
from .types import CameraIntrinsics, RigCalibration

log = logging.getLogger(__name__)

REFERENCE_DIR = "reference_views"
REFERENCE_MAX_SIDE_PX = 1024  # the stored view: enough for SIFT, ~0.2-0.5 MB as JPEG
JPEG_QUALITY = 95
INLIER_PX = 2.0  # a match fits a rotation within this, at the camera's focal
MIN_INLIERS = 30  # below: the camera is not judged (too different from its reference)
RANSAC_ITERATIONS = 300


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


@dataclass
class ViewTurn:
    """A camera's turn since its reference view."""
    camera: str
    rotation_deg: float  # the angle of new_from_reference
    shift_px: float  # rotation_deg in pixels at the camera's focal
    num_matches: int
    num_inliers: int
    residual_px: float  # median distance of the inliers from the rotation, at the focal
    new_from_reference: np.ndarray  # 3x3 rotation, camera frame

    def turned(self, tolerance_px: float) -> bool:
        return self.shift_px > tolerance_px


def _unit_rays(intrinsics: CameraIntrinsics, xy_px: np.ndarray) -> np.ndarray:
    camera = intrinsics.to_pycolmap()
    rays = np.column_stack([camera.cam_from_img(xy_px), np.ones(len(xy_px))])
    return rays / np.linalg.norm(rays, axis=1, keepdims=True)


def _kabsch(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The rotation R minimising |R a_k - b_k| over rows."""
    u, _, vt = np.linalg.svd(a.T @ b)
    d = np.sign(np.linalg.det(vt.T @ u.T))
    return vt.T @ np.diag([1.0, 1.0, d]) @ u.T


def fit_rotation(rays_ref: np.ndarray, rays_new: np.ndarray, threshold_rad: float,
                 seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(new_from_reference 3x3, inlier mask): RANSAC over pairs of rays, then a least-squares
    refit on the inliers (twice: the refit can take in a few more)."""
    n = len(rays_ref)
    rng = np.random.default_rng(seed)
    best = np.zeros(n, bool)
    for _ in range(RANSAC_ITERATIONS):
        pick = rng.choice(n, 2, replace=False)
        rotation = _kabsch(rays_ref[pick], rays_new[pick])
        inliers = np.linalg.norm(rays_ref @ rotation.T - rays_new, axis=1) < threshold_rad
        if inliers.sum() > best.sum():
            best = inliers
    rotation = np.eye(3)
    for _ in range(2):
        if best.sum() < 3:
            break
        rotation = _kabsch(rays_ref[best], rays_new[best])
        best = np.linalg.norm(rays_ref @ rotation.T - rays_new, axis=1) < threshold_rad
    return rotation, best


def view_turn(name: str, reference: np.ndarray, image: np.ndarray,
              intrinsics: CameraIntrinsics, matcher=None) -> Optional[ViewTurn]:
    """How far camera `name` turned between its reference view and `image` (full size, as the
    intrinsics); None when they share fewer than MIN_INLIERS matches."""
    from .matching.sift import SiftMatcher

    matcher = matcher or SiftMatcher(max_image_side_px=REFERENCE_MAX_SIDE_PX)
    match_set = matcher.match([reference, image])
    pair = match_set.pairs.get((0, 1))
    if pair is None:
        return None
    src = np.flatnonzero(pair.target >= 0)
    if len(src) < MIN_INLIERS:
        return None
    # the stored view is downscaled: its COLMAP pixel coordinates scale with the image
    scale = np.array([intrinsics.width / reference.shape[1],
                      intrinsics.height / reference.shape[0]])
    rays_ref = _unit_rays(intrinsics, match_set.sites[0][src] * scale)
    rays_new = _unit_rays(intrinsics, match_set.sites[1][pair.target[src]])
    finite = np.isfinite(rays_ref).all(axis=1) & np.isfinite(rays_new).all(axis=1)
    rays_ref, rays_new = rays_ref[finite], rays_new[finite]  # outside the lens model: none
    if len(rays_ref) < MIN_INLIERS:
        return None
    focal_px = float(intrinsics.to_pycolmap().mean_focal_length())
    rotation, inliers = fit_rotation(rays_ref, rays_new, INLIER_PX / focal_px)
    if inliers.sum() < MIN_INLIERS:
        return None
    angle = float(np.arccos(np.clip((np.trace(rotation) - 1.0) / 2.0, -1.0, 1.0)))
    residual = np.linalg.norm(rays_ref[inliers] @ rotation.T - rays_new[inliers], axis=1)
    return ViewTurn(name, float(np.degrees(angle)), angle * focal_px, len(src),
                    int(inliers.sum()), float(np.median(residual)) * focal_px, rotation)


@dataclass
class ReferenceReport:
    turns: list[ViewTurn]  # the judged cameras, in the latest frame set
    not_judged: list[str]  # too few matches with their reference view
    tolerance_px: float
    rig_moved: bool = False  # every judged camera (two or more) turned, alike in the rig frame
    alone: bool = False  # one camera judged and it turned: it or the whole rig moved
    # of the frame sets compared (the latest two at most), how many in a row from the latest show
    # the turned cameras turned: a turn seen twice is no odd frame set
    turned_sets: int = 0

    @property
    def turned(self) -> list[str]:
        """The cameras that turned on their own (none when the whole rig moved, or when the one
        judged camera turned: nothing that stood still to hold it against)."""
        if self.rig_moved or self.alone:
            return []
        return [t.camera for t in self.turns if t.turned(self.tolerance_px)]

    def summary(self) -> str:
        if not self.turns:
            return "no camera shares enough matches with its reference view to be judged"
        if self.alone:
            t = self.turns[0]
            return (f"{t.camera} turned by {t.rotation_deg:.2f} deg, and no other camera could be "
                    "judged: it or the whole rig moved")
        if self.rig_moved:
            return (f"the rig moved as a whole (every camera turned alike, "
                    f"{min(t.rotation_deg for t in self.turns):.2f}-"
                    f"{max(t.rotation_deg for t in self.turns):.2f} deg): the reference views "
                    "cannot judge the cameras")
        turned = [t for t in self.turns if t.turned(self.tolerance_px)]
        if not turned:
            return (f"every judged camera still sees its reference view within "
                    f"{self.tolerance_px:g} px (largest turn "
                    f"{max(t.shift_px for t in self.turns):.2f} px)")
        return "turned since the calibration: " + ", ".join(
            f"{t.camera} {t.rotation_deg:.2f} deg ({t.shift_px:.1f} px)" for t in turned)


def compare_with_reference_views(rig: RigCalibration, camera_names: Sequence[str],
                                 frame_sets: Sequence[Sequence[np.ndarray]], references: dict,
                                 tolerance_px: float) -> ReferenceReport:
    """Every camera that has a reference view, in the latest frame set (in time order) against
    it, and the turned ones in the frame set before too (module docstring)."""
    reports = [_compare(rig, camera_names, fs, references, tolerance_px)
               for fs in frame_sets[-2:]]
    latest = reports[-1]
    if latest.turned:
        latest.turned_sets = 1
        if len(reports) == 2 and set(latest.turned) <= set(reports[0].turned):
            latest.turned_sets = 2
    return latest


def _compare(rig: RigCalibration, camera_names: Sequence[str], frame_set: Sequence[np.ndarray],
             references: dict, tolerance_px: float) -> ReferenceReport:
    turns, not_judged = [], []
    for name, image in zip(camera_names, frame_set):
        if name not in references or name not in rig.cameras:
            continue
        lens = rig.cameras[name].intrinsics
        if image.shape[:2] != (lens.height, lens.width):  # not the calibrated camera's size
            not_judged.append(name)
            continue
        turn = view_turn(name, references[name], image, rig.cameras[name].intrinsics)
        (turns.append(turn) if turn is not None else not_judged.append(name))
    # a camera is blamed only beside one that stood still; when every judged camera turned,
    # alike is the rig moving
    all_turned = bool(turns) and all(t.turned(tolerance_px) for t in turns)
    rig_moved = all_turned and len(turns) >= 2 and _turned_alike(rig, turns, tolerance_px)
    return ReferenceReport(turns, not_judged, tolerance_px, rig_moved,
                           alone=all_turned and len(turns) == 1)


def _turned_alike(rig: RigCalibration, turns: Sequence[ViewTurn], tolerance_px: float) -> bool:
    """Whether the turns are one rotation of the rig: each camera's turn expressed in the rig
    frame (cam_from_rig^T R cam_from_rig) within the tolerance of the first's."""
    if len(turns) < 2:
        return False
    in_rig = []
    for t in turns:
        r = rig.cameras[t.camera].cam_from_rig[:3, :3]
        in_rig.append(r.T @ t.new_from_reference @ r)
    for t, rotation in zip(turns[1:], in_rig[1:]):
        relative = in_rig[0].T @ rotation
        angle = float(np.arccos(np.clip((np.trace(relative) - 1.0) / 2.0, -1.0, 1.0)))
        focal_px = t.shift_px / max(np.radians(t.rotation_deg), 1e-12)
        if angle * focal_px > 2.0 * tolerance_px:
            return False
    return True


def check_verdict(report, views: Optional[ReferenceReport],
                  epipolar_verdict: Optional[str] = None) -> tuple[bool, str]:
    """(fits, one line) of an epipolar check (core.consistency.ConsistencyReport; its verdict,
    or `epipolar_verdict` in its place) together with the reference views' report (None: the
    calibration kept none)."""
    verdict = epipolar_verdict or report.verdict()
    if views is None:
        return report.fits, verdict
    if report.fits and views.turned:
        return False, (f"the calibration no longer fits: {views.summary()} (each camera's view "
                       "against the calibration's), though the epipolar figures still fit (a turn "
                       "along the epipolar lines, or a camera without a triple)")
    return report.fits and not views.turned, f"{verdict}; reference views: {views.summary()}"
