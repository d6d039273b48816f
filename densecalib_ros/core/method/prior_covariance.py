"""The posterior covariance of the prior adjustment (core.method.prior_adjustment) at a
solution: the reduced camera system with the points marginalised, inverted with the gauge held
(camera_covariance), and each block's marginal of INTRINSIC_NAMES (posterior_covariance).
core.method.refinement_uncertainty builds the image refinement's sigmas on it."""
from __future__ import annotations

import logging

import numpy as np

from .prior_adjustment import (_NI, AdjustmentProblem, Priors, cauchy_weights, normal_equations,
                               reduced_system)
from .reconstruction import SfMState

log = logging.getLogger(__name__)

# A point whose 3x3 information is conditioned beyond this has no part in the covariance: double
# precision knows its weakest curvature to no better than eps * 1e12 (2e-4 of it), and its share
# of the reduced system nearly cancels its observations' own camera information, so that error
# lands on the cameras' (a point at a camera's centre gave diagonals of -1e13 beside 1e24). Such
# points (at a camera's centre, on parallel rays) fix no depth; leaving them out only widens it.
UNRELIABLE_POINT_CONDITION = 1e12


def posterior_covariance(state: SfMState, blocks: list[int], priors: Priors,
                         noise_px: float) -> dict:
    """Per block the posterior covariance of INTRINSIC_NAMES at `state` as it is (no adjustment)
    under these priors and pixel noise: where a parameter was held at its prior's centre, the
    covariance with it free under that prior says how far off it may be, and what the others
    inherit from it."""
    problem = AdjustmentProblem(state, blocks, priors)
    return _intrinsics_covariance(problem, noise_px, blocks)


def _intrinsics_covariance(problem: AdjustmentProblem, noise_px: float, blocks: list[int]) -> dict:
    """Per block the posterior covariance of INTRINSIC_NAMES (zeros where held): the inverse of
    the reduced camera system at the solution (the points marginalised) with the gauge's free
    direction (_scale_direction) fixed by holding the translation coordinate it moves most; the
    intrinsics' marginal does not depend on which. The points' blocks are pseudo-inverted, not
    ridged as in the solve (damped_point_inverses): the ridge resists the scale about as much as a
    3-camera rig's weakest directions, and the held coordinate's choice then moved their sigmas
    by up to 8 %. The system is inverted scaled to a unit diagonal: its curvatures span ~13
    orders of magnitude (per radian of rotation against per pixel of a weakly held principal
    point), and a pseudo-inverse's relative cut-off on the raw system gave the directions a few
    cameras leave weak no variance at all (docs/design-notes.md, Intrinsics' standard
    deviations: the gauge held, not cut off)."""
    return block_marginals(problem, camera_covariance(problem, noise_px)[0], blocks)


def camera_covariance(problem: AdjustmentProblem, noise_px: float):
    """(M, M) the covariance of the camera parameters (_intrinsics_covariance), and the normal
    equations' Wt, V^-1, g_pt, observations' columns and weighted residuals (N, 2; the loss's
    weight times the residual) it came from; the points numerically_reliable leaves out have
    no part in either."""
    U, Wt, V, g_cam, g_pt, obs_cols, res = normal_equations(problem, noise_px)
    reliable = numerically_reliable(V)
    point_weight = None
    if not reliable.all():
        log.debug("covariance: %d of %d points left out (their information conditioned beyond "
                  "%.0e)", int((~reliable).sum()), len(reliable), UNRELIABLE_POINT_CONDITION)
        point_weight = reliable.astype(float)
        U, Wt, V, g_cam, g_pt, obs_cols, res = normal_equations(problem, noise_px, point_weight)
    V_inv = np.linalg.pinv(V, hermitian=True)  # a point its rays do not fix moves by nothing
    S, _ = reduced_system(problem, U, Wt, V_inv, g_cam, g_pt)
    weight = cauchy_weights(res, noise_px)
    if point_weight is not None:
        weight = weight * point_weight[problem.p_idx]
    return gauge_held_inverse(problem, S), Wt, V_inv, g_pt, obs_cols, weight[:, None] * res


def numerically_reliable(V: np.ndarray) -> np.ndarray:
    """(P,) bool: the points whose information V (P, 3, 3) is conditioned within
    UNRELIABLE_POINT_CONDITION (its smallest eigenvalue above the largest's share)."""
    eig = np.linalg.eigvalsh(V)
    return eig[:, 0] > eig[:, 2] / UNRELIABLE_POINT_CONDITION


def gauge_held_inverse(problem: AdjustmentProblem, S: np.ndarray) -> np.ndarray:
    """(M, M) the inverse of the reduced camera system S with the gauge's translation
    coordinate held (its row and column zero), as _intrinsics_covariance describes."""
    d = 1.0 / np.sqrt(np.maximum(np.diag(S), np.finfo(float).tiny))
    keep = np.ones(len(S), bool)
    gauge = np.abs(_scale_direction(problem)) / d  # in the unit-diagonal system's coordinates
    if gauge.any():
        keep[np.argmax(gauge)] = False
    d_kept = d[keep]
    w, Q = np.linalg.eigh(S[np.ix_(keep, keep)] * d_kept[:, None] * d_kept[None, :])
    # A direction the images leave open (below numerical rank, numpy's matrix_rank tolerance)
    # gets the largest variance double precision can state, not an infinite one.
    w = np.maximum(w, w[-1] * len(w) * np.finfo(float).eps)
    cov = np.zeros_like(S)
    cov[np.ix_(keep, keep)] = (Q / w) @ Q.T * d_kept[:, None] * d_kept[None, :]
    return cov


def block_marginals(problem: AdjustmentProblem, cov: np.ndarray, blocks: list[int]) -> dict:
    """Per block the (8, 8) marginal of INTRINSIC_NAMES in cov (M, M) (zeros where held)."""
    out = {}
    for b in blocks:
        cols = problem.intr_cols[b]
        block = np.zeros((_NI, _NI))
        free = np.flatnonzero(cols >= 0)
        block[np.ix_(free, free)] = cov[np.ix_(cols[free], cols[free])]
        out[b] = block
    return out


def _scale_direction(problem: AdjustmentProblem) -> np.ndarray:
    """The gauge left free (the reference camera's pose is held): the whole scene scaled about
    the reference camera's centre C, which moves each other camera's translation by R C + t
    (that camera's t is additive, AdjustmentProblem.apply) and each point by X - C, reprojecting every
    point as before; in the camera columns (the points are marginalised). Free in the
    covariance's system, whose points' blocks are pseudo-inverted; the solve's ridge
    (damped_point_inverses) resists it a little."""
    out = np.zeros(problem.num_cam_params)
    ref = problem.reference
    centre = -problem.R[ref].T @ problem.t[ref]
    for c in range(len(problem.R)):
        cols = problem.pose_cols[c]
        if cols[0] >= 0:
            out[cols[3:]] = problem.R[c] @ centre + problem.t[c]
    return out
