"""The image refinement's sigmas (core.method.image_refinement): the adjustment's posterior
covariance, a cluster-robust (sandwich) covariance over image regions, and the spatial folds'
spread (core.method.image_folds), each camera's sigma the largest of them.

Why a sandwich: the covariance weights every dense correspondence as an independent measurement
at the fit's pixel noise. Correspondences from patch alignment are not: neighbours share a
texture, a blur, a JPEG block and what the lens model cannot express, so their errors move
together and tens of thousands of them determine a focal length far less than independent ones
would. The sandwich H^-1 B H^-1 takes the information H from the model and the spread B of the
gradient from the data, summed per image region (the cells the folds deal out,
image_folds.track_regions) and then squared: errors shared within a region add up as they do in
the estimate, errors independent between regions average out. Where the errors are independent
its expectation is the covariance. The folds estimate the same spread from four estimates (three
degrees of freedom: simulated, their sigma averages 0.73 of the true one); a 4:3 image has about
75 regions."""
from __future__ import annotations

from typing import Optional

import numpy as np

from .prior_adjustment import AdjustmentProblem, INTRINSIC_NAMES, Priors, add_prior_terms
from .prior_covariance import block_marginals, camera_covariance
from .reconstruction import SfMState
from .uncertainty import CameraUncertainty, projection_std_px


def posterior_covariances(state: SfMState, blocks: list[int], priors: Priors, noise_px: float,
                          track_region: np.ndarray) -> tuple[dict, dict]:
    """Per block the (8, 8) covariance of INTRINSIC_NAMES at `state` as it is, under these
    priors and pixel noise: the posterior's (prior_covariance.posterior_covariance) and the
    cluster-robust one over the tracks' regions (track_region (T,): image_folds.track_regions;
    module docstring)."""
    problem = AdjustmentProblem(state, blocks, priors)
    cov, Wt, V_inv, g_pt, obs_cols, weighted = camera_covariance(problem, noise_px)
    M = problem.num_cam_params
    # Each observation's share of the camera-side gradient with its point profiled out (zero
    # per point at the solution; gated observations leave it slightly off): A^T w r - W V^-1 g.
    _, A, _ = problem.residuals_and_jacobians()
    point_pull = np.einsum("pjk,pk->pj", V_inv, g_pt)[problem.p_idx]
    score = np.einsum("nik,ni->nk", A[:, :, problem.used], weighted) \
        - np.einsum("njk,nj->nk", Wt, point_pull)
    region = np.unique(track_region[problem.t_idx], return_inverse=True)[1].ravel()
    num_regions = int(region.max()) + 1
    flat = (region[:, None] * (M + 1) + obs_cols).ravel()
    per_region = np.bincount(flat, weights=score.ravel(),
                             minlength=num_regions * (M + 1)).reshape(num_regions, M + 1)[:, :M]
    # The regions' gradients sum to zero at the solution: one region's worth of freedom is
    # spent on it (the usual G / (G - 1) of clustered sandwiches).
    meat = per_region.T @ per_region * num_regions / max(num_regions - 1, 1)
    add_prior_terms(problem, meat, np.zeros(M))  # the priors' own information, as in H
    return block_marginals(problem, cov, blocks), \
        block_marginals(problem, cov @ meat @ cov, blocks)


def camera_uncertainty(state: SfMState, block: int, covariances: tuple, fold_sigmas: dict,
                       held_pp_std_fraction: Optional[float], focal_scale_std: float = 0.0
                       ) -> CameraUncertainty:
    """Focal, principal point and projection standard deviations of a block in its COLMAP
    model: per quantity the largest that the covariances of INTRINSIC_NAMES (posterior_covariances'
    two) give, the focal's and an estimated principal point's at least the folds' (fold_sigmas:
    image_folds.determined_by_images), the focal's at least focal_scale_std (a fraction:
    focal_determination.probed_focal_scale_std) of it. held_pp_std_fraction: a held principal
    point's sigma as a fraction of the long side (its prior's: at most as far off as real lenses'
    offsets); None where estimated. The projection's is at least what the wider of the two
    covariances (in focal length and principal point) gives with those two widened to the
    sigmas reported: a projection sigma below its own principal point's would contradict it (a
    point off by sigma moves every image point by about that much)."""
    cam = state.intrinsics[block]
    f, a = cam.params[0], (cam.params[1] / cam.params[0] - 1.0 if cam.model == "OPENCV" else 0.0)
    n = len(INTRINSIC_NAMES)
    if cam.model == "OPENCV":  # fx, fy, cx, cy, k1, k2, p1, p2 from f, cx, cy, k1, k2, a, p1, p2
        J = np.zeros((8, n))
        J[0, 0] = 1.0
        J[1, 0], J[1, 5] = 1.0 + a, f
        J[2, 1] = J[3, 2] = J[4, 3] = J[5, 4] = J[6, 6] = J[7, 7] = 1.0
    else:  # RADIAL: f, cx, cy, k1, k2
        J = np.eye(5, n)
    mean_focal = np.zeros(n)
    mean_focal[0], mean_focal[5] = 1.0 + a / 2.0, f / 2.0
    focal_std = max(fold_sigmas.get("focal_px", 0.0), focal_scale_std * f * (1.0 + a / 2.0))
    pp_std = max(fold_sigmas.get("principal_point_axes_px", (0.0,)))
    projection = 0.0
    for cov in covariances:
        focal_std = max(focal_std, float(np.sqrt(max(mean_focal @ cov @ mean_focal, 0.0))))
        pp_std = max(pp_std, float(np.sqrt(max(cov[1, 1], cov[2, 2], 0.0))))
        projection = max(projection, projection_std_px(
            cam.to_pycolmap(), list(range(len(cam.params))), J @ cov @ J.T))
    if held_pp_std_fraction is not None:
        pp_std = held_pp_std_fraction * max(cam.width, cam.height)
    cov = max(covariances, key=lambda c: np.trace(c[:3, :3]))  # widened below
    scale = np.ones(n)
    scale[0] = max(1.0, focal_std / max(np.sqrt(max(mean_focal @ cov @ mean_focal, 0.0)), 1e-12))
    scale[1:3] = [max(1.0, pp_std / max(np.sqrt(max(cov[i, i], 0.0)), 1e-12)) for i in (1, 2)]
    widened = projection_std_px(cam.to_pycolmap(), list(range(len(cam.params))),
                                J @ (scale[:, None] * cov * scale[None, :]) @ J.T)
    projection = max(projection, widened or 0.0)
    return CameraUncertainty(focal_std, pp_std, projection)
