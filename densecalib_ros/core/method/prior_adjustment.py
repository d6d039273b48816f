"""Bundle adjustment of pinhole cameras with Gaussian priors on the intrinsics the images pin down
least (maximum a posteriori), and the intrinsics' covariance at a solution
(core.method.prior_covariance).

Why a prior and not a switch: a principal point offset by d px is almost the same image as the
camera turned by d / f rad; only a second-order warp (~d tan^2 of the ray angle) and the
distortion centre tell them apart. Held at the image centre, a real lens's point (0.5-2 % of the
side off) turns every camera by ~d / f (1 deg at f = 800 px, d = 15 px). Freed with nothing to
hold it, it wanders by tens of pixels on the noise and on what the model cannot express (lens
aspect, wrong matches), with no better fit to show for it. A Gaussian prior of the spread real
lenses have keeps it where the images do not speak and lets them move it where they do; the
posterior covariance says which of the two happened.

The same holds for the pixel aspect (fy / fx - 1): real sensors are within a few tenths of a
percent of square, RADIAL cannot express any, and an unmodelled 0.5 % shows up as a residual
warp that the principal point and poses then absorb.

Parameters per camera block (RADIAL cameras; OPENCV ones with their decentering p1, p2 where it is
freed; OPENCV_FISHEYE ones with k3, k4 in p1's and p2's places, always free): f, cx, cy, k1, k2 and
the aspect a (fy = f (1 + a)); poses of every registered camera but the reference (gauge; the scale
is left free and damped, it changes no intrinsics); every point. Residuals: COLMAP-pixel
reprojection errors of the active observations of reconstruction points, Cauchy loss with COLMAP's
scale, weighted by 1 / sigma_n^2 with sigma_n the pixel noise of the fit (robust, from the
residuals); priors (value - centre) / sigma; ties (Priors.ties) (value - the tied blocks' weighted
mean) / sigma, the mean profiled out. Levenberg-Marquardt on the reduced camera system (Schur
complement over the points: every point is a 3x3 block)."""
from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import Optional, Sequence

import cv2
import numpy as np

from ..progress import check_stop
from ..types import CameraIntrinsics
from .prior_adjustment_kernels import (damped_point_inverses, _observation_products,
                                       _point_products, point_steps, _project, _to_columns)
from .reconstruction import SfMState

log = logging.getLogger(__name__)

# Per block: f, cx, cy, k1, k2, aspect, tangential p1, p2 (OPENCV's). Poses: rotation (3, left
# increment), translation (3).
INTRINSIC_NAMES = ("f", "cx", "cy", "k1", "k2", "aspect", "p1", "p2")
_NI, _NP = len(INTRINSIC_NAMES), 6
# Cauchy loss scale (px), as every other adjustment here (reconstruction.bundle_adjust: COLMAP's).
LOSS_SCALE_PX = 1.0
# The noise floor: sigma_n is never taken below this (a fit of exact synthetic tracks would make
# every prior irrelevant; no matcher localises better than ~0.05 px).
MIN_NOISE_PX = 0.05
NOISE_TOLERANCE = 0.2  # a re-measured noise within this fraction of the one used: solved
# Converged when an iteration lowers the cost by less than this fraction (Ceres' default
# function tolerance, as reconstruction.FUNCTION_TOLERANCE).
RELATIVE_DECREASE = 1e-6
_RAYLEIGH_MEDIAN = 1.1774  # median of |2D residual| / per-coordinate sigma for Gaussian noise


@dataclass
class Priors:
    """Gaussian priors per intrinsics block (index into SfMState.intrinsics): the standard
    deviation of each axis of the principal point around its prior centre (px; the image centre
    unless principal_point_centre_px gives one) and of the pixel aspect around 1 (fraction).
    None: that parameter is held at its current value."""

    principal_point_std_px: dict = field(default_factory=dict)  # block -> px or None
    aspect_std: dict = field(default_factory=dict)  # block -> fraction or None
    tangential_std: dict = field(default_factory=dict)  # block -> p1, p2 sigma or None
    principal_point_centre_px: dict = field(default_factory=dict)  # block -> (cx, cy)
    # [(index into INTRINSIC_NAMES, {block: sigma})]: that intrinsic tied across those blocks, a
    # Gaussian on each one's difference from their precision-weighted mean, which is left free
    # (the rig's own spread: core.method.rig_pooling); blocks where it is held are left out.
    ties: list = field(default_factory=list)


