"""Initial focal lengths of all cameras from the pairwise fundamental matrices (paper Sec. 3.3, eq.
2).

For cameras i, j with pinhole calibrations K_i, K_j (f_x = f_y = f, principal point at the image
centre, no distortion) the matrix E_ji = K_j^T F_ji K_i is an essential matrix exactly when the
focals are right, i.e. its two non-zero singular values are equal. The residual per pair is

    r_ij = w_ij * ((s1 - s2) / (s1 + s2) + s3 / s1),   s1 >= s2 >= s3 the singular values of E_ji.

Scaling of the s3 term: F is only defined up to scale, so E is normalised to s1 = 1 before s3 is
added (the term is s3 / s1 in [0, 1], scale-free like the first term). For the rank-2 F's that
MAGSAC++ returns s3 is ~1e-17 whatever the focals (K_i, K_j are invertible), so the term only
matters for an F that is not rank 2; it is kept as in the paper.

All pairs are solved together by non-linear least squares in log-focal space (scipy
least_squares, Cauchy loss so one bad pair is down-weighted), from a few uniform restarts around the
prior f = 1.2 * max(w, h). The restarts minimise a smooth form with the same zero set (the cubic
essential-matrix constraint), because eq. 2's |s1 - s2| is a cone at the optimum on which
Gauss-Newton needs ~800 iterations; the best restart is then polished on eq. 2 itself (analytic
Jacobian). Its time and accuracy: docs/design-notes.md (Initial focals from the F's). A tiny prior
term (weight 1e-3 on log(f / f_prior)) keeps directions that the F's do not constrain (e.g. a
camera pair whose optical axes intersect, the classical degeneracy of focal-from-F) at the prior
instead of drifting; its bias on constrained directions is negligible (same section).
"""
from __future__ import annotations

import logging
from typing import Optional

import numpy as np
from scipy.optimize import least_squares

from ..errors import FocalInitError

LOG = logging.getLogger(__name__)

PRIOR_FOCAL_FACTOR = 1.2  # f_prior = 1.2 * max(w, h): a ~45 deg horizontal field of view
FOCAL_BOUNDS_FACTOR = (0.1, 20.0)  # focal must lie in [0.1, 20] * max(w, h)
PRIOR_WEIGHT = 1e-3
ROBUST_SCALE = 0.05  # Cauchy scale on r_ij: a good pair's residual is ~0.01, a wrong F's ~0.3
# Above this (median over pairs, weighted by w_ij as in the solve) the F's agree on no focals.
# Weighted: pairs with few matches are the ones likely to carry a wrong F between cameras that
# barely overlap, and the solve already discounts them (docs/design-notes.md, Initial focals
# from the F's).
MAX_MEDIAN_RESIDUAL = 0.2
RESTART_FACTORS = (1.0, 0.5, 2.0, 4.0)
# How the user can skip this estimate (focal_start.start_focals); ends every FocalInitError message.
KNOWN_FOCALS_HINT = ("give the focal lengths if you know them (--focal-px; node and "
                     "PipelineConfig: initial_focal_px).")


def calibration_matrix(focal_px: float, principal_point_px) -> np.ndarray:
    """3x3 pinhole K on COLMAP pixels."""
    return np.array([[focal_px, 0.0, principal_point_px[0]],
                     [0.0, focal_px, principal_point_px[1]],
                     [0.0, 0.0, 1.0]])


def weighted_median(values: np.ndarray, weights: np.ndarray) -> float:
    """The smallest value below or at which at least half of the total weight lies."""
    order = np.argsort(values)
    cumulative = np.cumsum(weights[order])
    return float(values[order][np.searchsorted(cumulative, 0.5 * cumulative[-1])])


def essential_residual(F_ji: np.ndarray, K_i: np.ndarray, K_j: np.ndarray) -> float:
    """Unweighted eq. 2 residual (s1 - s2) / (s1 + s2) + s3 / s1 of E = K_j^T F_ji K_i."""
    s = np.linalg.svd(K_j.T @ F_ji @ K_i, compute_uv=False)
    return float((s[0] - s[1]) / (s[0] + s[1]) + s[2] / s[0])


