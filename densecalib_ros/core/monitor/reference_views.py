"""Each camera against its own view at calibration time.

A calibration keeps one image per camera (`reference_views/<camera>.jpg`, the last frame set it
was made from, at most REFERENCE_MAX_SIDE_PX: core.io.reference_view_files). A camera of a rig that
stands still sees the same scene later: matched with its reference view, the static background lands
on the same pixels. A camera that was bumped sees it turned, one refocused or zoomed sees it scaled
about the principal point. The model: the new image is the reference turned by a rotation and scaled
by a focal factor (fit_turn_and_zoom: RANSAC over pairs of matches, 2 px; what moved in the scene is
its outliers). The turn in pixels (its angle times the focal) and the zoom in pixels (at the
farthest corner) are held against the check's tolerance.

It needs no other camera, so it sees what the epipolar check (core.monitor.consistency) cannot: a
pan along the epipolar lines, a refocus of a camera of a two-camera rig. It assumes the rig stands
still, and blames a camera only beside one that stood still: when every judged camera changed and
turned alike (the same rotation in the rig frame), the rig moved as a whole (a rig on a vehicle, a
tripod knocked over and set up again; moving it nearer the scene also looks like a zoom: on the
real stereo rig set up again 20 deg turned, both cameras read +0.5 %) and the reference views say
nothing about the cameras; one camera judged alone that changed is "it or the whole rig moved". A
new image too different from the reference (night against day, a rearranged scene) gives too few
matches: that camera is not judged. A camera that only slid shows as a larger residual rather than
a turn; that is left to the epipolar check.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np

from ..io.reference_view_files import REFERENCE_MAX_SIDE_PX
from ..types import CameraIntrinsics, RigCalibration

INLIER_PX = 2.0  # a match fits a rotation within this, at the camera's focal
MIN_INLIERS = 30  # below: the camera is not judged (too different from its reference)
RANSAC_ITERATIONS = 300


@dataclass
class ViewTurn:
    """How a camera's view changed since its reference view: turned, and zoomed (its focal
    length changed: a refocus or zoom scales the image about the principal point)."""
    camera: str
    rotation_deg: float  # the angle of new_from_reference
    shift_px: float  # rotation_deg in pixels at the camera's focal
    focal_scale: float  # new focal / calibrated focal
    zoom_px: float  # how far that scale moves the image corner farthest from the principal point
    num_matches: int
    num_inliers: int
    residual_px: float  # median distance of the inliers from the model
    new_from_reference: np.ndarray  # 3x3 rotation, camera frame
    focal_px: float  # the calibrated mean focal, for angles in pixels

    def turned(self, tolerance_px: float) -> bool:
        return self.shift_px > tolerance_px

    def zoomed(self, tolerance_px: float) -> bool:
        return self.zoom_px > tolerance_px

    def describe(self, tolerance_px: float) -> str:
        what = []
        if self.turned(tolerance_px):
            what.append(f"turned {self.rotation_deg:.2f} deg ({self.shift_px:.1f} px)")
        if self.zoomed(tolerance_px):
            what.append(f"focal {100.0 * (self.focal_scale - 1.0):+.1f} % ({self.zoom_px:.1f} px "
                        "at the corners: refocused or zoomed)")
        return f"{self.camera} " + " and ".join(what)


def _unit_rays(intrinsics: CameraIntrinsics, xy_px: np.ndarray) -> np.ndarray:
    camera = intrinsics.to_pycolmap()
    rays = np.column_stack([camera.cam_from_img(xy_px), np.ones(len(xy_px))])
    return rays / np.linalg.norm(rays, axis=1, keepdims=True)


def _kabsch(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The rotation R minimising |R a_k - b_k| over rows."""
    u, _, vt = np.linalg.svd(a.T @ b)
    d = np.sign(np.linalg.det(vt.T @ u.T))
    return vt.T @ np.diag([1.0, 1.0, d]) @ u.T


def _angle_rad(rotation: np.ndarray) -> float:
    return float(np.arccos(np.clip((np.trace(rotation) - 1.0) / 2.0, -1.0, 1.0)))