@dataclass
class PriorAdjustment:
    """What the adjustment did: blocks adjusted, the pixel noise sigma_n (px, per coordinate) it
    weighted the images by, the MAP cost (at that noise) before and after, iterations, and the
    priors it ran with (prior_covariance.posterior_covariance gives the covariance at the solution: most
    adjustments, the folds' and the held-out tests', need none)."""

    blocks: list[int]
    noise_px: float
    # Robust per-coordinate scale of the residuals at the solution (px; at least MIN_NOISE_PX):
    # smaller than noise_px, since each point absorbs part of its observations' noise.
    residual_scale_px: float
    cost_before: float
    cost_after: float
    iterations: int
    priors: Priors


# The perspective models this adjustment projects, as (f, cx, cy, k1, k2, aspect, p1, p2), and
# the fisheye ones, as (f, cx, cy, k1, k2, aspect, k3, k4) (kernels._project_fisheye).
PERSPECTIVE_MODELS = ("SIMPLE_PINHOLE", "PINHOLE", "SIMPLE_RADIAL", "RADIAL", "OPENCV")
FISHEYE_MODELS = ("RADIAL_FISHEYE", "OPENCV_FISHEYE")
SUPPORTED_MODELS = PERSPECTIVE_MODELS + FISHEYE_MODELS
# Those written fx, fy, cx, cy and four distortion terms: the pixel aspect is fy / fx - 1.
TWO_FOCAL_MODELS = ("OPENCV", "OPENCV_FISHEYE")
# The models it adjusts (the others of SUPPORTED_MODELS it holds, e.g. given intrinsics).
ADJUSTED_MODELS = ("RADIAL", "OPENCV") + FISHEYE_MODELS


def perspective_blocks(intrinsics: Sequence[CameraIntrinsics], blocks: Sequence[int]) -> list[int]:
    """The blocks of `blocks` whose model is a perspective one (intrinsics: per block): those
    whose last two parameters are a decentering (p1, p2); a fisheye block's are its k3, k4, free
    as its k1, k2 are."""
    return [b for b in blocks if intrinsics[b].model not in FISHEYE_MODELS]


def intrinsics_vector(cam: CameraIntrinsics) -> np.ndarray:
    """cam's parameters as INTRINSIC_NAMES (ValueError for a model not in SUPPORTED_MODELS)."""
    p = np.asarray(cam.params, float)
    if cam.model == "SIMPLE_PINHOLE":
        return np.array([p[0], p[1], p[2], 0, 0, 0, 0, 0])
    if cam.model == "PINHOLE":
        return np.array([p[0], p[2], p[3], 0, 0, p[1] / p[0] - 1.0, 0, 0])
    if cam.model == "SIMPLE_RADIAL":
        return np.array([p[0], p[1], p[2], p[3], 0, 0, 0, 0])
    if cam.model in ("RADIAL", "RADIAL_FISHEYE"):
        return np.array([p[0], p[1], p[2], p[3], p[4], 0, 0, 0])
    if cam.model in TWO_FOCAL_MODELS:  # a fisheye's k3, k4 in p1's and p2's places
        return np.array([p[0], p[2], p[3], p[4], p[5], p[1] / p[0] - 1.0, p[6], p[7]])
    raise ValueError(f"prior adjustment: a {cam.model} camera; it projects "
                     f"{', '.join(SUPPORTED_MODELS)}")


