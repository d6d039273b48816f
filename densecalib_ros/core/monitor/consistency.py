"""Does a calibration still fit the rig? New images are matched and every match is held against
the calibration's epipolar geometry: with the calibrated intrinsics and relative pose of two
cameras, a right match lies on its epipolar line. A camera that was bumped or refocused since
breaks that for all of its pairs, the others keep fitting, so the check names the camera to look
at, in seconds and without a recalibration.

Two figures:
- per pair, the epipolar error of a match (px): the angle between each ray and the epipolar plane
  of the other, times that camera's focal length, averaged over the two cameras; the pair's figure
  is the median over its matches that agree with their own two-view geometry (self_consistent):
  raw matches of a wide pair can be mostly outliers, which would move even a median (before they
  were left out, the exact ground truth of generated rigs "no longer fitted": docs/design-notes.md,
  Rig consistency check). It misses motion along the epipolar lines: a camera panned about an axis
  across its baselines moves its points mostly along them (a fraction of what a tilt shows: same
  section);
- per camera triple, the transfer error (px): a point matched in two cameras is triangulated from
  them and projected into the third, where it is compared with its match; with three cameras or
  more this sees any rotation. The triple's figure is the median over its points, each divided by
  the noise its geometry adds (transfer_gain), on matches a third camera confirms
  (transfer_errors_px: both are what let a calibration fit its own real images).
The camera to blame is the one in every failing figure (suspect_cameras).

A buffer of frame sets may straddle the change: a camera bumped a minute ago leaves most of a
node's buffer from before, and pooled with them its few new matches pass or blur the blame over
several cameras. So check_latest holds each frame set against the calibration on its own first;
when sets that fit are followed by sets that do not, the rig changed in between, and the figures
are those of the sets since (sets_since_change, the same split a recalibration makes).
"""
from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np

from ..method.sampling import refined_targets_px
from ..types import RigCalibration, SiteMatchSet

# A pair (or a camera's best source pair) below this many matches over all frame sets gets no
# figure (its median would be noise).
MIN_PAIR_MATCHES = 20
# Transfer points need rays that meet at an angle: below this the triangulated depth is noise.
MIN_TRIANGULATION_ANGLE_DEG = 2.0
# Transfer errors are divided by the noise their geometry adds (transfer_gain); points whose
# geometry magnifies the sources' matching noise more than this are left out: divided by 3.6 or
# more, a moved target's error would count for too little in the median.
MAX_TRANSFER_GAIN = 5.0
DEFAULT_TOLERANCE_PX = 2.0  # a pair fits when its median epipolar error is at most this
# Matches are judged only when they agree with their own two-view geometry within this (px at
# the cameras' focal): what is left out are the matcher's outliers, not a moved camera's matches.
CONSENSUS_PX = 4.0
MIN_RAY_Z = 0.1  # rays ~84 deg or more from the pair's mean ray take no part in the consensus
MAX_JUDGED_MATCHES = 1000  # per pair: a seeded random subset beyond


@dataclass
class PairCheck:
    cameras: tuple[str, str]
    num_matches: int
    median_error_px: float

    def fits(self, tolerance_px: float) -> bool:
        return self.median_error_px <= tolerance_px


def _skew(t: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])


