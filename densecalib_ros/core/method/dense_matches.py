"""Dense, sub-pixel correspondences for the last refinement, guided by the found rig.

Why: keypoint matches find the rig but are too few and too biased to pin down what a camera's
principal point and focal length do to its rotation. A SIFT keypoint is where a blob's scale-space
extremum lies, and across a wide baseline the same blob's extremum moves with the perspective,
off the true correspondence in directions the adjustment absorbs into a wrong principal point. The
images themselves are unbiased: a patch around a point of one image, warped affinely onto the
other and aligned there photometrically (Lucas-Kanade), lands several times closer
(docs/design-notes.md, Dense correspondences).

How: per frame set and reference camera a, well-textured points spread over the image (Shi-Tomasi
corners, at most GRID_POINTS_PER_IMAGE); for every other camera b, each point's position is
predicted by a local affine map fitted to the nearest keypoint matches of the pair (so no depth
is needed), then refined by affine Lucas-Kanade with gain and offset on a PATCH_HALF_PX patch.
A refined position is kept when the patches agree (normalised cross-correlation >= MIN_NCC), it
moved at most MAX_SHIFT_PX from the prediction, aligning back from it returns to the reference
point (MAX_ROUND_TRIP_PX), and it lies within MAX_EPIPOLAR_PX of the epipolar line of the found
cameras. One track per reference point: its pixel in a and in every camera
where it was found. Frame sets beyond the few densified whole give reference points only where
they show something new: what moves through the view, seen by several cameras at once."""
from __future__ import annotations

import logging
import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Callable, Optional, Sequence

import cv2
import numpy as np
from scipy.spatial import cKDTree

from ..parallel import available_cores
from ..progress import check_stop
from ..types import Tracks
from .incremental import MIN_REGISTRATION_POINTS
from .matching.utils import to_gray
from .dense_frame_sets import densified_frame_sets, later_frame_sets
from .patch_alignment import align
from .reconstruction import SfMState
from .view_graph import connected_components, shared_counts

log = logging.getLogger(__name__)

# Reference points per image: a track every ~22 px at 1024x768; more add time, not accuracy,
# once each camera's principal point is held to a fraction of a pixel.
GRID_POINTS_PER_IMAGE = 1500
# Alignments per frame set (reference points x other cameras): larger rigs take fewer points per
# image, since each point is then seen by more cameras (10 cameras: ~670 points per image).
MAX_ALIGNMENTS = 60000
MIN_CORNER_QUALITY = 0.01  # Shi-Tomasi quality level (fraction of the image's best corner)
PATCH_HALF_PX = 7  # 15x15 patches: large enough to align, small enough to stay affine
LK_ITERATIONS = 12
# A patch whose last step moved none of its pixels by more than this has converged and leaves the
# iterations: its steps shrink by about half each time, so the ones left would move it by about as
# much again, a hundredth of the dense correspondences' noise (0.06-0.12 px).
CONVERGED_STEP_PX = 1e-3
# The normalised cross-correlation of the aligned patches below which a position is not trusted
# (sensor noise alone keeps well-textured patches above 0.95).
MIN_NCC = 0.85
# Movement from the prediction beyond which the alignment is taken to have slipped to another
# structure (the local affine prediction is off by a few px at most on a continuous surface).
MAX_SHIFT_PX = 4.0
# Aligned from a to b and back, a right correspondence returns within LK's own precision.
MAX_ROUND_TRIP_PX = 0.2
AFFINE_NEIGHBOURS = 8  # keypoint matches the local prediction is fitted to
MIN_AFFINE_NEIGHBOURS = 4
# Neighbours farther than this (px, in the reference image) do not predict a point: across an
# occlusion or onto another surface the affine map does not hold.
MAX_NEIGHBOUR_DISTANCE_PX = 60.0
# Distance from the found cameras' epipolar line (px): the found rig fits its own matches to a
# fraction of a pixel, so a right correspondence lies within a few px of it.
MAX_EPIPOLAR_PX = 3.0
# MAX_SHIFT_PX, MAX_NEIGHBOUR_DISTANCE_PX (and the neighbours' weights) and MAX_EPIPOLAR_PX are
# pixels of an image matched at its own size: the predictions come from keypoint matches, whose
# errors (and spacing) in a larger image, matched downscaled (config.max_image_side_px), grow
# with the scale. Each is multiplied by the camera's px_scale (keypoint_px_scale); the patches
# and MAX_ROUND_TRIP_PX, LK's own precision on the image's pixels, are not.
NEIGHBOUR_WEIGHT_PX = 20.0  # a neighbour this far weighs half as much as one at the point


