"""The image refinement's sigmas (core.method.image_refinement): the adjustment's posterior
covariance, cluster-robust (sandwich) covariances over image regions and frame sets, and the
spatial folds' spread (core.method.image_folds), each camera's sigma the largest of them, the
principal point's and the projection's with how far the lens model's choice moves them in
quadrature (decentering.lens_model_choice); each
camera's rotation sigma beside them (refinement_sigmas, core.method.rotation_spread).

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
75 regions.

A rig filmed over several frame sets has a third, clustered by frame set: correspondences of one
instant share what that instant did to them (what moved and where, how far the cameras' clocks
and rolling shutters stood apart meanwhile), which the regions, each spanning every frame set,
average away. On Caliscope's webcams it gave focal sigmas 1.3-1.8 times the regions' and close
to what leaving each frame set out in turn moves the focal lengths by (docs/design-notes.md,
Sigmas over frame sets)."""
from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Optional

import numpy as np

from .decentering import LensModelChoice, decentering_blocks, lens_model_choice, other_lens_model
from .image_folds import track_regions
from .prior_adjustment import (TWO_FOCAL_MODELS, AdjustmentProblem, INTRINSIC_NAMES, Priors,
                               add_prior_terms)
from .prior_covariance import block_marginals, camera_covariance
from .reconstruction import SfMState
from .rotation_spread import fold_rotation_std_deg, rotation_std_deg
from .uncertainty import (CameraUncertainty, in_quadrature, principal_point_spread_px,
                          projection_std_px)


# Frame sets a refinement's correspondences come from, at least, for a sandwich clustered by frame
# set (posterior_covariances): its variance then has 7 degrees of freedom, which keep its sigma
# within 0.56-1.42 of the true one at 90 %; each sigma reported is the largest of its sources, so
# a noisier one (4 clusters, the folds' 3 degrees of freedom: 0.34-1.61) would widen it by chance.
MIN_FRAME_SET_CLUSTERS = 8


@dataclass
class RefinementCovariances:
    """The posterior and the sandwich covariances (M, M) of the adjustment's camera parameters
    (posterior_covariances: over image regions, and over frame sets where there are enough),
    their columns (AdjustmentProblem.pose_cols, intr_cols) and per block their (8, 8) marginals
    of INTRINSIC_NAMES."""

    full: tuple[np.ndarray, ...]
    pose_cols: np.ndarray
    intr_cols: np.ndarray
    marginals: tuple[dict, ...]

    def of_block(self, block: int) -> tuple[np.ndarray, ...]:
        return tuple(marginals[block] for marginals in self.marginals)


def refinement_sigmas(state: SfMState, blocks: list[int], priors: tuple[Priors, Priors],
                      noise_px: float, determined: dict, fold_sigmas: dict,
                      one_cameras: list[list[int]], held_pp_std_fraction: float,
                      focal_scale_std: float) -> dict[int, CameraUncertainty]:
    """Per registered camera of the adjusted blocks its sigmas (camera_uncertainty, with the lens
    model's choice: with_lens_model_choice) with its rotation's (rotation_sigmas). priors:
    (every prior in place, those the rig was adjusted under): the covariances take the first,
    so that a held principal point may be off by its prior's spread and the focal length leans
    on it; the folds and the lens model's choice refit under the second. determined,
    fold_sigmas: image_folds.determined_by_images'; a principal point the images do not
    determine has held_point_std_px's sigma (real points' spread, principal_point_spread_px
    with held_pp_std_fraction, weighed with the folds')."""
    in_place, held = priors
    covariances = posterior_covariances(state, blocks, in_place, noise_px, track_regions(state))
    of_block = {b: camera_uncertainty(
        state, b, covariances.of_block(b), fold_sigmas.get(b, {}),
        None if "principal point" in determined[b] else held_point_std_px(
            state.intrinsics[b], fold_sigmas.get(b, {}), held_pp_std_fraction), focal_scale_std)
        for b in covariances.marginals[0]}
    lens, lens_ones = decentering_blocks(state.intrinsics, blocks, one_cameras)
    choice = lens_model_choice(state, blocks, other_lens_model(held, lens, lens_ones), noise_px) \
        if lens else LensModelChoice()  # only they have a lens model to choose
    # the rotations regress on the intrinsics' statistical sigmas: the lens model's part enters
    # them once, as their own move
    turns = rotation_sigmas(state, covariances, of_block,
                            fold_rotation_std_deg(state, blocks, held, noise_px),
                            choice.rotation_deg)
    return {c: replace(with_lens_model_choice(of_block[b], choice.intrinsics_px.get(b)),
                       rotation_std_deg=turns.get(c))
            for c in state.registered()
            if (b := int(state.camera_block[c])) in of_block}