def epipolar_errors_px(rig: RigCalibration, camera_names: Sequence[str],
                       match_sets: Sequence[SiteMatchSet]) -> dict[tuple[str, str], np.ndarray]:
    """Per unordered pair of calibrated cameras (names in camera_names order), the epipolar error
    (px, module docstring) of each of its matches over all frame sets."""
    cams = {n: rig.cameras[n] for n in camera_names if n in rig.cameras}
    colmap = {n: c.intrinsics.to_pycolmap() for n, c in cams.items()}
    focal = {n: float(np.mean([colmap[n].focal_length_x, colmap[n].focal_length_y])) for n in cams}
    out: dict[tuple[str, str], list[np.ndarray]] = {}
    for (i, a), (j, b) in itertools.combinations(enumerate(camera_names), 2):
        if a not in cams or b not in cams:
            continue
        b_from_a = cams[b].cam_from_rig @ np.linalg.inv(cams[a].cam_from_rig)
        t = b_from_a[:3, 3]
        if np.linalg.norm(t) < 1e-12:
            continue  # one optical centre: no epipolar geometry
        essential = _skew(t / np.linalg.norm(t)) @ b_from_a[:3, :3]
        rays_a, rays_b = [], []
        for ms in match_sets:
            pm = ms.pairs.get((i, j))
            if pm is None:
                continue
            valid = np.flatnonzero(pm.target >= 0)
            xy_a = ms.sites[i][valid]
            xy_b = refined_targets_px(ms, i, j, valid, pm.target[valid])
            rays_a.append(colmap[a].cam_ray_from_img(xy_a))
            rays_b.append(colmap[b].cam_ray_from_img(xy_b))
        if not rays_a:
            out[(a, b)] = np.zeros(0)
            continue
        ray_a, ray_b = np.concatenate(rays_a), np.concatenate(rays_b)
        if len(ray_a) > MAX_JUDGED_MATCHES:  # a median needs no more; the consensus costs less
            pick = np.random.default_rng(0).choice(len(ray_a), MAX_JUDGED_MATCHES, replace=False)
            ray_a, ray_b = ray_a[pick], ray_b[pick]
        ray_a /= np.linalg.norm(ray_a, axis=1, keepdims=True)
        ray_b /= np.linalg.norm(ray_b, axis=1, keepdims=True)
        agree = self_consistent(ray_a, ray_b, CONSENSUS_PX / np.sqrt(focal[a] * focal[b]))
        ray_a, ray_b = ray_a[agree], ray_b[agree]
        plane_b = ray_a @ essential.T  # normal of the epipolar plane in camera b
        plane_a = ray_b @ essential  # ... and in camera a
        sin_b = np.abs(np.einsum("ij,ij->i", ray_b, plane_b)) / np.linalg.norm(plane_b, axis=1)
        sin_a = np.abs(np.einsum("ij,ij->i", ray_a, plane_a)) / np.linalg.norm(plane_a, axis=1)
        err = 0.5 * (np.arcsin(np.clip(sin_a, 0, 1)) * focal[a]
                     + np.arcsin(np.clip(sin_b, 0, 1)) * focal[b])
        out[(a, b)] = err[np.isfinite(err)]
    return out


def _towards_z(direction: np.ndarray) -> np.ndarray:
    """A rotation (3x3) taking `direction` to +z."""
    import cv2

    d = direction / max(np.linalg.norm(direction), 1e-12)
    axis = np.cross(d, [0.0, 0.0, 1.0])
    angle = np.arctan2(np.linalg.norm(axis), d[2])
    if np.linalg.norm(axis) < 1e-12:
        return np.eye(3) if d[2] > 0 else np.diag([1.0, -1.0, -1.0])
    return cv2.Rodrigues(axis / np.linalg.norm(axis) * angle)[0]


def self_consistent(ray_a: np.ndarray, ray_b: np.ndarray, threshold_rad: float) -> np.ndarray:
    """bool (N,): the matches (unit rays in two cameras) that agree with the two-view geometry
    most of them agree on (an essential matrix by RANSAC), whatever the calibration says. Raw
    matches of a wide pair can be mostly wrong; their median error then says nothing of the
    calibration. The geometry is the rays' own, so a camera that moved keeps its true matches
    (which then disagree with the calibration). All False when no geometry has MIN_PAIR_MATCHES
    supporters."""
    import cv2

    keep = np.zeros(len(ray_a), dtype=bool)
    if len(ray_a) < MIN_PAIR_MATCHES:
        return keep
    # Turn each camera's rays about its centre so that their mean points along z (a known
    # rotation leaves the two-view consensus as it is): a fisheye pair that overlaps at its
    # image borders keeps its rays normalisable.
    ray_a, ray_b = ray_a @ _towards_z(ray_a.mean(0)).T, ray_b @ _towards_z(ray_b.mean(0)).T
    front = (ray_a[:, 2] > MIN_RAY_Z) & (ray_b[:, 2] > MIN_RAY_Z)  # normalisable rays
    if front.sum() < MIN_PAIR_MATCHES:
        return keep
    x_a = ray_a[front, :2] / ray_a[front, 2:]
    x_b = ray_b[front, :2] / ray_b[front, 2:]
    _, inliers = cv2.findEssentialMat(x_a, x_b, np.eye(3), method=cv2.USAC_DEFAULT, prob=0.999,
                                      threshold=float(threshold_rad))
    if inliers is None or int(inliers.sum()) < MIN_PAIR_MATCHES:
        return keep
    keep[np.flatnonzero(front)[inliers.ravel() > 0]] = True
    return keep


