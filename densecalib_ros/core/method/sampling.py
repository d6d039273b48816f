"""Hierarchical two-stage grid sampling of cycle-consistent tracks (paper Sec. 3.1-3.2, Alg. 1).

    result = sample_tracks(match_sets, config)      # list[SiteMatchSet] (one per time step)
    result.tracks                                   # core.types.Tracks, COLMAP px of the originals

Pipeline: n-cycle closure (cycles.py) -> stage 1 -> F per camera pair on the pooled stage-1
correspondences of all time steps (MAGSAC++) -> F_err filter -> initial focals (focal.py) ->
relative poses -> triangulation-angle scores (scoring.py) -> stage 2 -> tracks.

Decisions (the paper leaves them open):
- Grid image. A cycle set belongs to a camera subset; its grids are laid over the image of the
  subset's lowest-index camera (the "source image of the warp" in the paper: cycles are composed
  starting from that camera's sites). Every subset has its own grids.
- Stage 1: fine cells of `fine_cell_px`, one uniformly random cycle per cell, per subset and time.
- Stage 2 per time step, orders N down to 2, per subset: coarse cells of `cell_size_px` d. A cell is
  filled when it already holds a selected track of this subset or of a higher-order subset that
  contains it (its observation in the grid image), and is then not refilled. In each free cell one
  cycle is picked: by the highest score (argmax), or with probability proportional to the score
  (`probabilistic_scoring`; uniform among equal/zero scores, and when top_k = 0).
- Coverage rule: the paper writes n_min = c_min * d^2, which for d = 80 (1920) exceeds the ~120
  cells of a 1024x768 image, so it cannot be meant literally. Here n_min = c_min * (number of d x d
  cells of the grid image), counted at the top level d and kept while d is halved (up to
  `max_grid_iterations` levels in all): a subset whose filled cells cover less than c_min of its
  image is resampled on a finer grid, so views whose overlap is concentrated in a small region are
  still represented, while well-spread subsets are sampled at d. (`stats["halvings"]` counts it.)
- Budget: `samples_per_order[n]` is the number of n-cycle tracks for the whole input (the paper's
  "view set"; all time steps together). When stage 2 yields more, a seeded uniform subset is kept
  (before lower orders are filled, so their free cells are computed from the kept tracks).
- Fisheye (`sfm.camera_model` containing FISHEYE and no intrinsics given): F on raw pixels does not
  hold, so rays come from an assumed equidistant model r = f * theta with a 180 deg horizontal field
  of view (f = width / pi) and the principal point at the image centre, and E is estimated on those
  rays (z > cos 70 deg). focal_px then reports this assumed focal.
- Observations: a cycle is a tuple of site indices; its pixel observations follow an anchor rule
  (`cycle_observations_px`): the lowest-index camera keeps its site position, the others take the
  matcher's sub-pixel position of that site's scene point (SiteMatches.target_xy_px) where given,
  else their site positions. Stage-1 and stage-2 grids use the anchor's (site) position.
Deterministic for a fixed `sampling.seed`.
"""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from itertools import combinations
from typing import Optional

import numpy as np

from ..config import PipelineConfig
from ..errors import FocalInitError, InputError, NotEnoughOverlapError
from ..parallel import map_threads
from ..types import CameraIntrinsics, SiteMatchSet, Tracks
from .cycles import CycleSet, close_cycles
from .focal import calibration_matrix, estimate_initial_focals
from .grid_sampling import CycleCandidates, stage1_pick, stage2_tracks
from .scoring import (angle_score, equidistant_rays, pair_poses_from_rig, rays_from_intrinsics,
                      top_k_sum)
from .twoview import (F_THRESHOLD_PX, TwoViewGeometry, estimate_essential_from_rays,
                      estimate_fundamental, pair_weights as compute_pair_weights, pixels_to_rays,
                      relative_pose_from_essential, symmetric_epipolar_distance_px,
                      triangulation_angles_deg)

LOG = logging.getLogger(__name__)