def keypoint_px_scale(image_sizes: Sequence[tuple[int, int]], max_image_side_px: Optional[int]
                      ) -> np.ndarray:
    """Per camera, how many of its pixels one pixel of the image its keypoints were matched
    on spans: its long side over max_image_side_px where larger, else 1 (image_sizes: (w, h))."""
    long_sides = np.array([max(w, h) for w, h in image_sizes], float)
    if not max_image_side_px:
        return np.ones(len(long_sides))
    return np.maximum(long_sides / float(max_image_side_px), 1.0)


def reference_points(gray: np.ndarray, max_points: int = GRID_POINTS_PER_IMAGE,
                     mask: Optional[np.ndarray] = None) -> np.ndarray:
    """(N, 2) COLMAP px: Shi-Tomasi corners spread over the image (min distance from the image
    area per point), away from the border by the patch size. mask: bool (H, W), True = ignored."""
    h, w = gray.shape
    spacing = 0.5 * np.sqrt(h * w / max_points)
    allowed = np.zeros((h, w), np.uint8)
    b = PATCH_HALF_PX + 2
    allowed[b:h - b, b:w - b] = 255
    if mask is not None:
        allowed[mask] = 0
    corners = cv2.goodFeaturesToTrack(gray, max_points, MIN_CORNER_QUALITY, spacing,
                                      mask=allowed, blockSize=7)
    if corners is None:
        return np.zeros((0, 2))
    return corners.reshape(-1, 2).astype(np.float64) + 0.5