def midpoints(o_a: np.ndarray, d_a: np.ndarray, o_b: np.ndarray, d_b: np.ndarray):
    """Midpoint triangulation of rays o + s d (unit d): (points (N, 3), s_a, s_b, sin of the
    angle between the rays)."""
    w = o_a - o_b
    dot = np.einsum("ij,ij->i", d_a, d_b)
    denom = 1.0 - dot ** 2
    with np.errstate(invalid="ignore", divide="ignore"):
        s_a = (dot * (d_b @ w) - (d_a @ w)) / np.where(denom > 0, denom, np.nan)
        s_b = ((d_b @ w) - dot * (d_a @ w)) / np.where(denom > 0, denom, np.nan)
    point = 0.5 * (o_a + s_a[:, None] * d_a + o_b + s_b[:, None] * d_b)
    return point, s_a, s_b, np.sqrt(np.clip(denom, 0.0, None))


def _ray_miss_px(point: np.ndarray, centre: np.ndarray, rays: np.ndarray,
                 focal_px: float) -> np.ndarray:
    """(N,) how far (px at the camera's focal) each triangulated point lies off its ray."""
    to_point = point - centre
    return focal_px * (np.linalg.norm(np.cross(rays, to_point), axis=1)
                       / np.linalg.norm(to_point, axis=1))


def _match_ends(ms: SiteMatchSet, i: int, j: int, sites_i: np.ndarray) -> np.ndarray:
    """Pixel positions in camera j of the matches of camera i's sites `sites_i` (NaN: none)."""
    out = np.full((len(sites_i), 2), np.nan)
    pm = ms.pairs.get((i, j))
    if pm is None:
        return out
    target = pm.target[sites_i]
    ok = target >= 0
    out[ok] = refined_targets_px(ms, i, j, sites_i[ok], target[ok])
    return out


def confirmed_matches(ms: SiteMatchSet, cameras: Sequence[int]) -> dict[tuple[int, int],
                                                                          np.ndarray]:
    """{(i, j): bool per site of i}: i's site has a match in j that a third camera confirms
    (i's match in c, matched on into j, lands within CONSENSUS_PX of it: a closed 3-cycle up to
    the pixel). Raw matches of a wide pair can be mostly wrong (half of a real wide triple's
    were, 70-220 px off); three cameras agreeing on a wrong match is rare, and it does not
    depend on the calibration, so a moved camera's matches stay confirmed."""
    out = {}
    for i, j in itertools.permutations(cameras, 2):
        sites = np.arange(len(ms.sites[i]))
        xy_j = _match_ends(ms, i, j, sites)
        ok = np.zeros(len(sites), dtype=bool)
        for c in cameras:
            pm = ms.pairs.get((i, c))
            if c in (i, j) or pm is None:
                continue
            in_c = np.flatnonzero((pm.target >= 0) & np.isfinite(xy_j).all(1))
            via_c = _match_ends(ms, c, j, pm.target[in_c].astype(np.int64))
            with np.errstate(invalid="ignore"):
                ok[in_c[np.linalg.norm(via_c - xy_j[in_c], axis=1) <= CONSENSUS_PX]] = True
        out[(i, j)] = ok
    return out