MAX_F_POINTS = 20000  # correspondences per pair given to MAGSAC++ (a seeded random subset beyond)
FISHEYE_ASSUMED_FOV_DEG = 180.0  # horizontal field of view of the assumed equidistant fisheye
# Start focal (x max(width, height)) of a pinhole camera that shares a fundamental matrix with no
# other pinhole camera (a rig mixing lenses), so eq. 2 cannot give one: COLMAP's prior for unknown
# focals; the SfM's focal multi-start also tries the generic priors (multistart.focal_starts).
MIXED_LONE_PINHOLE_FOCAL_RATIO = 1.2


@dataclass
class SamplingResult:
    """tracks: the sampled tracks. two_view: {(i, j), i < j: TwoViewGeometry} (F_ji on pixels, or
    E/R/t on rays for fisheye; R_ji/t_ji filled where a pose was found). focal_px: (C,) focal used
    for scoring (estimated, given, or the fisheye assumption). pair_weights: {(i, j): w_ij}.
    stats: counts per stage and order, halvings, timings."""

    tracks: Tracks
    two_view: dict
    focal_px: np.ndarray
    pair_weights: dict
    stats: dict = field(default_factory=dict)


def _is_fisheye(model: str) -> bool:
    return "FISHEYE" in model.upper()


def _check_inputs(match_sets: list) -> tuple[int, list]:
    if not match_sets:
        raise InputError("sample_tracks needs at least one SiteMatchSet (one per time step).")
    num_cams = len(match_sets[0].sites)
    sizes = [tuple(s) for s in match_sets[0].image_sizes]
    for t, ms in enumerate(match_sets):
        if len(ms.sites) != num_cams or [tuple(s) for s in ms.image_sizes] != sizes:
            raise InputError(f"Time step {t} has a different camera set or image sizes than time "
                             "step 0: every frame set must hold one image per camera of the rig.")
    if num_cams < 2:
        raise InputError(f"{num_cams} camera(s): a rig needs at least two overlapping cameras.")
    return num_cams, sizes


@dataclass
class _Lenses:
    """How pixels become rays while sampling, before any calibration: through the given
    intrinsics, else an equidistant fisheye of FISHEYE_ASSUMED_FOV_DEG, else a centred pinhole of
    the focal passed in."""

    sizes: list
    fisheye: list[bool]
    fisheye_focal: np.ndarray  # (C,) px of the assumed fisheye
    intrinsics: Optional[list[CameraIntrinsics]]
    seed: int

    def rays(self, c: int, xy: np.ndarray, focal: Optional[np.ndarray]) -> np.ndarray:
        if self.intrinsics is not None:
            return rays_from_intrinsics(self.intrinsics[c], xy)
        if self.fisheye[c]:
            return equidistant_rays(xy, self.sizes[c], self.fisheye_focal[c])
        K = calibration_matrix(focal[c], (self.sizes[c][0] / 2.0, self.sizes[c][1] / 2.0))
        return pixels_to_rays(xy, K)

    def essential(self, i: int, j: int, xy_i: np.ndarray, xy_j: np.ndarray,
                  focal: Optional[np.ndarray]) -> TwoViewGeometry:
        f_mean = 0.5 * (_focal_hint(self.intrinsics, self.fisheye_focal, i, focal)
                        + _focal_hint(self.intrinsics, self.fisheye_focal, j, focal))
        return estimate_essential_from_rays(self.rays(i, xy_i, focal), self.rays(j, xy_j, focal),
                                            F_THRESHOLD_PX / f_mean, seed=self.seed)