def fit_turn_and_zoom(intrinsics: CameraIntrinsics, ref_px: np.ndarray, new_px: np.ndarray,
                      threshold_px: float = INLIER_PX, seed: int = 0
                      ) -> Optional[tuple[np.ndarray, float, np.ndarray]]:
    """(new_from_reference 3x3, focal scale, residual px per match) of matches ref_px -> new_px
    (COLMAP pixels of one camera, rays finite): the new image is the reference turned by the
    rotation and scaled about the principal point by the focal scale (any lens model: the focal
    scales the pixel offsets). RANSAC over pairs of matches (the scale from their distance
    ratio, the rotation from their rays with the scale taken off), then the two refined in turn
    on the inliers (residual below threshold_px). None when no sample gives a model."""
    camera = intrinsics.to_pycolmap()
    pp = np.array([camera.principal_point_x, camera.principal_point_y])
    rays_ref = _unit_rays(intrinsics, ref_px)

    def predict(rotation, scale):
        return pp + scale * (camera.img_from_cam(rays_ref @ rotation.T) - pp)

    def unzoomed_rays(px, scale):
        return _unit_rays(intrinsics, pp + (px - pp) / scale)

    rng = np.random.default_rng(seed)
    best, model = np.zeros(len(ref_px), bool), None
    for _ in range(RANSAC_ITERATIONS):
        pick = rng.choice(len(ref_px), 2, replace=False)
        spread = np.linalg.norm(ref_px[pick[0]] - ref_px[pick[1]])
        if spread < 20.0 * threshold_px:  # too close: the distance ratio is noise
            continue
        scale = np.linalg.norm(new_px[pick[0]] - new_px[pick[1]]) / spread
        rays_new = unzoomed_rays(new_px[pick], scale)
        if not np.isfinite(rays_new).all():
            continue
        rotation = _kabsch(rays_ref[pick], rays_new)
        inliers = np.linalg.norm(predict(rotation, scale) - new_px, axis=1) < threshold_px
        if inliers.sum() > best.sum():
            best, model = inliers, (rotation, scale)
    if model is None:
        return None
    rotation, scale = model
    for _ in range(3):
        if best.sum() < 3:
            break
        rays_new = unzoomed_rays(new_px[best], scale)
        finite = np.isfinite(rays_new).all(axis=1)
        rotation = _kabsch(rays_ref[best][finite], rays_new[finite])
        turned = camera.img_from_cam(rays_ref[best] @ rotation.T) - pp
        scale = float((turned * (new_px[best] - pp)).sum() / (turned * turned).sum())
        best = np.linalg.norm(predict(rotation, scale) - new_px, axis=1) < threshold_px
    return rotation, scale, np.linalg.norm(predict(rotation, scale) - new_px, axis=1)


def view_turn(name: str, reference: np.ndarray, image: np.ndarray,
              intrinsics: CameraIntrinsics, matcher=None) -> Optional[ViewTurn]:
    """How camera `name` turned and zoomed between its reference view and `image` (full size,
    as the intrinsics); None when they share fewer than MIN_INLIERS matches."""
    from ..method.matching.sift import SiftMatcher

    matcher = matcher or SiftMatcher(max_image_side_px=REFERENCE_MAX_SIDE_PX)
    match_set = matcher.match([reference, image])
    pair = match_set.pairs.get((0, 1))
    if pair is None:
        return None
    src = np.flatnonzero(pair.target >= 0)
    # the stored view is downscaled: its COLMAP pixel coordinates scale with the image
    ref_px = match_set.sites[0][src] * np.array([intrinsics.width / reference.shape[1],
                                                 intrinsics.height / reference.shape[0]])
    new_px = match_set.sites[1][pair.target[src]]
    finite = np.isfinite(_unit_rays(intrinsics, ref_px)).all(axis=1)
    ref_px, new_px = ref_px[finite], new_px[finite]  # outside the lens model: none
    if len(ref_px) < MIN_INLIERS:
        return None
    fit = fit_turn_and_zoom(intrinsics, ref_px, new_px)
    if fit is None:
        return None
    rotation, scale, residual_px = fit
    inliers = residual_px < INLIER_PX
    if inliers.sum() < MIN_INLIERS:
        return None
    camera = intrinsics.to_pycolmap()
    pp = np.array([camera.principal_point_x, camera.principal_point_y])
    corners = np.array([[0, 0], [intrinsics.width, 0], [0, intrinsics.height],
                        [intrinsics.width, intrinsics.height]], np.float64)
    focal_px = float(camera.mean_focal_length())
    angle = _angle_rad(rotation)
    return ViewTurn(name, float(np.degrees(angle)), angle * focal_px, scale,
                    abs(scale - 1.0) * float(np.linalg.norm(corners - pp, axis=1).max()),
                    len(src), int(inliers.sum()), float(np.median(residual_px[inliers])),
                    rotation, focal_px)