def transfer_errors_px(rig: RigCalibration, camera_names: Sequence[str],
                       match_sets: Sequence[SiteMatchSet]
                       ) -> dict[str, dict[tuple[str, str], np.ndarray]]:
    """errors[target][(a, b)]: transfer errors (px, module docstring) in camera `target` of the
    points matched in a, b and target, triangulated from a and b, over all frame sets.

    The points are a's sites matched in b, and in the target where a third camera confirms that
    match (confirmed_matches; raw matches into a wide target can be mostly wrong: a real triple's
    median was 866 px). A point whose two source rays miss each other by more than CONSENSUS_PX
    is left out too: a repeated texture can make wrong matches agree (19 of a real triple's 66,
    transferred 1000 px off), and a source camera moved across its epipolar lines is for the
    pair figures to name (the triples it is the target of still see it). Each error is divided
    by the noise its geometry adds (transfer_gain): sources a few degrees apart fix the depth
    loosely, and a target 30 deg aside turns their matching noise into several px (what failed
    real calibrations against their own images), while a camera moved by d px still shows about
    d px through a well-posed triple."""
    cams = [n for n in camera_names if n in rig.cameras]
    index = {n: camera_names.index(n) for n in cams}
    colmap = {n: rig.cameras[n].intrinsics.to_pycolmap() for n in cams}
    rig_from_cam = {n: np.linalg.inv(rig.cameras[n].cam_from_rig) for n in cams}
    focal = {n: float(np.mean([colmap[n].focal_length_x, colmap[n].focal_length_y]))
             for n in cams}
    min_sin = np.sin(np.deg2rad(MIN_TRIANGULATION_ANGLE_DEG))
    out: dict[str, dict[tuple[str, str], np.ndarray]] = {n: {} for n in cams}
    confirmed = [confirmed_matches(ms, [index[n] for n in cams]) for ms in match_sets]
    for a, b in itertools.combinations(cams, 2):
        ia, ib = index[a], index[b]
        o_a, o_b = rig_from_cam[a][:3, 3], rig_from_cam[b][:3, 3]
        errors: dict[str, list] = {t: [] for t in cams if t not in (a, b)}
        for ms_k, ms in enumerate(match_sets):
            pm = ms.pairs.get((ia, ib))
            if pm is None:
                continue
            # Each point of a matched in b is triangulated once, then projected into every target.
            sites_a = np.flatnonzero(pm.target >= 0)
            if not len(sites_a):
                continue
            sites_b = pm.target[sites_a].astype(np.int64)
            xy_a = ms.sites[ia][sites_a]
            xy_b = refined_targets_px(ms, ia, ib, sites_a, sites_b)
            rays = []
            for name, xy in ((a, xy_a), (b, xy_b)):
                r = colmap[name].cam_ray_from_img(xy) @ rig_from_cam[name][:3, :3].T
                rays.append(r / np.linalg.norm(r, axis=1, keepdims=True))
            point, s_a, s_b, sin_ab = midpoints(o_a, rays[0], o_b, rays[1])
            with np.errstate(invalid="ignore"):
                meet = ((sin_ab > min_sin) & (s_a > 0) & (s_b > 0)
                        & (_ray_miss_px(point, o_a, rays[0], focal[a]) <= CONSENSUS_PX)
                        & (_ray_miss_px(point, o_b, rays[1], focal[b]) <= CONSENSUS_PX))
            for target in errors:
                it = index[target]
                xy_t = _match_ends(ms, ia, it, sites_a)
                cam_t = rig.cameras[target].cam_from_rig
                x_t = point @ cam_t[:3, :3].T + cam_t[:3, 3]
                with np.errstate(invalid="ignore", divide="ignore"):
                    good = meet & confirmed[ms_k][(ia, it)][sites_a] & (x_t[:, 2] > 0)
                    if not good.any():
                        continue
                    gain = transfer_gain(point[good], (rays[0][good], s_a[good], focal[a]),
                                         (rays[1][good], s_b[good], focal[b]),
                                         rig_from_cam[target][:3, 3], focal[target])
                projected = np.asarray(colmap[target].img_from_cam(x_t[good]), float)
                err = (np.linalg.norm(projected - xy_t[good], axis=1)
                       / np.sqrt(0.5 * (1.0 + gain ** 2)))  # as through a gain-1 triple
                keep = (gain <= MAX_TRANSFER_GAIN) & np.isfinite(err)
                errors[target].append(err[keep])
        for target, errs in errors.items():
            out[target][(a, b)] = np.concatenate(errs) if errs else np.zeros(0)
    return out