def with_lens_model_choice(sigma: CameraUncertainty, moved: Optional[tuple]) -> CameraUncertainty:
    """sigma with the principal point and projection sigmas widened in quadrature by how far the
    other lens model moves them (moved: decentering.LensModelChoice.intrinsics_px' (principal
    point, projection) px; None: as it is). A decentering's first-order trade is with
    the principal point and the camera's yaw and pitch, which the rotation sigma takes as its own
    move; the focal sigmas fit without it, and the matcher's choice, the second matcher and the
    one-model retry read them (docs/design-notes.md, The lens model's choice in the principal
    point's sigma). A principal point the refinement held is held under both models and does
    not move."""
    if moved is None:
        return sigma
    return replace(sigma,
                   principal_point_std_px=in_quadrature(sigma.principal_point_std_px, moved[0]),
                   projection_std_px=in_quadrature(sigma.projection_std_px, moved[1]))


def posterior_covariances(state: SfMState, blocks: list[int], priors: Priors, noise_px: float,
                          track_region: np.ndarray) -> RefinementCovariances:
    """The covariance of the camera parameters at `state` as it is, under these priors and
    pixel noise: the posterior's (prior_covariance.posterior_covariance), the cluster-robust
    one over the tracks' regions (track_region (T,): image_folds.track_regions) and, where the
    tracks come from at least MIN_FRAME_SET_CLUSTERS frame sets, the one over their frame sets
    (module docstring)."""
    problem = AdjustmentProblem(state, blocks, priors)
    cov, Wt, V_inv, g_pt, obs_cols, weighted = camera_covariance(problem, noise_px)
    # Each observation's share of the camera-side gradient with its point profiled out (zero
    # per point at the solution; gated observations leave it slightly off): A^T w r - W V^-1 g.
    _, A, _ = problem.residuals_and_jacobians()
    point_pull = np.einsum("pjk,pk->pj", V_inv, g_pt)[problem.p_idx]
    score = np.einsum("nik,ni->nk", A[:, :, problem.used], weighted) \
        - np.einsum("njk,nj->nk", Wt, point_pull)
    full = [cov, cov @ _clustered_meat(problem, score, obs_cols, track_region) @ cov]
    frame_sets = state.tracks.time_index
    if len(np.unique(frame_sets[problem.t_idx])) >= MIN_FRAME_SET_CLUSTERS:
        full.append(cov @ _clustered_meat(problem, score, obs_cols, frame_sets) @ cov)
    return RefinementCovariances(tuple(full), problem.pose_cols, problem.intr_cols,
                                 tuple(block_marginals(problem, c, blocks) for c in full))


def _clustered_meat(problem: AdjustmentProblem, score: np.ndarray, obs_cols: np.ndarray,
                    track_cluster: np.ndarray) -> np.ndarray:
    """(M, M): the observations' gradients (score, per observation its camera-side columns
    obs_cols) summed per cluster of their track (track_cluster (T,)) and then squared, with the
    priors' own information added: the sandwich's B."""
    M = problem.num_cam_params
    cluster = np.unique(track_cluster[problem.t_idx], return_inverse=True)[1].ravel()
    num_clusters = int(cluster.max()) + 1
    flat = (cluster[:, None] * (M + 1) + obs_cols).ravel()
    per_cluster = np.bincount(flat, weights=score.ravel(), minlength=num_clusters * (M + 1)
                              ).reshape(num_clusters, M + 1)[:, :M]
    # The clusters' gradients sum to zero at the solution: one cluster's worth of freedom is
    # spent on it (the usual G / (G - 1) of clustered sandwiches).
    meat = per_cluster.T @ per_cluster * num_clusters / max(num_clusters - 1, 1)
    add_prior_terms(problem, meat, np.zeros(M))  # the priors' own information, as in H
    return meat