def sample_tracks(match_sets: list[SiteMatchSet], config: PipelineConfig,
                  focal_px: Optional[np.ndarray] = None,
                  cam_from_rig: Optional[list[np.ndarray]] = None,
                  intrinsics: Optional[list[CameraIntrinsics]] = None) -> SamplingResult:
    """Cycle-consistent, spatially balanced, scored tracks from the matches of every time step.

    match_sets: one SiteMatchSet per time step (same cameras and image sizes).
    focal_px: (C,) initial focals to use instead of estimating them from the F's (NaN: estimate
      that camera's).
    cam_from_rig, intrinsics: a known calibration (refinement/recalibration): poses (4x4 per
      camera) and COLMAP intrinsics give the triangulation angles directly; intrinsics alone give
      the rays (and focals).
    Raises NotEnoughOverlapError when no camera pair has a closed cycle, FocalInitError when
    focals must be estimated and cannot be.

    Stages, each timed in stats["timing_s"]: n-cycle closure and stage 1 (fine grid, random
    pick); two-view geometry per camera pair on the pooled stage-1 correspondences; the focals
    the scores are computed with; relative poses; the F_err filter and a score per cycle;
    stage 2 (coarse grid, orders N..2, coverage rule, budget).
    """
    s_cfg = config.sampling
    num_cams, sizes = _check_inputs(match_sets)
    rng = np.random.default_rng(s_cfg.seed)  # drawn from in this order: stage 1, F, stage 2
    stats: dict = {"timing_s": {}}
    clock = time.perf_counter()
    stage1, closed_counts = _closed_cycles_stage1(
        match_sets, max(2, min(s_cfg.max_cycle_order, num_cams)), s_cfg.fine_cell_px, sizes, rng,
        stats)
    stats["timing_s"]["cycles_stage1"] = time.perf_counter() - clock

    clock = time.perf_counter()
    lenses = _Lenses(sizes, [(_is_fisheye(intrinsics[c].model) if intrinsics is not None
                              else _is_fisheye(config.sfm.model_of(c))) for c in range(num_cams)],
                     np.array([w / np.radians(FISHEYE_ASSUMED_FOV_DEG) for w, _ in sizes]),
                     intrinsics, s_cfg.seed)
    pair_xy = _pooled_pair_correspondences(match_sets, stage1, num_cams)
    two_view, counts, deferred = _pair_geometry(pair_xy, lenses, rng)
    weights = compute_pair_weights(counts)
    stats["pair_correspondences"] = {f"{i}-{j}": n for (i, j), n in counts.items()}
    stats["pair_inlier_ratio"] = {f"{i}-{j}": round(g.num_inliers / max(counts[(i, j)], 1), 4)
                                  for (i, j), g in two_view.items()}
    stats["timing_s"]["two_view"] = time.perf_counter() - clock

    clock = time.perf_counter()
    given = None if focal_px is None else np.asarray(focal_px, np.float64).reshape(num_cams)
    focal = _scoring_focals(two_view, weights, lenses, given, stats)
    for i, j in deferred:  # pinhole-fisheye pairs, which needed the pinhole camera's focal
        two_view[(i, j)] = lenses.essential(i, j, *pair_xy[(i, j)], focal)
        stats["pair_inlier_ratio"][f"{i}-{j}"] = round(two_view[(i, j)].num_inliers
                                                       / max(counts[(i, j)], 1), 4)
    stats["timing_s"]["focal"] = time.perf_counter() - clock

    clock = time.perf_counter()
    _relative_poses(two_view, pair_xy, focal, sizes, cam_from_rig)
    stats["timing_s"]["poses"] = time.perf_counter() - clock

    clock = time.perf_counter()
    candidates = _filtered_scored_cycles(match_sets, stage1, closed_counts, two_view, lenses,
                                         focal, config, stats)
    stats["timing_s"]["filter_score"] = time.perf_counter() - clock

    clock = time.perf_counter()
    tracks, halvings = stage2_tracks(candidates, sizes, s_cfg, rng, num_cams, len(match_sets))
    stats["halvings"] = halvings
    stats["tracks_per_order"] = {n: int((tracks.cycle_order == n).sum()) for n in closed_counts}
    stats["timing_s"]["stage2"] = time.perf_counter() - clock
    LOG.debug("sampled %d tracks (per order %s) from %s closed cycles", tracks.num_tracks,
             stats["tracks_per_order"], closed_counts)
    return SamplingResult(tracks, two_view, focal, weights, stats)