class AdjustmentProblem:
    """Observations, parameter layout and the current estimate."""

    def __init__(self, state: SfMState, blocks: list[int], priors: Priors):
        self.state = state
        registered = state.registered()
        self.reference = registered[0]
        points = state.point_mask()
        obs = state.registered_active() & points[:, None]
        t_idx, c_idx = np.nonzero(obs)
        self.t_idx, self.c_idx = t_idx, c_idx
        self.xy = state.tracks.xy_px[t_idx, c_idx]
        self.tracks = np.flatnonzero(points)
        self.point_of_track = np.full(state.tracks.num_tracks, -1)
        self.point_of_track[self.tracks] = np.arange(len(self.tracks))
        self.p_idx = self.point_of_track[t_idx]
        # Observations are in track order, then camera order (np.nonzero, row-major): each
        # point's are contiguous from here, and _point_products' mirroring relies on the order.
        self.first_obs = np.searchsorted(self.p_idx, np.arange(len(self.tracks) + 1))
        self.X = state.points_xyz[self.tracks].copy()
        C = state.num_cameras
        self.R = np.zeros((C, 3, 3))
        self.t = np.zeros((C, 3))
        for c in registered:
            self.R[c], self.t[c] = state.cam_from_world[c][:3, :3], state.cam_from_world[c][:3, 3]
        self.block_of = np.asarray(state.camera_block)
        self.K = np.zeros((len(state.intrinsics), _NI))
        for b, cam in enumerate(state.intrinsics):
            self.K[b] = intrinsics_vector(cam)
        self.fisheye = np.array([cam.model in FISHEYE_MODELS for cam in state.intrinsics])
        self.centre = np.array([priors.principal_point_centre_px.get(
            b, (cam.width / 2.0, cam.height / 2.0)) for b, cam in enumerate(state.intrinsics)],
            dtype=float)
        self.priors = priors
        # Free parameters: poses of registered cameras but the reference; per adjusted block f,
        # k1, k2 and, where it has a prior, cx and cy and the aspect.
        index = 0
        self.pose_cols = np.full((C, _NP), -1)
        for c in registered:
            if c != self.reference:
                self.pose_cols[c] = np.arange(index, index + _NP)
                index += _NP
        self.intr_cols = np.full((len(state.intrinsics), _NI), -1)
        for b in blocks:
            pp = priors.principal_point_std_px.get(b) is not None
            # a fisheye block's last two are its k3, k4, free as its k1, k2 are
            tangential = priors.tangential_std.get(b) is not None or bool(self.fisheye[b])
            free = [True, pp, pp, True, True, priors.aspect_std.get(b) is not None,
                    tangential, tangential]
            for k in range(_NI):
                if free[k]:
                    self.intr_cols[b, k] = index
                    index += 1
        self.num_cam_params = index
        # Per camera and per observation: the columns of its 6 pose + 8 intrinsic parameters
        # (cameras of one block share their intrinsics' columns); a held one's is
        # num_cam_params, a column the sums collect and then drop. Only the parameters some
        # camera frees (`used`, indices into the 14) enter the sums: the pipeline holds the
        # tangential ones in every adjustment, and the point products cost the square of their
        # number.
        cols = np.concatenate([self.pose_cols, self.intr_cols[self.block_of]], axis=1)
        self.used = np.flatnonzero((cols >= 0).any(axis=0))
        self.camera_cols = np.where(cols >= 0, cols, self.num_cam_params)[:, self.used]
        self.obs_cols = self.camera_cols[c_idx]
        self.observing_cameras = [int(c) for c in np.unique(c_idx)]

    def residuals_and_jacobians(self, with_jacobians: bool = True):
        """r (N, 2) px and, if asked, A (N, 2, 6 + 8) camera-side and B (N, 2, 3) point
        Jacobians (_project)."""
        N = len(self.c_idx)
        res = np.empty((N, 2))
        A = np.zeros((N if with_jacobians else 0, 2, _NP + _NI))
        B = np.empty((N if with_jacobians else 0, 2, 3))
        _project(self.R, self.t, self.X, self.K, self.block_of, self.c_idx, self.p_idx, self.xy,
                 res, A, B, self.fisheye)
        return (res, A, B) if with_jacobians else res

    def prior_terms(self):
        """[(column, residual in sigmas, 1 / sigma)] of every prior on a free parameter."""
        out = []
        for b in range(len(self.K)):
            pp = self.priors.principal_point_std_px.get(b)
            if pp is not None and self.intr_cols[b, 1] >= 0:
                out.append((self.intr_cols[b, 1], (self.K[b, 1] - self.centre[b, 0]) / pp, 1 / pp))
                out.append((self.intr_cols[b, 2], (self.K[b, 2] - self.centre[b, 1]) / pp, 1 / pp))
            sa = self.priors.aspect_std.get(b)
            if sa is not None and self.intr_cols[b, 5] >= 0:
                out.append((self.intr_cols[b, 5], self.K[b, 5] / sa, 1 / sa))
            st = self.priors.tangential_std.get(b)
            if st is not None and self.intr_cols[b, 6] >= 0:
                out.append((self.intr_cols[b, 6], self.K[b, 6] / st, 1 / st))
                out.append((self.intr_cols[b, 7], self.K[b, 7] / st, 1 / st))
        return out

    def tie_terms(self):
        """[(columns, the values' differences from their weighted mean, weights 1 / sigma^2)]
        of every tie (Priors.ties) with two or more free blocks."""
        out = []
        for i, sigmas in self.priors.ties:
            free = [b for b in sigmas if self.intr_cols[b, i] >= 0]
            if len(free) < 2:
                continue
            values = self.K[free, i]
            weights = np.array([sigmas[b] for b in free], float) ** -2.0
            mean = float(np.sum(weights * values) / np.sum(weights))
            out.append((self.intr_cols[free, i], values - mean, weights))
        return out

    def cost(self, noise_px: float, res: Optional[np.ndarray] = None) -> float:
        res = self.residuals_and_jacobians(False) if res is None else res
        s2 = np.sum(res * res, axis=1)
        c2 = LOSS_SCALE_PX ** 2
        data = np.sum(c2 * np.log1p(s2 / c2)) / noise_px ** 2
        return float(data + sum(e * e for _, e, _ in self.prior_terms())
                     + sum(np.sum(w * d * d) for _, d, w in self.tie_terms()))

    def apply(self, delta_cam: np.ndarray, delta_pts: np.ndarray) -> dict:
        """Apply a step; returns what is needed to undo it."""
        saved = dict(R=self.R.copy(), t=self.t.copy(), K=self.K.copy(), X=self.X.copy())
        for c in range(len(self.R)):
            cols = self.pose_cols[c]
            if cols[0] < 0:
                continue
            w, dt = delta_cam[cols[:3]], delta_cam[cols[3:]]
            E = cv2.Rodrigues(np.asarray(w, float))[0]
            self.R[c] = E @ self.R[c]
            self.t[c] = E @ self.t[c] + dt
        mask = self.intr_cols >= 0
        self.K[mask] += delta_cam[self.intr_cols[mask]]
        self.X += delta_pts
        return saved

    def restore(self, saved: dict) -> None:
        self.R, self.t, self.K, self.X = saved["R"], saved["t"], saved["K"], saved["X"]