def estimate_initial_focals(F: dict, weights: dict, image_sizes: list,
                            principal_points: Optional[list] = None,
                            known_px: Optional[np.ndarray] = None) -> np.ndarray:
    """Focal length in pixels per camera, (C,) float64, from fundamental matrices of camera pairs.

    F: {(i, j): F_ji (3, 3) with x_j^T F_ji x_i = 0 on COLMAP pixels, or None}.
    weights: {(i, j): w_ij} (paper: n_ij / max n); pairs with weight <= 0 are ignored.
    image_sizes: [(width, height)] per camera; principal_points: [(cx, cy)] COLMAP px per camera,
      default the image centre (w / 2, h / 2).
    known_px: (C,) focals already known [px], NaN where not: held fixed, so they set the scale the
      others are solved at (eq. 2 alone tends to miss by a factor common to all cameras).
    Raises FocalInitError when a camera has no usable pair, or when the least-squares problem
    does not converge to focals inside [0.1, 20] * max(w, h) with consistent F's.
    """
    num_cams = len(image_sizes)
    if principal_points is None:
        principal_points = [(w / 2.0, h / 2.0) for w, h in image_sizes]
    pairs, F_list, w_list = _usable_pairs(F, weights)
    known = np.full(num_cams, np.nan) if known_px is None else np.asarray(known_px, np.float64)
    fixed = np.isfinite(known)
    covered = {c for p in pairs for c in p}
    missing = [c for c in range(num_cams) if c not in covered and not fixed[c]]
    if missing:
        raise FocalInitError(
            "No usable fundamental matrix for camera(s) {cameras}: they share too few "
            "cycle-consistent matches with the other cameras. Check that each of them sees the "
            "scene (not a covered, dark, blank or defocused lens) and overlaps at least one other "
            "camera; if so, " + KNOWN_FOCALS_HINT, missing)
    if fixed.all():
        return known.copy()
    problem = _Eq2Problem(pairs, F_list, np.array(w_list), image_sizes, principal_points, known)
    best = problem.solve()
    if best is None:
        raise FocalInitError(
            "Initial focal estimation did not converge: the fundamental matrices are degenerate. "
            "Use more overlapping views or scene texture, or "
            + KNOWN_FOCALS_HINT)
    log_f = problem.full(best.x)
    focal = np.where(fixed, known, np.exp(log_f))
    lower, upper = problem.lower, problem.upper
    at_bound = np.abs(log_f - lower) < 1e-3 * np.abs(lower) + 1e-6
    at_bound |= np.abs(log_f - upper) < 1e-3 * np.abs(upper) + 1e-6
    at_bound &= ~fixed
    if np.any(at_bound):
        bad = np.flatnonzero(at_bound).tolist()
        raise FocalInitError(
            "Initial focal of camera(s) {cameras} ran to the limit of "
            f"[{FOCAL_BOUNDS_FACTOR[0]}, {FOCAL_BOUNDS_FACTOR[1]}] x image size: the fundamental "
            "matrices are inconsistent (wrong matches or a degenerate camera configuration). "
            "Check the overlap between cameras, or " + KNOWN_FOCALS_HINT, bad)
    median_residual = weighted_median(np.abs(problem.pair_residuals(log_f)), problem.weights)
    if median_residual > MAX_MEDIAN_RESIDUAL:
        raise FocalInitError(
            f"Initial focals do not fit the fundamental matrices (weighted median residual "
            f"{median_residual:.2f} > {MAX_MEDIAN_RESIDUAL}): most camera pairs have wrong "
            "two-view geometry. Check the matches / overlap, or "
            + KNOWN_FOCALS_HINT)
    LOG.debug("initial focals %s px (median eq.2 residual %.4f)", np.round(focal, 1),
              median_residual)
    return focal


