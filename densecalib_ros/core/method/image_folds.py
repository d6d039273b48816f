"""The image refinement's spatial folds (core.method.image_refinement, module docstring): its dense
tracks dealt out into HOLDOUT_FOLDS folds that each cover the whole of every image, and what the
folds' separate estimates say the images determine: a parameter whose uncertainty, the spread
of the folds' estimates, is below ESTIMATED_FRACTION of its prior's spread. Intrinsics that
several views share are also estimated with each view left out (view_jackknife), and their
uncertainty is at least that spread (determined_by_images; one_camera_jackknife for separate
cameras the one-camera test holds as one). held_out_errors scores a rig adjusted on all folds
but one on that one, for the tests that compare two models of the same images (one camera or
several, a decentering or none)."""
from __future__ import annotations

import logging
from typing import Callable, Optional, Sequence

import numpy as np

from ..parallel import map_threads
from .prior_adjustment import TWO_FOCAL_MODELS, Priors, adjust_with_priors
from .reconstruction import BAStage, SfMState, bundle_adjust, reprojection_errors, triangulate

log = logging.getLogger(__name__)

MAD_TO_SIGMA = 1.4826  # median absolute deviation -> standard deviation of a normal
# A parameter the images hold to less than this fraction of its prior's sigma is "estimated".
ESTIMATED_FRACTION = 0.5
HOLDOUT_FOLDS = 4  # spatial folds of the held-out check (image_refinement's docstring)
HOLDOUT_CELL_FRACTION = 0.1  # fold cells: this fraction of the image's long side
# A block of intrinsics that this many registered cameras share (one camera moved between shots,
# frames of one video) is also resampled over its views (view_jackknife). With three views each
# replicate rests on one pair, whose intrinsics two views do not determine.
JACKKNIFE_MIN_VIEWS = 4
# Observations farther than this many noise sigmas (per coordinate, robust) are dropped between
# adjustments: a Gaussian 2-D residual lies beyond 4 sigma once in ~3000.
GATE_SIGMAS = 4.0
# Held-out correspondences' points are adjusted from their midpoints with the cameras held: each
# point alone converges in a few steps; the cap only bounds a stray one.
HELD_OUT_POINT_ITERATIONS = 50


def _track_cells(state: SfMState) -> tuple[np.ndarray, np.ndarray]:
    """Each of state's tracks' first observing camera (T,) and its cell there (T, 2): squares
    of HOLDOUT_CELL_FRACTION of the long side."""
    tracks = state.tracks
    first = np.argmax(tracks.observed(), axis=1)
    xy = tracks.xy_px[np.arange(tracks.num_tracks), first]
    cell_px = HOLDOUT_CELL_FRACTION * max(max(c.width, c.height) for c in state.intrinsics)
    return first, np.floor(xy / cell_px).astype(np.int64)


def track_folds(state: SfMState) -> np.ndarray:
    """int (T,): each of state's tracks' spatial fold (HOLDOUT_FOLDS of them): the cells
    around its first observation (_track_cells), dealt out in turn, so that every fold covers
    the whole of every image."""
    first, cell = _track_cells(state)
    return (cell[:, 0] + 2 * cell[:, 1] + 3 * first) % HOLDOUT_FOLDS


def track_regions(state: SfMState) -> np.ndarray:
    """int (T,): each of state's tracks' image region, the cell around its first observation
    (_track_cells) numbered from 0: the units the folds deal out, each one on its own."""
    first, cell = _track_cells(state)
    return np.unique(np.c_[first, cell], axis=0, return_inverse=True)[1].ravel()


# Where each of the tied intrinsics (rig_pooling.POOLED_INTRINSICS: f, k1, k2; and the aspect,
# which cameras judged one share: by index into prior_adjustment.INTRINSIC_NAMES) sits in
# fold_values.
FOLD_VALUE_OF = {0: 3, 3: 4, 4: 5, 5: 2, 6: 6, 7: 7}


def fold_values(cam) -> tuple[float, ...]:
    """(cx, cy, aspect, mean focal, k1, k2, p1, p2) of a camera, as the folds compare them (a
    fisheye's k3, k4 in p1's and p2's places; 0 where the model has none)."""
    p = np.asarray(cam.params, float)
    if cam.model in TWO_FOCAL_MODELS:
        return p[2], p[3], p[1] / p[0] - 1.0, 0.5 * (p[0] + p[1]), p[4], p[5], p[6], p[7]
    return p[1], p[2], 0.0, p[0], p[3], p[4], 0.0, 0.0