def normal_equations(problem: AdjustmentProblem, noise_px: float,
                     point_weight: Optional[np.ndarray] = None):
    """Robust-weighted normal equations: U (M, M), Wt (N, 3, K), V (P, 3, 3), g_cam (M,),
    g_pt (P, 3), each observation's camera columns (N, K; M where held) and the residuals; K
    columns of each camera: those of its parameters that some camera frees (AdjustmentProblem.used).
    Held columns' parts go to a column M, dropped (Wt keeps them: every use of it adds them
    to column M or multiplies them by a zero step). point_weight (P,): each point's
    observations' weights scaled by it (0: left out)."""
    res, A, B = problem.residuals_and_jacobians()
    w = cauchy_weights(res, noise_px)
    if point_weight is not None:
        w = w * point_weight[problem.p_idx]
    M, P = problem.num_cam_params, len(problem.X)
    U_cam, g_of_cam, V, g_pt, Wt = _observation_products(res, A, B, w, problem.used,
                                                        problem.c_idx, problem.p_idx,
                                                        len(problem.R), P)
    cols = problem.camera_cols
    U, g_cam = np.zeros((M + 1, M + 1)), np.zeros(M + 1)
    for c in problem.observing_cameras:
        U[np.ix_(cols[c], cols[c])] += U_cam[c]
        g_cam[cols[c]] += g_of_cam[c]
    U, g_cam = U[:M, :M], g_cam[:M]
    add_prior_terms(problem, U, g_cam)
    return U, Wt, V, g_cam, g_pt, problem.obs_cols, res