@dataclass
class ReferenceReport:
    turns: list[ViewTurn]  # the judged cameras, in the latest frame set
    not_judged: list[str]  # too few matches with their reference view
    tolerance_px: float
    rig_moved: bool = False  # every judged camera (two or more) changed, turned alike in the rig
    alone: bool = False  # one camera judged and it changed: it or the whole rig moved
    # of the frame sets compared (the latest two at most), how many in a row from the latest show
    # the changed cameras changed: a change seen twice is no odd frame set
    changed_sets: int = 0

    @property
    def changed(self) -> list[str]:
        """The cameras that turned or zoomed on their own (none when the whole rig moved, nor
        the one camera judged: nothing that stood still to hold it against)."""
        if self.rig_moved or self.alone:
            return []
        tol = self.tolerance_px
        return [t.camera for t in self.turns if t.turned(tol) or t.zoomed(tol)]

    def summary(self) -> str:
        if not self.turns:
            return "no camera shares enough matches with its reference view to be judged"
        tol = self.tolerance_px
        if self.alone:
            return (f"{self.turns[0].describe(tol)}, and no other camera could be judged: it or "
                    "the whole rig moved")
        if self.rig_moved:
            return (f"the rig moved as a whole (every camera changed, turned alike by "
                    f"{min(t.rotation_deg for t in self.turns):.2f}-"
                    f"{max(t.rotation_deg for t in self.turns):.2f} deg): the reference views "
                    "cannot judge the cameras")
        changed = [t for t in self.turns if t.camera in self.changed]
        if not changed:
            return (f"every judged camera still sees its reference view within {tol:g} px "
                    f"(largest turn {max(t.shift_px for t in self.turns):.2f} px, zoom "
                    f"{max(t.zoom_px for t in self.turns):.2f} px"
                    + (f"; {', '.join(self.not_judged)} not judged)" if self.not_judged else ")"))
        return "changed since the calibration: " + ", ".join(t.describe(tol) for t in changed)


def compare_with_reference_views(rig: RigCalibration, camera_names: Sequence[str],
                                 frame_sets: Sequence[Sequence[np.ndarray]], references: dict,
                                 tolerance_px: float) -> ReferenceReport:
    """Every camera that has a reference view, in the latest frame set (in time order) against
    it, and the changed ones in the frame set before too (module docstring)."""
    reports = [_compare(rig, camera_names, fs, references, tolerance_px)
               for fs in frame_sets[-2:]]
    latest = reports[-1]
    if latest.changed:
        latest.changed_sets = 1
        if len(reports) == 2 and set(latest.changed) <= set(reports[0].changed):
            latest.changed_sets = 2
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
    # a camera is blamed only beside one that stood still: when every judged camera changed and
    # turned alike, the rig moved (moving it also looks like a zoom: the scene comes nearer)
    all_changed = bool(turns) and all(t.turned(tolerance_px) or t.zoomed(tolerance_px)
                                      for t in turns)
    rig_moved = all_changed and len(turns) >= 2 and _turned_alike(rig, turns, tolerance_px)
    return ReferenceReport(turns, not_judged, tolerance_px, rig_moved,
                           alone=all_changed and len(turns) == 1)