def _closed_cycles_stage1(match_sets: list[SiteMatchSet], max_order: int, cell_px: float,
                          sizes: list, rng: np.random.Generator, stats: dict
                          ) -> tuple[list[dict[int, list[CycleSet]]], dict[int, int]]:
    """Per time step, the closed n-cycles (n = 2..max_order) thinned by stage 1 (one per fine
    cell, picked at random), and how many closed per order. NotEnoughOverlapError when no
    2-cycle is left."""
    stage1: list[dict[int, list[CycleSet]]] = []
    closed_counts = {n: 0 for n in range(2, max_order + 1)}
    for ms in match_sets:
        cycles = close_cycles(ms, max_order)
        per_order = {}
        for n, sets in cycles.items():
            closed_counts[n] += sum(len(cs) for cs in sets)
            per_order[n] = [stage1_pick(cs, ms.sites[cs.cameras[0]], cell_px,
                                    sizes[cs.cameras[0]], rng) for cs in sets]
        stage1.append(per_order)
    stats["closed_cycles"] = closed_counts
    stats["stage1_cycles"] = {n: sum(len(cs) for p in stage1 for cs in p[n])
                              for n in closed_counts}
    if stats["stage1_cycles"].get(2, 0) == 0:
        raise NotEnoughOverlapError(
            "No cycle-consistent matches between any two cameras: check that the cameras overlap "
            "and the scene is textured, or try another matcher.")
    return stage1, closed_counts


def _pair_geometry(pair_xy: dict, lenses: _Lenses, rng: np.random.Generator
                   ) -> tuple[dict, dict, list]:
    """({(i, j): TwoViewGeometry}, {(i, j): correspondences used}, the pairs deferred): F on
    pixels between pinhole cameras, E on rays where a fisheye is involved. A pinhole camera
    paired with a fisheye one (a rig mixing lenses) needs its focal for the rays: such pairs
    wait for the focals the pinhole pairs give (or the user's). pair_xy is thinned in place to
    MAX_F_POINTS per pair."""
    counts: dict = {}
    deferred = []
    now = []
    fisheye = lenses.fisheye
    for (i, j), (xy_i, xy_j) in pair_xy.items():
        if len(xy_i) > MAX_F_POINTS:
            pick = np.sort(rng.choice(len(xy_i), MAX_F_POINTS, replace=False))
            xy_i, xy_j = xy_i[pick], xy_j[pick]
            pair_xy[(i, j)] = (xy_i, xy_j)
        counts[(i, j)] = len(xy_i)
        if fisheye[i] != fisheye[j] and lenses.intrinsics is None:
            deferred.append((i, j))
        else:
            now.append((i, j))

    def geometry(ij: tuple[int, int]) -> TwoViewGeometry:
        (i, j), (xy_i, xy_j) = ij, pair_xy[ij]
        if fisheye[i] or fisheye[j]:
            return lenses.essential(i, j, xy_i, xy_j, None)
        return estimate_fundamental(xy_i, xy_j, F_THRESHOLD_PX, seed=lenses.seed)
    # Each pair's RANSAC is seeded and releases the GIL: the pairs run side by side.
    two_view = dict(zip(now, map_threads(geometry, now)))
    return two_view, counts, deferred


def _scoring_focals(two_view: dict, weights: dict, lenses: _Lenses,
                    given: Optional[np.ndarray], stats: dict) -> np.ndarray:
    """(C,) focal px the cycles are scored with: the given ones, the intrinsics', the assumed
    fisheye's, or eq. 2's on the pinhole pairs' F (a generic lens where it fails); a given NaN
    is estimated. Where they came from goes into stats["focal_source"]."""
    fisheye, fisheye_focal, sizes = lenses.fisheye, lenses.fisheye_focal, lenses.sizes
    num_cams = len(sizes)
    if given is not None and np.isfinite(given).all():
        focal = given
        stats["focal_source"] = "given"
    elif lenses.intrinsics is not None:
        focal = np.array([_focal_hint(lenses.intrinsics, fisheye_focal, c)
                          for c in range(num_cams)])
        stats["focal_source"] = "intrinsics"
    elif all(fisheye):
        focal = fisheye_focal.copy()
        stats["focal_source"] = f"equidistant {FISHEYE_ASSUMED_FOV_DEG:.0f} deg assumption"
    else:
        focal = _eq2_focals(two_view, weights, lenses, given, stats)
    if given is not None and not np.isfinite(given).all():  # NaN: estimate this camera's focal
        focal = np.where(np.isfinite(given), given, focal)
        stats["focal_source"] = "given, the rest " + stats["focal_source"]
    return focal