def cauchy_weights(res: np.ndarray, noise_px: float) -> np.ndarray:
    """(N,) the Cauchy loss's IRLS weight of each observation's residual (N, 2), over sigma_n^2."""
    s2 = np.sum(res * res, axis=1)
    return 1.0 / (1.0 + s2 / LOSS_SCALE_PX ** 2) / noise_px ** 2


def add_prior_terms(problem: AdjustmentProblem, U: np.ndarray, g_cam: np.ndarray) -> None:
    """The priors' and ties' information and gradient added to U (M, M) and g_cam (M,)."""
    for col, e, inv_sigma in problem.prior_terms():
        U[col, col] += inv_sigma ** 2
        g_cam[col] += e * inv_sigma
    for cols, d, w in problem.tie_terms():  # the mean profiled out: no pull on the rig's level
        U[np.ix_(cols, cols)] += np.diag(w) - np.outer(w, w) / np.sum(w)
        g_cam[cols] += w * d


def reduced_system(problem: AdjustmentProblem, U, Wt, V_inv, g_cam, g_pt):
    """The reduced camera system S = U - sum over points of W_p V_p^-1 W_p^T (M, M) and its
    right-hand side -g_cam + sum over points of W_p V_p^-1 g_p (M,): each point's share
    computed camera pair by camera pair (_point_products), then added to the cameras' columns
    (problem.camera_cols; held ones go to a column M, dropped)."""
    M = problem.num_cam_params
    products, yg = _point_products(Wt, V_inv, g_pt, problem.first_obs, problem.c_idx,
                                   len(problem.R))
    S, r = _to_columns(products, yg, problem.camera_cols, problem.obs_cols, M + 1)
    return U - S[:M, :M], r[:M] - g_cam


def adjust_with_priors(state: SfMState, blocks: list[int], priors: Priors,
                       max_iterations: int = 50, noise_px: Optional[float] = None
                       ) -> PriorAdjustment:
    """MAP adjustment of `state` in place (module docstring); `blocks`: the intrinsics blocks
    refined (ADJUSTED_MODELS); the others are held. A perspective block whose aspect ends free is
    written back as OPENCV (fx, fy, cx, cy, k1, k2, p1, p2), else in its own model; a fisheye
    block as OPENCV_FISHEYE.
    noise_px: sigma_n; None estimates it from the residuals at the start."""
    for b in blocks:
        if state.intrinsics[b].model not in ADJUSTED_MODELS:
            raise ValueError(f"prior adjustment: block {b} is {state.intrinsics[b].model}; "
                             f"{', '.join(ADJUSTED_MODELS)} cameras are adjusted (others may be "
                             "held)")
    problem = AdjustmentProblem(state, blocks, priors)
    if not len(problem.t_idx):
        raise ValueError("prior adjustment: no observations")
    estimate_noise = noise_px is None
    noise_px = _noise_px(problem) if estimate_noise else noise_px
    start = dict(R=problem.R.copy(), t=problem.t.copy(), K=problem.K.copy(), X=problem.X.copy())
    iterations = 0
    # The noise is measured on the residuals; from a start far from the solution they are larger
    # than the noise, so it is measured again at the solution and the solve repeated once.
    for _ in range(2 if estimate_noise else 1):
        iterations += _levenberg_marquardt(problem, noise_px, max_iterations)
        if not estimate_noise:
            break
        measured = _noise_px(problem)
        if abs(measured - noise_px) <= NOISE_TOLERANCE * noise_px:
            break
        noise_px = measured
    solution = dict(R=problem.R, t=problem.t, K=problem.K, X=problem.X)
    problem.restore(start)
    cost_before = problem.cost(noise_px)
    problem.restore(solution)
    _write_back(problem, state, blocks)
    return PriorAdjustment(blocks=list(blocks), noise_px=noise_px,
                           residual_scale_px=_residual_scale_px(problem),
                           cost_before=cost_before, cost_after=problem.cost(noise_px),
                           iterations=iterations, priors=priors)