def local_affine(query: np.ndarray, src: np.ndarray, dst: np.ndarray, px_scale: float = 1.0
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For query points (N, 2) of the source image: the predicted target position (N, 2), the
    local affine Jacobian (N, 2, 2) and valid (N,), from a weighted least-squares affine fit to the
    AFFINE_NEIGHBOURS nearest correspondences src -> dst within MAX_NEIGHBOUR_DISTANCE_PX (times
    the source camera's px_scale)."""
    n = len(query)
    pred, jac, valid = np.full((n, 2), np.nan), np.zeros((n, 2, 2)), np.zeros(n, bool)
    if len(src) < MIN_AFFINE_NEIGHBOURS or n == 0:
        return pred, jac, valid
    k = min(AFFINE_NEIGHBOURS, len(src))
    dist, nn = cKDTree(src).query(query, k=k)
    dist, nn = dist.reshape(n, k), nn.reshape(n, k)
    near = dist <= MAX_NEIGHBOUR_DISTANCE_PX * px_scale
    enough = near.sum(axis=1) >= MIN_AFFINE_NEIGHBOURS
    # Weights fall with distance (the map is local); far neighbours weigh nothing.
    wgt = np.where(near, 1.0 / (1.0 + (dist / (NEIGHBOUR_WEIGHT_PX * px_scale)) ** 2), 0.0)
    P = src[nn] - query[:, None, :]
    X = np.concatenate([P, np.ones((n, k, 1))], axis=2)  # (n, k, 3)
    Y = dst[nn]
    XtW = X.transpose(0, 2, 1) * wgt[:, None, :]
    G = XtW @ X + 1e-9 * np.eye(3)[None]
    ok = enough & (np.linalg.cond(G) < 1e8)
    sol = np.zeros((n, 3, 2))
    sol[ok] = np.linalg.solve(G[ok], XtW[ok] @ Y[ok])
    jac[ok] = sol[ok, :2, :].transpose(0, 2, 1)
    pred[ok] = sol[ok, 2, :]
    det = np.linalg.det(jac)
    valid = ok & (det > 0.1) & (det < 10.0)
    return pred, jac, valid


def with_gradients(gray: np.ndarray) -> np.ndarray:
    """float32 (H, W, 3): the image and its x and y gradients (central differences) as
    align_patches samples them: one position's interpolation weights serve all three. Filled a
    channel at a time: one gradient image at a time is held beside it."""
    out = np.empty(gray.shape + (3,), np.float32)
    out[..., 0] = gray
    out[..., 1] = cv2.Sobel(gray, cv2.CV_32F, 1, 0, ksize=1, scale=0.5)
    out[..., 2] = cv2.Sobel(gray, cv2.CV_32F, 0, 1, ksize=1, scale=0.5)
    return out


def align_patches(gray_a: np.ndarray, gray_b: np.ndarray, xy_a: np.ndarray, xy_b: np.ndarray,
                  jac: np.ndarray, b_and_gradients: Optional[np.ndarray] = None
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Affine Lucas-Kanade (Gauss-Newton on translation, the 2x2 map, gain and offset) of the
    patches of image a around xy_a (N, 2) onto image b, starting at xy_b with the map jac
    (core.method.patch_alignment). COLMAP px in, COLMAP px out: (refined xy_b (N, 2),
    normalised cross-correlation (N,), the refined map (N, 2, 2)). b_and_gradients:
    with_gradients(gray_b), where the caller aligns onto image b more than once."""
    off = np.stack(np.meshgrid(np.arange(-PATCH_HALF_PX, PATCH_HALF_PX + 1),
                               np.arange(-PATCH_HALF_PX, PATCH_HALF_PX + 1)), -1
                   ).reshape(-1, 2).astype(np.float32)
    if b_and_gradients is None:
        b_and_gradients = with_gradients(gray_b)
    # OpenCV pixel positions (pixel centres at integers) in the kernel.
    t = np.array(xy_b, np.float64).reshape(-1, 2) - 0.5
    maps = np.array(jac, np.float64).reshape(-1, 2, 2)
    ncc = align(np.asarray(gray_a, np.float32)[:, :, None], b_and_gradients,
                (np.asarray(xy_a, np.float64) - 0.5).astype(np.float32).reshape(-1, 2), t, maps,
                off, LK_ITERATIONS, CONVERGED_STEP_PX, float(PATCH_HALF_PX))
    return t + 0.5, ncc, maps


def epipolar_distance_px(state: SfMState, a: int, b: int, xy_a: np.ndarray,
                         xy_b: np.ndarray) -> np.ndarray:
    """(N,) distance (px of camera b, small-angle) of each xy_b from the epipolar plane of xy_a
    under the state's cameras (lens distortion included: rays, not pixels)."""
    Ta, Tb = state.cam_from_world[a], state.cam_from_world[b]
    T_ba = Tb @ np.linalg.inv(Ta)
    R, t = T_ba[:3, :3], T_ba[:3, 3]
    ray_a = state.camera(a).to_pycolmap().cam_ray_from_img(xy_a)
    ray_b = state.camera(b).to_pycolmap().cam_ray_from_img(xy_b)
    normal = np.cross(t[None, :], ray_a @ R.T)
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
    ray_b = ray_b / np.linalg.norm(ray_b, axis=1, keepdims=True)
    focal_b = float(state.camera(b).to_pycolmap().mean_focal_length())
    return focal_b * np.abs(np.sum(normal * ray_b, axis=1))


@dataclass
class FirstPass:
    """dense_tracks' first pass, which needs the images and the keypoint matches but not the rig:
    for each densified frame set (times), the reference points of each camera (points: camera ->
    (n, 2) COLMAP px) and, per pair (a, b) of `cameras`, a's points aligned onto b and back to
    where they started (returned: (a, b) -> (indices into points[a], positions in b (n, 2))),
    not yet checked against the rig's epipolar geometry."""

    cameras: tuple
    times: np.ndarray
    later: dict  # later_frame_sets': the frame sets densified on part of their images, shares
    points: list
    returned: list

    def share(self, time: int) -> float:
        """The share of whole images frame set `time` is densified on (AlignmentCount's unit)."""
        return self.later.get(int(time), 1.0)


class AlignmentCount:
    """Directed alignments done (one camera's points aligned onto another image, or back from
    it: _aligned_both_ways' steps; a step on part of the image, a later frame set's new
    content, counts its share), counted from any thread: how far dense work run ahead got."""

    def __init__(self) -> None:
        self._lock, self.done = threading.Lock(), 0.0

    def add(self, share: float = 1.0) -> None:
        with self._lock:
            self.done += share


def points_per_image(num_cameras: int) -> int:
    """Reference points per image where this many cameras align them (MAX_ALIGNMENTS)."""
    return min(GRID_POINTS_PER_IMAGE, MAX_ALIGNMENTS // max(num_cameras * (num_cameras - 1), 1))


# A camera left with fewer dense observations than this is not refined on the images (nor the
# rig): a handful of correspondences would pull its intrinsics wherever their few errors point.
MIN_CAMERA_OBSERVATIONS = 50


class TooFewDenseCorrespondences(Exception):
    """Some registered camera keeps fewer than MIN_CAMERA_OBSERVATIONS dense observations once
    triangulated and gated (thin_cameras): counts is camera name -> its observations."""

    def __init__(self, counts: dict):
        super().__init__(", ".join(f"{name} ({n})" for name, n in counts.items()))
        self.counts = counts


def thin_cameras(state: SfMState, camera_names: Sequence[str]) -> dict:
    """Camera name -> dense observations of the registered cameras of `state` (on the dense
    tracks, triangulated) that keep fewer than MIN_CAMERA_OBSERVATIONS."""
    per_camera = state.registered_active()[state.point_mask()].sum(axis=0)
    return {camera_names[c]: int(per_camera[c]) for c in state.registered()
            if per_camera[c] < MIN_CAMERA_OBSERVATIONS}


def dense_groups(state: SfMState, camera_names: Sequence[str]) -> list[list[str]]:
    """The registered cameras of `state` (on the dense tracks, triangulated) in the groups its
    points connect: two cameras are linked where they observe MIN_REGISTRATION_POINTS points in
    common (fewer could not register one on the other's points). One group where the points tie
    the whole rig together; more where they leave groups without such a link, whose poses
    relative to one another the dense correspondences then do not determine."""
    reg = state.registered()
    shared = shared_counts(state.registered_active()[state.point_mask()][:, reg])
    edges = [(i, j) for i in range(len(reg)) for j in range(i + 1, len(reg))
             if shared[i, j] >= MIN_REGISTRATION_POINTS]
    return [[camera_names[reg[k]] for k in group]
            for group in connected_components(len(reg), edges)]


class Cancelled(Exception):
    """Dense alignments run ahead were called off (first_pass's or dense_tracks' `cancelled`)."""


def first_pass(frame_sets: Sequence[Sequence[np.ndarray]], cameras: Sequence[int],
               keypoint_tracks: Tracks, masks: Optional[Sequence] = None,
               cancelled: Optional[threading.Event] = None,
               thread_start: Optional[Callable[[], None]] = None,
               px_scale: Optional[np.ndarray] = None,
               counted: Optional[AlignmentCount] = None,
               later: Optional[dict] = None) -> FirstPass:
    """dense_tracks' first pass among `cameras` (FirstPass). It does not depend on the rig, so a
    calibration runs it ahead, while the rig is still being found (core.pipeline): cancelled,
    set, stops it between pairs (Cancelled); thread_start runs first in each of its threads.
    px_scale: per camera, keypoint_px_scale (None: 1 for every camera); counted: where to count
    its alignments (AlignmentCount), or None; later: later_frame_sets' (None: found here)."""
    if later is None:
        later = later_frame_sets(frame_sets, keypoint_tracks)
    cameras = tuple(int(c) for c in cameras)
    observed = keypoint_tracks.observed()
    times, all_points, all_returned = [], [], []
    for time, regions in densified_frame_sets(frame_sets, keypoint_tracks, later):
        grays = _grays(frame_sets, int(time), cameras)
        in_set = keypoint_tracks.time_index == time
        points = {a: reference_points(grays[a], points_per_image(len(cameras)),
                                      mask=_ignored(masks, regions, a))
                  for a in cameras}
        seeds = _pair_seeds(keypoint_tracks, observed, in_set, cameras)
        none = np.zeros(0, np.int64)
        times.append(time)
        all_points.append(points)
        all_returned.append(_aligned_both_ways(grays, cameras, points, seeds,
                                               {k: none for k in seeds}, cancelled,
                                               thread_start, px_scale, counted,
                                               later.get(time, 1.0)))
    return FirstPass(cameras, np.array(times, np.int64), later, all_points, all_returned)


def dense_tracks(frame_sets: Sequence[Sequence[np.ndarray]], state: SfMState,
                 keypoint_tracks: Tracks, masks: Optional[Sequence] = None,
                 ahead: Optional[FirstPass] = None,
                 cancelled: Optional[threading.Event] = None,
                 thread_start: Optional[Callable[[], None]] = None,
                 px_scale: Optional[np.ndarray] = None,
                 counted: Optional[AlignmentCount] = None) -> Tracks:
    """Guided dense tracks (module docstring) of the registered cameras of `state`, predicted from
    keypoint_tracks (the keypoint matches as tracks, with their frame set index).

    Two passes: the first predicts from the keypoint matches alone, the second, for the points
    not yet found, also from the dense correspondences the first found, which reach the parts of
    the images between sparse keypoints (a wider baseline's pairs share few of them). ahead: the
    first pass as first_pass gave it on the same frame sets, matches and masks, used where it
    was run among the registered cameras (else it runs here); cancelled, thread_start, px_scale,
    counted: as first_pass's."""
    C = state.num_cameras
    registered = tuple(int(c) for c in state.registered())
    if ahead is None or ahead.cameras != registered:  # the same frame sets among fewer cameras
        ahead = first_pass(frame_sets, registered, keypoint_tracks, masks, cancelled,
                           thread_start, px_scale, counted, None if ahead is None else ahead.later)
    observed = keypoint_tracks.observed()
    parts = []
    for time, points, returned in zip(ahead.times, ahead.points, ahead.returned):
        grays = _grays(frame_sets, int(time), registered)
        in_set = keypoint_tracks.time_index == time
        seeds = _pair_seeds(keypoint_tracks, observed, in_set, registered)
        found = {k: (np.zeros(0, np.int64), np.zeros((0, 2))) for k in seeds}
        for second in (False, True):
            if second:
                returned = _aligned_both_ways(grays, registered, points, seeds,
                                              {k: v[0] for k, v in found.items()}, cancelled,
                                              thread_start, px_scale, counted,
                                              ahead.share(time))
            new = {(a, b): _on_epipolar_lines(state, a, b, points[a], *returned[a, b],
                                              _scale(px_scale, b))
                   for (a, b) in seeds}
            seeds = {(a, b): (np.concatenate([seeds[a, b][0], points[a][new[a, b][0]],
                                              new[b, a][1]]),
                              np.concatenate([seeds[a, b][1], new[a, b][1],
                                              points[b][new[b, a][0]]]))
                     for (a, b) in seeds}
            found = {k: (np.concatenate([found[k][0], new[k][0]]),
                         np.concatenate([found[k][1], new[k][1]])) for k in seeds}
        for a in registered:
            xy = np.full((len(points[a]), C, 2), np.nan)
            xy[:, a] = points[a]
            for b in registered:
                if b != a:
                    idx, refined = found[a, b]
                    xy[idx, b] = refined
            seen = (~np.isnan(xy[..., 0])).sum(axis=1) >= 2
            n = int(seen.sum())
            parts.append(Tracks(xy[seen], np.full(n, 2, np.int32), np.zeros(n),
                                np.full(n, int(time), np.int32)))
    return Tracks.concatenate(parts, C)


def _pair_seeds(keypoint_tracks: Tracks, observed: np.ndarray, in_set: np.ndarray,
                cameras: Sequence[int]) -> dict:
    """(a, b) -> (a's pixels (n, 2), b's pixels (n, 2)) of the keypoint matches of the pair in
    the frame set in_set selects: what the local affine predictions start from."""
    return {(a, b): (keypoint_tracks.xy_px[rows, a], keypoint_tracks.xy_px[rows, b])
            for a in cameras for b in cameras if a != b
            for rows in [np.flatnonzero(in_set & observed[:, a] & observed[:, b])]}


def _ignored(masks: Optional[Sequence], regions: Optional[list], c: int) -> Optional[np.ndarray]:
    """Camera c's pixels no reference point may take: its mask's, and outside its region."""
    mask = None if masks is None else masks[c]
    if regions is None or regions[c] is None:
        return mask
    outside = ~regions[c]
    return outside if mask is None else outside | mask


def _grays(frame_sets: Sequence[Sequence[np.ndarray]], time: int, cameras: Sequence[int]
           ) -> dict:
    return {c: to_gray(np.asarray(frame_sets[time][c])).astype(np.float32) for c in cameras}


def _scale(px_scale: Optional[np.ndarray], c: int) -> float:
    return 1.0 if px_scale is None else float(px_scale[c])


def _aligned_both_ways(grays: dict, cameras: Sequence[int], points: dict, seeds: dict,
                       skip: dict, cancelled: Optional[threading.Event] = None,
                       thread_start: Optional[Callable[[], None]] = None,
                       px_scale: Optional[np.ndarray] = None,
                       counted: Optional[AlignmentCount] = None, share: float = 1.0) -> dict:
    """(a, b) -> (indices into points[a], positions in b (n, 2)): camera a's points, but those
    in skip[a, b], predicted from seeds[a, b] and aligned onto b (_aligned), that align back
    onto where they started (_returned); each of the steps is counted in `counted` (or not), as
    `share` of a whole image's."""
    def check() -> None:
        if cancelled is not None and cancelled.is_set():
            raise Cancelled()
        check_stop()  # a stopped calibration (not work run ahead: its own thread has none)

    # Pairs are independent; the alignment kernel (patch_alignment) releases the GIL. Grouped
    # by the image they align onto, each image's gradients are computed once a pass and held
    # only while its pairs run (one image per core).
    def onto(b: int) -> dict:
        image, out = with_gradients(grays[b]), {}
        for a in cameras:
            if a != b:
                check()
                out[a, b] = _aligned(grays, image, a, b, points[a], *seeds[a, b],
                                     skip=skip[a, b], scales=(_scale(px_scale, a),
                                                              _scale(px_scale, b)))
                if counted is not None:
                    counted.add(share)
        return out

    def back_onto(a: int) -> dict:
        image, out = with_gradients(grays[a]), {}
        for b in cameras:
            if b != a:
                check()
                out[a, b] = _returned(grays, image, a, b, points[a], *forward[a, b])
                if counted is not None:
                    counted.add(share)
        return out
    with ThreadPoolExecutor(available_cores(), initializer=thread_start) as pool:
        forward = {k: v for part in pool.map(onto, cameras) for k, v in part.items()}
        return {k: v for part in pool.map(back_onto, cameras) for k, v in part.items()}


def _aligned(grays: dict, b_and_gradients: np.ndarray, a: int, b: int, points: np.ndarray,
             seed_a: np.ndarray, seed_b: np.ndarray, skip: np.ndarray,
             scales: tuple[float, float] = (1.0, 1.0)
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(indices into points, their positions in camera b (n, 2), the local maps (n, 2, 2)) of the
    reference points of camera a aligned onto camera b, predicted from the seed
    correspondences, that pass the correlation, shift and border checks; the points `skip`
    (indices) are not looked for. b_and_gradients: with_gradients(grays[b]); scales: a's and
    b's px_scale."""
    none = (np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros((0, 2, 2)))
    if not len(points):
        return none
    pred, jac, valid = local_affine(points, seed_a, seed_b, scales[0])
    valid[skip] = False
    h, w = grays[b].shape
    border = PATCH_HALF_PX + 2
    inside = valid & (pred[:, 0] > border) & (pred[:, 0] < w - border) \
        & (pred[:, 1] > border) & (pred[:, 1] < h - border)
    idx = np.flatnonzero(inside)
    if not len(idx):
        return none
    refined, ncc, map_ab = align_patches(grays[a], grays[b], points[idx], pred[idx], jac[idx],
                                         b_and_gradients)
    shift = np.linalg.norm(refined - pred[idx], axis=1)
    good = np.isfinite(refined).all(1) & (ncc >= MIN_NCC) & (shift <= MAX_SHIFT_PX * scales[1])
    good &= (refined[:, 0] > border) & (refined[:, 0] < w - border) \
        & (refined[:, 1] > border) & (refined[:, 1] < h - border)
    good &= np.abs(np.linalg.det(map_ab)) > 1e-3
    return idx[good], refined[good], map_ab[good]


def _returned(grays: dict, a_and_gradients: np.ndarray, a: int, b: int, points: np.ndarray,
              idx: np.ndarray, refined: np.ndarray, map_ab: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray]:
    """Of _aligned's correspondences (idx, refined, map_ab) of camera a's points in camera b,
    those that align back onto their reference point: (indices into points, positions in
    camera b (n, 2)). a_and_gradients: with_gradients(grays[a])."""
    if len(idx):
        # Aligned back from b, a right correspondence returns to its reference point; one that
        # slid along an edge or onto another surface at an occlusion does not.
        back, _, _ = align_patches(grays[b], grays[a], refined, points[idx],
                                   np.linalg.inv(map_ab), a_and_gradients)
        returned = np.linalg.norm(back - points[idx], axis=1) <= MAX_ROUND_TRIP_PX
        idx, refined = idx[returned], refined[returned]
    return idx, refined


def _on_epipolar_lines(state: SfMState, a: int, b: int, points: np.ndarray, idx: np.ndarray,
                       refined: np.ndarray, scale_b: float = 1.0
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Of camera a's points[idx] found at `refined` in camera b, those on their epipolar line in b
    under the state's cameras (MAX_EPIPOLAR_PX times b's px_scale, scale_b)."""
    if len(idx):
        keep = epipolar_distance_px(state, a, b, points[idx], refined) <= \
            MAX_EPIPOLAR_PX * scale_b
        idx, refined = idx[keep], refined[keep]
    return idx, refined