def transfer_gain(point: np.ndarray, source_a: tuple, source_b: tuple, centre_t: np.ndarray,
                  focal_t: float) -> np.ndarray:
    """(N,) px of transfer error in the target per px of matching noise in the sources, for
    points (N, 3) triangulated from two rays per point. A source is (unit rays (N, 3), distance
    of each point along its ray, focal px), all in one frame. Noise of 1 px in
    b turns its ray by 1/f_b and slides the point along a's ray by s_b / (f_b sin alpha), alpha
    the angle between the rays; the target sees that slide across its own ray r_t at distance
    d_t as f_t |d_a x r_t| / d_t px of it. The two sources' shares add in quadrature."""
    (d_a, s_a, f_a), (d_b, s_b, f_b) = source_a, source_b
    to_t = point - centre_t
    dist_t = np.linalg.norm(to_t, axis=1)
    r_t = to_t / dist_t[:, None]
    sin_alpha = np.linalg.norm(np.cross(d_a, d_b), axis=1)
    across_a = np.linalg.norm(np.cross(d_a, r_t), axis=1)  # the slide along d_a, seen from t
    across_b = np.linalg.norm(np.cross(d_b, r_t), axis=1)
    gain_from_b = focal_t / f_b * s_b / dist_t * across_a / sin_alpha
    gain_from_a = focal_t / f_a * s_a / dist_t * across_b / sin_alpha
    return np.hypot(gain_from_a, gain_from_b)


@dataclass
class TransferCheck:
    target: str
    sources: tuple[str, str]  # the two cameras the points were triangulated from
    num_points: int
    median_error_px: float

    @property
    def cameras(self) -> tuple[str, str, str]:
        return (*self.sources, self.target)

    def fits(self, tolerance_px: float) -> bool:
        return self.median_error_px <= tolerance_px


def check_transfers(errors: dict[str, dict[tuple[str, str], np.ndarray]]) -> list[TransferCheck]:
    """TransferCheck per (target, source pair) with at least MIN_PAIR_MATCHES points."""
    return [TransferCheck(target, pair, len(e), float(np.median(e)))
            for target, by_pair in errors.items() for pair, e in by_pair.items()
            if len(e) >= MIN_PAIR_MATCHES]


def best_transfer_per_camera(transfers: Sequence[TransferCheck]) -> list[TransferCheck]:
    """Per target camera, its best-fitting transfer (the figure shown per camera)."""
    best: dict[str, TransferCheck] = {}
    for t in transfers:
        if t.target not in best or t.median_error_px < best[t.target].median_error_px:
            best[t.target] = t
    return list(best.values())


def check_pairs(errors: dict[tuple[str, str], np.ndarray]) -> list[PairCheck]:
    """PairCheck per pair with at least MIN_PAIR_MATCHES matches."""
    return [PairCheck(pair, len(e), float(np.median(e))) for pair, e in errors.items()
            if len(e) >= MIN_PAIR_MATCHES]


def suspect_cameras(figures: Sequence, tolerance_px: float) -> list[str]:
    """The cameras common to every failing figure (PairCheck / TransferCheck): one camera when a
    single camera moved and the others still check each other, several when these cameras cannot
    tell which (three cameras, a move the pairs do not see), none when nothing fails or more than
    one camera moved (no camera is in every failing figure)."""
    failing = [set(f.cameras) for f in figures if not f.fits(tolerance_px)]
    return sorted(set.intersection(*failing)) if failing else []