def _levenberg_marquardt(problem: AdjustmentProblem, noise_px: float, max_iterations: int) -> int:
    """Levenberg-Marquardt on the reduced camera system, in place; returns the iterations."""
    cost = problem.cost(noise_px)
    lam, iterations = 1e-4, 0
    for iterations in range(1, max_iterations + 1):
        check_stop()  # a stopped calibration ends between iterations
        U, Wt, V, g_cam, g_pt, flat, _ = normal_equations(problem, noise_px)
        improved = False
        for _ in range(10):
            Ud = U + lam * np.diag(np.maximum(np.diag(U), 1e-9))
            V_inv = damped_point_inverses(V, lam)
            S, rhs = reduced_system(problem, Ud, Wt, V_inv, g_cam, g_pt)
            try:
                delta_cam = np.linalg.solve(S, rhs)
            except np.linalg.LinAlgError:
                delta_cam = np.linalg.lstsq(S, rhs, rcond=None)[0]
            delta_pts = point_steps(Wt, V_inv, g_pt, np.r_[delta_cam, 0.0], flat,
                                     problem.first_obs)
            saved = problem.apply(delta_cam, delta_pts)
            new_cost = problem.cost(noise_px)
            if np.isfinite(new_cost) and new_cost < cost:
                improved = True
                lam = max(lam / 3.0, 1e-9)
                break
            problem.restore(saved)
            lam *= 4.0
        if not improved:
            break
        decrease, cost = cost - new_cost, new_cost
        if decrease < RELATIVE_DECREASE * cost:
            break
    return iterations


def _residual_scale_px(problem: AdjustmentProblem) -> float:
    """Robust per-coordinate scale of the residuals (median of the 2-D norm over the Rayleigh
    median), at least MIN_NOISE_PX."""
    res = problem.residuals_and_jacobians(False)
    return max(float(np.median(np.linalg.norm(res, axis=1))) / _RAYLEIGH_MEDIAN, MIN_NOISE_PX)


def _noise_px(problem: AdjustmentProblem) -> float:
    """The pixel noise sigma_n per coordinate: the residuals' robust scale, corrected for the
    degrees of freedom the points take (a 2-view point absorbs 3 of its 4 coordinates' noise)."""
    return max(_residual_scale_px(problem) * points_dof_factor(len(problem.t_idx), len(problem.X)),
               MIN_NOISE_PX)


def points_dof_factor(num_observations: int, num_points: int) -> float:
    """sqrt(2 n / (2 n - 3 p)): how much smaller the residuals of a fit are than the pixel noise
    where p points take 3 each of the 2 n coordinates of their n observations; 1 where no
    observation is counted (nothing to correct by)."""
    if num_observations <= 0:
        return 1.0
    return float(np.sqrt(2 * num_observations / max(2 * num_observations - 3 * num_points, 1)))


def _write_back(problem: AdjustmentProblem, state: SfMState, blocks: list[int]) -> None:
    for c in state.registered():
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = problem.R[c], problem.t[c]
        state.cam_from_world[c] = T
    state.points_xyz[problem.tracks] = problem.X
    for b in blocks:
        cam = state.intrinsics[b]
        f, cx, cy, k1, k2, a, p1, p2 = problem.K[b]
        if problem.fisheye[b]:  # p1, p2 are k3, k4 here
            state.intrinsics[b] = CameraIntrinsics("OPENCV_FISHEYE", cam.width, cam.height,
                                                   np.array([f, f * (1 + a), cx, cy, k1, k2,
                                                             p1, p2]))
        elif (problem.intr_cols[b, 5:] >= 0).any() or np.any(problem.K[b, 5:] != 0.0):
            state.intrinsics[b] = CameraIntrinsics("OPENCV", cam.width, cam.height,
                                                   np.array([f, f * (1 + a), cx, cy, k1, k2,
                                                             p1, p2]))
        else:
            state.intrinsics[b] = CameraIntrinsics("RADIAL", cam.width, cam.height,
                                                   np.array([f, cx, cy, k1, k2]))