def view_jackknife(views: dict[int, list[int]], estimate: Callable[[int], Optional[dict]]
                   ) -> dict[int, np.ndarray]:
    """Per block shared by at least JACKKNIFE_MIN_VIEWS registered cameras (views: block -> its
    cameras), the jackknife standard deviations of fold_values over its views: the block
    estimated once with each of its cameras left out (estimate(camera): block -> fold_values, or
    None where the adjustment failed), sqrt((n - 1) / n * sum of squared deviations).

    The spatial folds share every view, so they cannot see what the camera path does to a shared
    camera's estimate: a principal point trades off against the views' common pitch and yaw,
    and which views there are decides how. Leaving a view out changes the path and shows it
    (docs/design-notes.md, Image refinement: one camera's views left out in turn)."""
    out = {}
    for b, cams in views.items():
        if len(cams) < JACKKNIFE_MIN_VIEWS:
            continue
        replicates = [e[b] for e in map_threads(estimate, cams) if e is not None and b in e]
        values = np.array(replicates, dtype=float)
        if len(values) < len(cams) - 1 or not np.isfinite(values).all():
            continue
        n = len(values)
        out[b] = np.sqrt((n - 1) / n * ((values - values.mean(axis=0)) ** 2).sum(axis=0))
        log.debug("block %d: view jackknife of cx, cy, aspect, f, k1, k2 over %d views: %s", b,
                  n, np.round(out[b], 4).tolist())
    return out


def _free_estimate(part: SfMState, blocks: list[int], ties: Sequence = ()) -> Optional[dict]:
    """block -> fold_values of `part` adjusted without priors but Priors.ties `ties` (in place),
    None where the adjustment fails."""
    part.drop_weak_points()
    free = Priors(principal_point_std_px={b: np.inf for b in blocks},
                  aspect_std={b: np.inf for b in blocks}, ties=list(ties))
    try:
        adjust_with_priors(part, blocks, free)
    except (ValueError, np.linalg.LinAlgError):
        return None
    return {b: fold_values(part.intrinsics[b]) for b in blocks}


def _without_view(state: SfMState, camera: int) -> SfMState:
    part = state.copy()
    part.cam_from_world[camera] = None
    return part


def determined_by_images(state: SfMState, blocks: list[int], priors: Priors
                         ) -> tuple[dict, dict]:
    """Per block, which of "principal point" and "aspect" the images determine
    (core.method.image_refinement, module docstring), and the folds' standard deviations of the
    mean of the principal point (per axis), of the focal length (px) and of each tied intrinsic
    (determined_by_folds): from the folds' estimates, adjusted without priors from `state` (the
    found rig: the principal point at the image centre, square pixels), and for a block several
    cameras share, at least the spread of its estimates with each of them left out
    (view_jackknife)."""
    fold = track_folds(state)

    def fold_estimate(k: int) -> Optional[dict]:
        part = state.copy()
        part.active[fold != k] = False
        return _free_estimate(part, blocks)
    # the folds and the views left out are independent adjustments, side by side
    estimates = [e for e in map_threads(fold_estimate, range(HOLDOUT_FOLDS)) if e is not None]
    views = {b: [c for c in state.registered() if int(state.camera_block[c]) == b]
             for b in blocks}
    floors = view_jackknife(views, lambda c: _free_estimate(_without_view(state, c), blocks))
    return determined_by_folds(estimates, blocks, priors, floors)


def one_camera_jackknife(state: SfMState, blocks: list[int], members: list[int],
                         ties: Sequence) -> Optional[np.ndarray]:
    """view_jackknife's standard deviations (fold_values' order) for the blocks `members` that
    the one-camera test holds together as one camera (Priors.ties `ties`): `state` (the found
    rig) adjusted without priors but the ties, with each of their cameras left out in turn, the
    one camera's estimate the mean over the members that keep a camera. None where fewer than
    JACKKNIFE_MIN_VIEWS cameras are theirs. Separate cameras judged one share the view-to-view
    trade-off of a shared block (view_jackknife) that their spatial folds cannot see."""
    cams = [c for c in state.registered() if int(state.camera_block[c]) in members]

    def estimate(c: int) -> Optional[dict]:
        part = _without_view(state, c)
        values = _free_estimate(part, blocks, ties)
        if values is None:
            return None
        kept = {int(part.camera_block[k]) for k in part.registered()}
        return {members[0]: np.mean([values[b] for b in members if b in kept], axis=0)}
    return view_jackknife({members[0]: cams}, estimate).get(members[0])