def held_point_std_px(cam, fold_sigmas: dict, prior_fraction: float) -> float:
    """The sigma (px, the larger axis) of a principal point held where the images' estimate and
    the prior weighed by their spreads put it (image_refinement._hold_principal_points: the
    folds' sigma fold_sigmas["principal_point_axes_px"] against the prior's, prior_fraction of
    the long side): per axis the root mean square of how far the truth may be from there, the
    truth spread as real cameras' points are (principal_point_spread_px) and the images'
    estimate off by the folds' sigma. Where that spread is the prior's, it is the precision-
    weighted mean's sigma: a point the folds place to 6.4 px against a prior of 12.8 px is
    held to 5.7 px, not 12.8 (the prior's spread alone, carried into each camera's rotation,
    made right rigs of a few cameras report rotation sigmas of 2 deg for errors of 0.6:
    docs/design-notes.md, Cameras placed loosely: warned); where the folds gave none, the
    spread. A video frame's short axis spreads wider than the prior holds it: the prior only
    shrinks the images' estimate toward the centre, where a wider one lets points the images
    leave open wander (docs/design-notes.md, Real cameras' principal points)."""
    prior_px = prior_fraction * max(cam.width, cam.height)
    spread_px = principal_point_spread_px(cam.width, cam.height, cam.model, prior_fraction)
    axes = np.asarray(fold_sigmas.get("principal_point_axes_px", (np.inf, np.inf)), float)
    axes = np.where(np.isfinite(axes) & (axes > 0), axes, np.inf)  # no sigma: no weight
    weight = held_point_weight(prior_px, axes)
    images_part = weight * np.where(np.isfinite(axes), axes, 0.0)
    return float(np.max(np.hypot((1.0 - weight) * np.asarray(spread_px), images_part)))


def held_point_weight(prior_px, images_std_px) -> np.ndarray:
    """Per axis the share of the images' estimate in a held principal point, against the prior's
    centre: the precision weight of the estimate (its sigma images_std_px, the folds') beside the
    prior's (prior_px); 0 where the folds gave no sigma (inf)."""
    prior_var = np.square(np.asarray(prior_px, float))
    return prior_var / (prior_var + np.square(np.asarray(images_std_px, float)))