def _eq2_focals(two_view: dict, weights: dict, lenses: _Lenses, given: Optional[np.ndarray],
                stats: dict) -> np.ndarray:
    fisheye, fisheye_focal, sizes = lenses.fisheye, lenses.fisheye_focal, lenses.sizes
    num_cams = len(sizes)
    F = {k: g.F_ji for k, g in two_view.items() if not (fisheye[k[0]] or fisheye[k[1]])}
    known = np.full(num_cams, np.nan) if given is None else given.copy()
    known[np.array(fisheye)] = fisheye_focal[np.array(fisheye)]  # not in eq. 2: no F
    lone = [c for c in range(num_cams) if any(fisheye) and not fisheye[c]
            and not np.isfinite(known[c]) and not any(c in k and F[k] is not None for k in F)]
    for c in lone:  # a pinhole camera with no pinhole partner: a generic lens as its start
        known[c] = MIXED_LONE_PINHOLE_FOCAL_RATIO * max(sizes[c])
    stats["focal_source"] = "fundamental matrices (eq. 2)" + (
        f", generic {MIXED_LONE_PINHOLE_FOCAL_RATIO:g} x image size for camera(s) {lone}"
        if lone else "")
    try:
        focal = estimate_initial_focals(F, weights, sizes, known_px=known) \
            if not np.isfinite(known).all() else known
    except FocalInitError as exc:
        # Eq. 2 degenerates where optical axes nearly meet (long lenses aimed at one spot)
        # and fails on few, weak pairs; the SfM's focal multi-start does not need it (its
        # generic priors span 25-90 deg lenses), so a generic lens starts the sampling.
        LOG.info("no focal lengths from the fundamental matrices (%s); sampling with a "
                 "generic %g x image size", exc, MIXED_LONE_PINHOLE_FOCAL_RATIO)
        focal = np.where(np.isfinite(known), known, MIXED_LONE_PINHOLE_FOCAL_RATIO
                         * np.array([max(s) for s in sizes], dtype=np.float64))
        stats["focal_source"] = (f"generic {MIXED_LONE_PINHOLE_FOCAL_RATIO:g} x image size "
                                 "(eq. 2 failed)")
    focal[np.array(fisheye)] = fisheye_focal[np.array(fisheye)]
    return focal


def _relative_poses(two_view: dict, pair_xy: dict, focal: np.ndarray, sizes: list,
                    cam_from_rig: Optional[list[np.ndarray]]) -> None:
    """Fill each pair's R_ji, t_ji (and E_ji from F): from the given rig, else from its F with
    centred pinhole cameras of `focal`."""
    given_poses = pair_poses_from_rig(cam_from_rig) if cam_from_rig is not None else None
    for (i, j), geo in two_view.items():
        if given_poses is not None:
            geo.R_ji, geo.t_ji = given_poses[(i, j)]
        elif geo.F_ji is not None and geo.num_inliers >= 5:
            xy_i, xy_j = pair_xy[(i, j)]
            K_i = calibration_matrix(focal[i], (sizes[i][0] / 2.0, sizes[i][1] / 2.0))
            K_j = calibration_matrix(focal[j], (sizes[j][0] / 2.0, sizes[j][1] / 2.0))
            inl = geo.inlier_mask
            geo.R_ji, geo.t_ji, _ = relative_pose_from_essential(geo.F_ji, K_i, K_j, xy_i[inl],
                                                                  xy_j[inl])
            geo.E_ji = K_j.T @ geo.F_ji @ K_i