def fits_per_frame_set_and_view(rig: RigCalibration, camera_names: Sequence[str],
                                match_sets: Sequence, frame_sets: Sequence[Sequence[np.ndarray]],
                                references: dict, tolerance_px: float) -> list[Optional[bool]]:
    """consistency.fits_per_frame_set, with a frame set in which a camera's view changed since
    the calibration (this module) counted as not fitting."""
    from .consistency import fits_per_frame_set

    fits = fits_per_frame_set(rig, camera_names, match_sets, tolerance_px)
    if not references:
        return fits
    return [False if _compare(rig, camera_names, frame_set, references, tolerance_px).changed
            else fit for fit, frame_set in zip(fits, frame_sets)]


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
        if _angle_rad(in_rig[0].T @ rotation) * t.focal_px > 2.0 * tolerance_px:
            return False
    return True


def check_verdict(report, views: Optional[ReferenceReport],
                  epipolar_verdict: Optional[str] = None,
                  cameras: Sequence[str] = (),
                  absent: Sequence[str] = ()) -> tuple[Optional[bool], str]:
    """(fits, one line) of an epipolar check (core.monitor.consistency.ConsistencyReport; its
    verdict, or `epipolar_verdict` in its place) together with the reference views' report (None:
    the calibration kept none). fits None: neither could tell. `cameras`: the calibrated cameras
    the images are of; one that neither judged (a covered or dark lens), like one of `absent`
    (calibrated, but no images of it given: a stolen or dead camera), keeps a fit from being
    declared: the calibration is vouched for only where it was seen."""
    fits, verdict = _combined_verdict(report, views, epipolar_verdict)
    seen = {c for f in report.figures for c in f.cameras} | (
        {t.camera for t in views.turns} if views is not None else set())
    unseen = [c for c in cameras if c not in seen]
    if not unseen and not absent:
        return fits, verdict
    notes = ([f"{', '.join(unseen)} could not be judged: too few matches with the other "
              "cameras and with its reference view (a covered, dark or defocused lens, or a "
              "changed scene)"] if unseen else []) + (
        [f"no images of {', '.join(absent)} were given (calibrated, so not judged)"]
        if absent else [])
    note = "; ".join(notes)
    if fits:
        return None, f"{note}; for the others: {verdict}"
    return fits, f"{verdict}; {note}"


def _combined_verdict(report, views: Optional[ReferenceReport],
                      epipolar_verdict: Optional[str]) -> tuple[Optional[bool], str]:
    if not report.figures:  # no camera pair shares enough matches: only the views can tell
        return _views_alone_verdict(views)
    verdict = epipolar_verdict or report.verdict()
    if views is None:
        return report.fits, verdict
    if report.fits and views.changed:
        return False, (f"the calibration no longer fits: {views.summary()} (each camera's view "
                       "against the calibration's), though the epipolar figures still fit (a turn "
                       "along the epipolar lines, or a camera without a triple)")
    return report.fits and not views.changed, f"{verdict}; reference views: {views.summary()}"


def _views_alone_verdict(views: Optional[ReferenceReport]) -> tuple[Optional[bool], str]:
    """check_verdict when the cameras share too few matches for any epipolar figure (a camera
    bumped so far that it lost its overlap, a scene that changed): a camera that changed against
    its view fails the calibration; every camera still seeing its view within the tolerance keeps
    it (a camera that only slid would go unseen); anything else cannot be told."""
    short = ("the cameras share too few matches for the epipolar figures (more frame sets, or a "
             "textured scene)")
    if views is None:
        return None, short
    if views.changed:
        return False, (f"the calibration no longer fits: {views.summary()} (each camera's view "
                       f"against the calibration's); {short}")
    if views.turns and not views.not_judged and not views.rig_moved and not views.alone:
        return True, (f"the calibration fits by the reference views: {views.summary()}; {short}")
    return None, f"{short}; reference views: {views.summary()}" + (
        f" ({', '.join(views.not_judged)} not judged)" if views.not_judged else "")