def camera_uncertainty(state: SfMState, block: int, covariances: tuple, fold_sigmas: dict,
                       held_pp_std_px: Optional[float], focal_scale_std: float = 0.0
                       ) -> CameraUncertainty:
    """Focal, principal point and projection standard deviations of a block in its COLMAP
    model: per quantity the largest that the covariances of INTRINSIC_NAMES (posterior_covariances')
    give, the focal's and an estimated principal point's at least the folds' (fold_sigmas:
    image_folds.determined_by_images), the focal's at least focal_scale_std (a fraction:
    focal_determination.probed_focal_scale_std) of it. held_pp_std_px: a held principal
    point's sigma (held_point_std_px; at least the covariances'); None where estimated. The
    projection's is at least what the widest of the covariances (in focal length and
    principal point) gives with those two widened to the sigmas reported: a projection sigma
    below its own principal point's would contradict it (a point off by sigma moves every image
    point by about that much)."""
    cam = state.intrinsics[block]
    two = cam.model in TWO_FOCAL_MODELS
    f, a = cam.params[0], (cam.params[1] / cam.params[0] - 1.0 if two else 0.0)
    n = len(INTRINSIC_NAMES)
    if two:  # fx, fy, cx, cy, k1, k2, p1, p2 (fisheye: k3, k4) from f, cx, cy, k1, k2, a, p1, p2
        J = np.zeros((8, n))
        J[0, 0] = 1.0
        J[1, 0], J[1, 5] = 1.0 + a, f
        J[2, 1] = J[3, 2] = J[4, 3] = J[5, 4] = J[6, 6] = J[7, 7] = 1.0
    else:  # RADIAL (RADIAL_FISHEYE): f, cx, cy, k1, k2
        J = np.eye(5, n)
    mean_focal = np.zeros(n)
    mean_focal[0], mean_focal[5] = 1.0 + a / 2.0, f / 2.0
    focal_std = max(fold_sigmas.get("focal_px", 0.0), focal_scale_std * f * (1.0 + a / 2.0))
    # held: the weighted mean's, which the folds' spread already entered; else the folds'
    pp_std = held_pp_std_px if held_pp_std_px is not None else \
        max(fold_sigmas.get("principal_point_axes_px", (0.0,)))
    projection = 0.0
    for cov in covariances:
        focal_std = max(focal_std, float(np.sqrt(max(mean_focal @ cov @ mean_focal, 0.0))))
        pp_std = max(pp_std, float(np.sqrt(max(cov[1, 1], cov[2, 2], 0.0))))
        projection = max(projection, projection_std_px(
            cam.to_pycolmap(), list(range(len(cam.params))), J @ cov @ J.T))
    cov = max(covariances, key=lambda c: np.trace(c[:3, :3]))  # widened below
    scale = widening(cam, cov, focal_std, pp_std)
    widened = projection_std_px(cam.to_pycolmap(), list(range(len(cam.params))),
                                J @ (scale[:, None] * cov * scale[None, :]) @ J.T)
    projection = max(projection, widened or 0.0)
    return CameraUncertainty(focal_std, pp_std, projection)


def widening(cam, cov: np.ndarray, focal_std: float, pp_std: float) -> np.ndarray:
    """(8,) per INTRINSIC_NAMES the factor (>= 1) that takes its sigma in cov (a block's (8, 8)
    marginal) to the one reported: the mean focal's to focal_std, cx's and cy's to pp_std; 1 for
    the others."""
    p = cam.params
    a = p[1] / p[0] - 1.0 if cam.model in TWO_FOCAL_MODELS else 0.0
    mean_focal = np.zeros(len(INTRINSIC_NAMES))
    mean_focal[0], mean_focal[5] = 1.0 + a / 2.0, p[0] / 2.0
    scale = np.ones(len(INTRINSIC_NAMES))
    scale[0] = max(1.0, focal_std / max(np.sqrt(max(mean_focal @ cov @ mean_focal, 0.0)), 1e-12))
    scale[1:3] = [max(1.0, pp_std / max(np.sqrt(max(cov[i, i], 0.0)), 1e-12)) for i in (1, 2)]
    return scale


def rotation_sigmas(state: SfMState, covariances: RefinementCovariances, sigmas: dict,
                    folds: dict[int, float], model: dict[int, float]) -> dict[int, float]:
    """Per registered camera but the reference the rotation sigma (deg; rotation_spread, module
    docstring): the covariances' with each block's focal and principal point widened to its
    sigmas (sigmas: block -> CameraUncertainty), or the folds' (rotation_spread.
    fold_rotation_std_deg) where larger, with the lens model's choice
    (decentering.lens_model_choice)."""
    columns = covariances.intr_cols
    intrinsic_cols = columns[columns >= 0]
    widen = []
    for k, full in enumerate(covariances.full):
        factor = np.ones(full.shape[0])
        for b, sigma in sigmas.items():
            scale = widening(state.intrinsics[b], covariances.marginals[k][b], sigma.focal_std_px,
                             sigma.principal_point_std_px)
            free = columns[b] >= 0
            factor[columns[b][free]] = scale[free]
        widen.append(factor[intrinsic_cols])
    out = {}
    for c in state.registered():
        std = rotation_std_deg(covariances.full, covariances.pose_cols, intrinsic_cols,
                               tuple(widen), folds, model, c)
        if std is not None:
            out[c] = std
    return out