def _filtered_scored_cycles(match_sets: list[SiteMatchSet], stage1: list, closed_counts: dict,
                            two_view: dict, lenses: _Lenses, focal: np.ndarray,
                            config: PipelineConfig, stats: dict
                            ) -> dict[int, list[CycleCandidates]]:
    """The stage-1 cycles that pass the F_err filter on every pair, with their scores (top-k
    sum of the pairs' triangulation-angle scores), per order; 2-cycles of pairs whose two-view
    geometry has too few inliers are not used."""
    s_cfg = config.sampling
    unverified = {k for k, g in two_view.items()
                  if g.num_inliers < s_cfg.min_two_cycle_pair_inliers}
    stats["unverified_pairs"] = sorted(f"{i}-{j}" for i, j in unverified)
    removed_unverified = 0
    candidates: dict[int, list[CycleCandidates]] = {n: [] for n in closed_counts}
    removed = {n: 0 for n in closed_counts}
    for t, ms in enumerate(match_sets):
        for n, sets in stage1[t].items():
            for cs in sets:
                if n == 2 and cs.cameras in unverified:
                    removed_unverified += len(cs)
                    continue
                xy = cycle_observations_px(ms, cs)
                keep, score = _cycle_fit_and_score(cs, xy, n, two_view, lenses, focal, config)
                removed[n] += int((~keep).sum())
                if keep.any():
                    candidates[n].append(CycleCandidates(
                        t, CycleSet(cs.cameras, cs.sites[keep]), xy[keep], score[keep]))
    stats["f_err_removed"] = removed
    stats["unverified_two_cycles_removed"] = removed_unverified
    if unverified:
        LOG.info("2-cycles of camera pairs %s not used: their two-view geometry has fewer than %d "
                 "inliers (%d cycles)", ", ".join(stats["unverified_pairs"]),
                 s_cfg.min_two_cycle_pair_inliers, removed_unverified)
    return candidates


def _cycle_fit_and_score(cs: CycleSet, xy: np.ndarray, n: int, two_view: dict, lenses: _Lenses,
                         focal: np.ndarray, config: PipelineConfig
                         ) -> tuple[np.ndarray, np.ndarray]:
    """(bool (M,) the cycles within F_err on every pair, float (M,) their scores)."""
    s_cfg, sfm_cfg = config.sampling, config.sfm
    keep = np.ones(len(cs), bool)
    pair_scores = []
    cam_rays = [lenses.rays(c, xy[:, k], focal) for k, c in enumerate(cs.cameras)]
    for (a, ca), (b, cb) in combinations(enumerate(cs.cameras), 2):
        geo = two_view.get((ca, cb))
        thr = sfm_cfg.pair_f_err_px(ca, cb)
        if thr is None and n == 2:
            # Higher orders are verified by their closure; with F_err off (fisheye) 2-cycles
            # are not.
            thr = sfm_cfg.two_cycle_f_err_px
        if thr is not None and geo is not None:
            d = _epipolar_distance_px(geo, xy[:, a], xy[:, b], cam_rays[a], cam_rays[b],
                                      focal[ca], focal[cb])
            keep &= ~(d > thr)
        if s_cfg.top_k > 0:
            if geo is None or geo.R_ji is None:
                pair_scores.append(np.zeros(len(cs)))
            else:
                theta = triangulation_angles_deg(geo.R_ji, geo.t_ji, cam_rays[a], cam_rays[b])
                pair_scores.append(angle_score(theta, s_cfg.score_alpha_deg,
                                               s_cfg.score_sigma_deg, s_cfg.score_p,
                                               s_cfg.score_boundary_eps))
    score = (top_k_sum(np.stack(pair_scores, axis=1), s_cfg.top_k)
             if pair_scores else np.zeros(len(cs)))
    return keep, score