def _usable_pairs(F: dict, weights: dict) -> tuple[list, list, list]:
    """(pairs, their F normalised to s1 = 1, their weights) for the pairs with a positive weight
    and a finite F of rank 2."""
    pairs, F_list, w_list = [], [], []
    for (i, j), F_ji in F.items():
        w = float(weights.get((i, j), 0.0))
        if F_ji is None or w <= 0:
            continue
        F_ji = np.asarray(F_ji, dtype=np.float64)
        s = np.linalg.svd(F_ji, compute_uv=False) if np.all(np.isfinite(F_ji)) else None
        if s is None or s[1] <= 1e-9 * s[0]:  # rank < 2: no essential structure to test
            continue
        pairs.append((i, j))
        F_list.append(F_ji / s[0])
        w_list.append(w)
    return pairs, F_list, w_list


class _Eq2Problem:
    """Eq. 2 over all pairs in the free cameras' log focals (module docstring), with the prior
    term, its analytic Jacobian and the smooth form the restarts run on."""

    def __init__(self, pairs: list, F_list: list, weights: np.ndarray, image_sizes: list,
                 principal_points: list, known: np.ndarray):
        self.num_cams = len(image_sizes)
        sizes = np.array([max(int(w), int(h)) for w, h in image_sizes], dtype=np.float64)
        self.weights = weights
        self.lower = np.log(FOCAL_BOUNDS_FACTOR[0] * sizes)
        self.upper = np.log(FOCAL_BOUNDS_FACTOR[1] * sizes)
        fixed = np.isfinite(known)
        # The solver moves the free cameras' log focals only; known ones stay in place. With none
        # known, `free` is a plain slice: a boolean index copies the Jacobian into another memory
        # layout, which changed the focals' last digits (0.04 %), and SfM can amplify that.
        self.free = ~fixed if fixed.any() else slice(None)
        self.log_known = np.log(np.where(fixed, known, 1.0))
        self.log_prior = np.where(fixed, self.log_known, np.log(PRIOR_FOCAL_FACTOR * sizes))
        self.F_stack = np.stack(F_list)  # (P, 3, 3)
        self.idx_i = np.array([i for i, _ in pairs])
        self.idx_j = np.array([j for _, j in pairs])
        self.pp = np.asarray(principal_points, dtype=np.float64)

    def full(self, x_free: np.ndarray) -> np.ndarray:
        log_f = self.log_known.copy()
        log_f[self.free] = x_free
        return log_f

    def K(self, log_f: np.ndarray) -> np.ndarray:
        K = np.zeros((self.num_cams, 3, 3))
        K[:, 0, 0] = K[:, 1, 1] = np.exp(log_f)
        K[:, :2, 2] = self.pp
        K[:, 2, 2] = 1.0
        return K

    def pair_residuals(self, log_f: np.ndarray) -> np.ndarray:
        K = self.K(log_f)
        E = np.einsum("pba,pbc,pcd->pad", K[self.idx_j], self.F_stack, K[self.idx_i])
        s = np.linalg.svd(E, compute_uv=False)
        return (s[:, 0] - s[:, 1]) / (s[:, 0] + s[:, 1]) + s[:, 2] / s[:, 0]

    def residuals(self, log_f: np.ndarray) -> np.ndarray:
        return np.concatenate([self.weights * self.pair_residuals(log_f),
                               PRIOR_WEIGHT * (log_f - self.log_prior)])

    def jacobian(self, log_f: np.ndarray) -> np.ndarray:
        # Analytic: ds_k = u_k^T dE v_k; dE/dlog f_i = K_j^T F D_i, dE/dlog f_j = D_j^T F K_i
        # with D = f diag(1, 1, 0) (the derivative of K in log-focal).
        idx_i, idx_j, F_stack = self.idx_i, self.idx_j, self.F_stack
        K = self.K(log_f)
        D = np.zeros_like(K)
        D[:, 0, 0] = D[:, 1, 1] = np.exp(log_f)
        FK_i = np.einsum("pbc,pcd->pbd", F_stack, K[idx_i])
        E = np.einsum("pba,pbd->pad", K[idx_j], FK_i)
        u, s, vt = np.linalg.svd(E)
        dE_i = np.einsum("pba,pbc,pcd->pad", K[idx_j], F_stack, D[idx_i])
        dE_j = np.einsum("pba,pbd->pad", D[idx_j], FK_i)
        J = np.zeros((len(idx_i) + self.num_cams, self.num_cams))
        rows = np.arange(len(idx_i))
        for dE, cam in ((dE_i, idx_i), (dE_j, idx_j)):
            ds = np.einsum("pak,pab,pkb->pk", u, dE, vt)  # (P, 3): d s_k
            s1, s2, s3 = s[:, 0], s[:, 1], s[:, 2]
            dr = ((ds[:, 0] - ds[:, 1]) * (s1 + s2) - (s1 - s2) * (ds[:, 0] + ds[:, 1])) / (
                s1 + s2) ** 2 + (ds[:, 2] * s1 - s3 * ds[:, 0]) / s1 ** 2
            np.add.at(J, (rows, cam), self.weights * dr)
        J[len(idx_i):, :] = PRIOR_WEIGHT * np.eye(self.num_cams)
        return J

    def smooth_residuals(self, log_f: np.ndarray) -> np.ndarray:
        # Same zero set, smooth: the cubic essential constraint 2 E E^T E - tr(E E^T) E = 0 on
        # E normalised to ||E||_F = 1; per pair its norm is (s1^2 - s2^2) ~ 2 * eq. 2 residual.
        K = self.K(log_f)
        E = np.einsum("pba,pbc,pcd->pad", K[self.idx_j], self.F_stack, K[self.idx_i])
        E /= np.linalg.norm(E, axis=(1, 2), keepdims=True)
        cubic = 0.5 * (2.0 * E @ np.swapaxes(E, 1, 2) @ E - E)
        return np.concatenate([(self.weights[:, None] * cubic.reshape(-1, 9)).ravel(),
                               PRIOR_WEIGHT * (log_f - self.log_prior)])

    def solve(self):
        """The least_squares result of the best restart polished on eq. 2, or None.

        Eq. 2's |s1 - s2| is a cone at its minimum, where Gauss-Newton crawls (~800 iterations
        measured); the smooth form converges in a few dozen. Restarts run on the smooth form,
        the best one (by eq. 2 cost) is then polished on eq. 2 itself."""
        free, lower, upper, num_cams = self.free, self.lower, self.upper, self.num_cams
        best, best_cost = None, np.inf
        for factor in RESTART_FACTORS:
            x0 = np.clip(self.log_prior + np.log(factor), lower + 1e-6, upper - 1e-6)[free]
            try:
                res = least_squares(lambda x: self.smooth_residuals(self.full(x)), x0,
                                    bounds=(lower[free], upper[free]), loss="cauchy",
                                    f_scale=ROBUST_SCALE / 3.0, max_nfev=100 * (num_cams + 1))
                r = self.weights * self.pair_residuals(self.full(res.x)) / ROBUST_SCALE
                cost = float(np.sum(np.log1p(r ** 2)))
            except ValueError as exc:  # non-finite residuals from a pathological F
                LOG.debug("focal restart %.1f failed: %s", factor, exc)
                continue
            if np.isfinite(cost) and cost < best_cost:
                best, best_cost = res, cost
        if best is not None:
            polished = least_squares(lambda x: self.residuals(self.full(x)), best.x,
                                     jac=lambda x: self.jacobian(self.full(x))[:, free],
                                     bounds=(lower[free], upper[free]),
                                     loss="cauchy", f_scale=ROBUST_SCALE, max_nfev=50 * num_cams)
            if np.all(np.isfinite(polished.x)):
                best = polished
        return best