def determined_by_folds(estimates: list[dict], blocks: list[int], priors: Priors,
                        floors: Optional[dict[int, np.ndarray]] = None) -> tuple[dict, dict]:
    """Per block, which of "principal point" and "aspect" the images determine, from the folds'
    estimates (per fold: block -> fold_values): those whose estimates scatter by less than
    ESTIMATED_FRACTION of the prior's sigma once averaged over the folds. The scatter is the
    folds' median absolute deviation (as a sigma): one fold that ran off on a weak part of the
    images does not decide it. Also per block the folds' standard deviations of the mean of the
    principal point (per axis), of the focal length (px) and of each tied intrinsic
    (rig_pooling.POOLED_INTRINSICS): how far off the images leave them. floors: per block,
    standard deviations in fold_values' order (view_jackknife's) that these are at least."""
    out, spread_of = {}, {}
    for b in blocks:
        values = np.array([e[b] for e in estimates])
        if len(values) < 2 or not np.isfinite(values).all():
            out[b] = set()
            continue
        std_of_mean = folds_std_of_mean(values)
        if floors is not None and b in floors:
            std_of_mean = np.maximum(std_of_mean, floors[b])
        spread_of[b] = dict(principal_point_axes_px=(float(std_of_mean[0]), float(std_of_mean[1])),
                            focal_px=float(std_of_mean[3]),
                            # the tied ones (POOLED_INTRINSICS) by index into INTRINSIC_NAMES
                            intrinsics={i: float(std_of_mean[k])
                                        for i, k in FOLD_VALUE_OF.items()})
        log.debug("block %d: fold estimates of cx, cy, aspect, f, k1, k2 %s, sigma of their "
                  "mean %s", b,
                  np.round(values, 4).tolist(), np.round(std_of_mean, 4).tolist())
        out[b] = set()
        if principal_point_determined(std_of_mean[:2], priors.principal_point_std_px[b]):
            out[b].add("principal point")
        if std_of_mean[2] < ESTIMATED_FRACTION * priors.aspect_std[b]:
            out[b].add("aspect")
    return out, spread_of


def folds_std_of_mean(values: np.ndarray) -> np.ndarray:
    """Per column the standard deviation of the mean of the folds' estimates (rows): their
    median absolute deviation as a sigma (one fold that ran off on a weak part of the images
    does not decide it) over sqrt(folds)."""
    spread = MAD_TO_SIGMA * np.median(np.abs(values - np.median(values, axis=0)), axis=0)
    return spread / np.sqrt(len(values))


def principal_point_determined(axes_std_px, prior_std_px: float) -> bool:
    """Whether the images determine a principal point whose estimate has these standard
    deviations per axis (the folds'), against a prior of prior_std_px (ESTIMATED_FRACTION)."""
    return max(axes_std_px) < ESTIMATED_FRACTION * prior_std_px


def held_out_errors(state: SfMState, blocks: list[int], priors: Priors, noise_px: float,
                     camera_names: Sequence[str], iterations: Optional[int]) -> np.ndarray:
    """Per fold (`track_folds`) the mean squared reprojection error (px^2) of its correspondences,
    triangulated anew with the rig adjusted under `priors` on the other folds; each error is
    truncated at the gate (GATE_SIGMAS noise sigmas), and an observation whose point cannot be
    triangulated counts the gate. iterations: the adjustments' cap (None: the adjustment's own)."""
    fold = track_folds(state)
    cap = {} if iterations is None else {"max_iterations": iterations}
    gate_px = GATE_SIGMAS * noise_px

    def fold_error(k: int) -> float:
        train = state.copy()
        train.active[fold == k] = False
        train.drop_weak_points()
        adjust_with_priors(train, blocks, priors, noise_px=noise_px, **cap)
        test = train.copy()
        test.active = state.active & (fold == k)[:, None]
        rows = np.flatnonzero(fold == k)
        test.points_xyz[:] = np.nan
        triangulate(test, rows, max_error_px=np.inf, min_angle_deg=0.0)
        views = test.registered_active()[rows]
        observed = views & (views.sum(axis=1) >= 2)[:, None]
        if test.point_mask()[rows].any():
            bundle_adjust(test, camera_names, BAStage(HELD_OUT_POINT_ITERATIONS,
                                                      refine_focal=False, refine_extra=False,
                                                      refine_poses=False), num_threads=1)
        err = reprojection_errors(test)[rows][observed]
        return (float(np.mean(np.minimum(np.nan_to_num(err, nan=gate_px), gate_px) ** 2))
                if err.size else np.nan)
    return np.array(map_threads(fold_error, range(HOLDOUT_FOLDS)))