def _focal_hint(intrinsics: Optional[list], fisheye_focal: np.ndarray, c: int,
                focal: Optional[np.ndarray] = None) -> float:
    if intrinsics is not None:
        return float(intrinsics[c].params[0])
    return float(fisheye_focal[c] if focal is None else focal[c])


def _epipolar_distance_px(geo: TwoViewGeometry, xy_a, xy_b, rays_a, rays_b, f_a, f_b):
    """F_err measure: on pixels with F, else on ray-based E expressed in pinhole-equivalent pixels
    (normalised-plane distances times the focal; rays behind either camera are not judged)."""
    if geo.F_ji is not None:
        return symmetric_epipolar_distance_px(geo.F_ji, xy_a, xy_b)
    if geo.E_ji is None:
        return np.zeros(len(xy_a))
    with np.errstate(invalid="ignore", divide="ignore"):
        n_a = rays_a[:, :2] / rays_a[:, 2:3] * f_a
        n_b = rays_b[:, :2] / rays_b[:, 2:3] * f_b
        F_eq = np.diag([1 / f_b, 1 / f_b, 1.0]) @ geo.E_ji @ np.diag([1 / f_a, 1 / f_a, 1.0])
        d = symmetric_epipolar_distance_px(F_eq, n_a, n_b)
    return np.where((rays_a[:, 2] > 0) & (rays_b[:, 2] > 0), d, 0.0)


def refined_targets_px(match_set: SiteMatchSet, i: int, j: int, sites_i: np.ndarray,
                       sites_j: np.ndarray) -> np.ndarray:
    """float64 (M, 2): the observations in camera j of sites `sites_i` of camera i (int (M,)) whose
    matched sites in j are `sites_j`: the pair's refined position (SiteMatches.target_xy_px) where
    the matcher gives a finite one, else the site position sites[j][sites_j]."""
    xy = match_set.sites[j][sites_j]
    refined = match_set.pairs[(i, j)].target_xy_px
    if refined is None:
        return xy
    r = refined[sites_i]
    return np.where(np.isfinite(r).all(axis=1)[:, None], r, xy)


def cycle_observations_px(match_set: SiteMatchSet, cycles: CycleSet) -> np.ndarray:
    """float64 (M, n, 2) COLMAP px: the observation of each closed cycle in each of its cameras.

    Anchor rule: the cycle's first (lowest-index) camera keeps its site position; every other
    camera c takes the position that pair (anchor, c) refined for the anchor's site
    (`refined_targets_px`), so all observations are of the scene point at the anchor's site. For
    matchers without refined positions this is the site position in every camera.
    """
    anchor = cycles.cameras[0]
    xy = [match_set.sites[anchor][cycles.sites[:, 0]]]
    for k, c in enumerate(cycles.cameras[1:], start=1):
        xy.append(refined_targets_px(match_set, anchor, c, cycles.sites[:, 0], cycles.sites[:, k]))
    return np.stack(xy, axis=1)


def _pooled_pair_correspondences(match_sets, stage1, num_cams) -> dict:
    """{(i, j), i < j: (xy_i (K, 2), xy_j (K, 2))}: the distinct site pairs that take part in a
    stage-1 cycle of any order at any time step (F is the same for all time steps of a rigid rig).
    xy_i is the site position, xy_j the position refined from i's site (`refined_targets_px`)."""
    out = {}
    for i, j in combinations(range(num_cams), 2):
        parts_i, parts_j = [], []
        for t, ms in enumerate(match_sets):
            pairs = []
            for sets in stage1[t].values():
                for cs in sets:
                    if i in cs.cameras and j in cs.cameras:
                        pairs.append(cs.sites[:, [cs.cameras.index(i), cs.cameras.index(j)]])
            if pairs:
                uniq = np.unique(np.concatenate(pairs), axis=0)
                parts_i.append(ms.sites[i][uniq[:, 0]])
                parts_j.append(refined_targets_px(ms, i, j, uniq[:, 0], uniq[:, 1]))
        if parts_i:
            out[(i, j)] = (np.concatenate(parts_i), np.concatenate(parts_j))
    return out