@dataclass
class ConsistencyReport:
    pairs: list[PairCheck]
    transfers: list[TransferCheck]
    tolerance_px: float
    # check_latest: the figures are from frame sets [frame_sets_before_change, num_frame_sets);
    # the ones before fit the calibration one by one (0: all sets were judged together)
    num_frame_sets: int = 0
    frame_sets_before_change: int = 0

    @property
    def figures(self) -> list:
        return [*self.pairs, *self.transfers]

    @property
    def failing(self) -> list:
        return [f for f in self.figures if not f.fits(self.tolerance_px)]

    @property
    def fits(self) -> bool:
        return not self.failing

    @property
    def suspects(self) -> list[str]:
        return suspect_cameras(self.figures, self.tolerance_px)

    def verdict(self) -> str:
        """One line: whether the calibration fits, else which camera moved."""
        if self.fits:
            worst = max((f.median_error_px for f in self.figures), default=float("nan"))
            counts = " and ".join(f"{n} {what} figure{'s' if n != 1 else ''}" for n, what in (
                (len(self.pairs), "pair"), (len(self.transfers), "transfer")) if n)
            return (f"the calibration fits: {counts} within {self.tolerance_px:g} px (worst "
                    f"{worst:.2f} px)")
        moved = self.suspects
        if len(moved) == 1:
            what = f"{moved[0]} moved or changed"
        elif moved:
            what = f"one of {', '.join(moved)} moved or changed (these cameras cannot tell which)"
        else:
            what = "several cameras moved or changed"
        return (f"the calibration no longer fits: {what} ({len(self.failing)} of "
                f"{len(self.figures)} figures above {self.tolerance_px:g} px)"
                + (f"; frame sets 1-{k} fit it, the rig changed after frame set {k} (figures from "
                   f"the {self.num_frame_sets - k} since)"
                   if (k := self.frame_sets_before_change) else "")
                + ("; only the last frame set shows it: check again after the next to rule out "
                   "an odd one" if k and self.num_frame_sets - k == 1 else ""))


def check_calibration(rig: RigCalibration, camera_names: Sequence[str],
                      match_sets: Sequence[SiteMatchSet],
                      tolerance_px: float = DEFAULT_TOLERANCE_PX) -> ConsistencyReport:
    """All the figures of new matches against `rig` (module docstring)."""
    return ConsistencyReport(check_pairs(epipolar_errors_px(rig, camera_names, match_sets)),
                             check_transfers(transfer_errors_px(rig, camera_names, match_sets)),
                             tolerance_px)


def fits_per_frame_set(rig: RigCalibration, camera_names: Sequence[str],
                       match_sets: Sequence[SiteMatchSet],
                       tolerance_px: float = DEFAULT_TOLERANCE_PX) -> list[Optional[bool]]:
    """Per frame set, whether it alone fits `rig` (None: too few matches for any figure)."""
    fits: list[Optional[bool]] = []
    for match_set in match_sets:
        report = check_calibration(rig, camera_names, [match_set], tolerance_px)
        fits.append(report.fits if report.figures else None)
    return fits


def sets_since_change(fits: Sequence[Optional[bool]]) -> int:
    """From fits_per_frame_set: the index of the first frame set after the last one that fits,
    when a later one does not fit; else 0 (all fit at the end, or none ever did: no change seen
    inside the buffer)."""
    last_fit = max((t for t, f in enumerate(fits) if f), default=None)
    if last_fit is None or not any(f is False for f in fits[last_fit + 1:]):
        return 0
    return last_fit + 1


def check_latest(rig: RigCalibration, camera_names: Sequence[str],
                 match_sets: Sequence[SiteMatchSet],
                 tolerance_px: float = DEFAULT_TOLERANCE_PX) -> ConsistencyReport:
    """check_calibration on the frame sets since the rig last changed inside the sequence (all of
    them when it did not; module docstring). The match sets must be in time order."""
    before = sets_since_change(fits_per_frame_set(rig, camera_names, match_sets, tolerance_px))
    report = check_calibration(rig, camera_names, match_sets[before:], tolerance_px)
    report.num_frame_sets, report.frame_sets_before_change = len(match_sets), before
    return report
