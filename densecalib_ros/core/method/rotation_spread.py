"""Each camera's rotation sigma in the image refinement (core.method.image_refinement): how far
its orientation relative to the reference camera (the rig frame) may be off, in degrees.

The statistical part is the larger of two estimates, as for the intrinsics
(core.method.refinement_uncertainty):
- the adjustment's covariance (posterior, or sandwich over image regions or frame sets) of the
  camera's rotation with the reference camera's held, widened by what its regression on the
  intrinsics carries once their variance is widened to the sigmas reported: a principal point
  off by a pixel turns its camera by about a pixel's angle, and the covariance, resting on the same
  correlated correspondences, holds the principal point and the focal far tighter than the folds
  and the views left out show (refinement_uncertainty, module docstring);
- the spatial folds' spread of the rotation, each fold adjusted on its own under the final
  priors and ties: errors the correspondences of one part of the images share. Not the folds
  of image_folds.determined_by_images: adjusted without priors, each camera's principal point
  free, they turn the cameras several times further than the final model lets them.

Added in quadrature, the lens model's part: how far the rotations move when the rig is adjusted
under the nested lens model the decentering test did not choose (p1, p2 free or held:
decentering.lens_model_choice). What a lens model cannot express does not stay in the residuals:
the principal point and the cameras' yaw and pitch take it up, alike in every fold and every
resample of the same correspondences, so neither estimate above can see it; the two models put
it in different places, and how far apart they put the cameras is the size of that error
(docs/design-notes.md, Rotation sigmas).

Per camera the sigma is sqrt(trace) of its rotation's 3x3 covariance: the root mean square of
the rotation error's angle, which is what the bench's per-pair rotation error measures against
the reference camera."""
from __future__ import annotations

import logging
from typing import Optional

import cv2
import numpy as np

from ..parallel import map_threads
from .image_folds import HOLDOUT_FOLDS, folds_std_of_mean, track_folds
from .prior_adjustment import Priors, adjust_with_priors
from .reconstruction import SfMState

log = logging.getLogger(__name__)


def relative_rotvecs(state: SfMState, about: SfMState) -> dict[int, np.ndarray]:
    """Per camera registered in both (the reference camera, `about`'s first registered, left
    out): the rotation vector (rad, 3) that takes its rotation relative to the reference camera
    in `about` to that in `state`. Empty where `state` lost the reference camera."""
    registered = about.registered()
    ref = registered[0]
    if state.cam_from_world[ref] is None:
        return {}

    def relative(s: SfMState, c: int) -> np.ndarray:
        return s.cam_from_world[c][:3, :3] @ s.cam_from_world[ref][:3, :3].T
    out = {}
    for c in registered[1:]:
        if state.cam_from_world[c] is not None:
            turn = relative(state, c) @ relative(about, c).T
            out[c] = cv2.Rodrigues(np.asarray(turn, float))[0].ravel()
    return out


def _folds_std(replicates: list[dict[int, np.ndarray]]) -> dict[int, float]:
    """Per camera the standard deviation (rad) of the mean of the folds' rotations: per axis
    as for the intrinsics (image_folds.folds_std_of_mean), summed in quadrature."""
    out = {}
    for c in {c for r in replicates for c in r}:
        v = np.array([r[c] for r in replicates if c in r])
        if len(v) >= 2:
            out[c] = float(np.linalg.norm(folds_std_of_mean(v)))
    return out


def covariance_rotation_std_deg(cov: np.ndarray, rotation_cols: np.ndarray,
                                intrinsic_cols: np.ndarray, widen: np.ndarray) -> float:
    """sqrt(trace) in degrees of a rotation's covariance in cov (M, M) (its columns
    rotation_cols (3,), in rad), with the variance of the intrinsics (their columns
    intrinsic_cols) widened by the factors `widen` (per column, >= 1: the sigma reported over the
    covariance's own): the rotation's regression on them, B = S_ri S_ii^+, carries
    B (W S_ii W - S_ii) B^T more."""
    r, i = np.asarray(rotation_cols), np.asarray(intrinsic_cols)
    S_rr = cov[np.ix_(r, r)]
    if len(i):
        S_ii, S_ri = cov[np.ix_(i, i)], cov[np.ix_(r, i)]
        B = S_ri @ np.linalg.pinv(S_ii, hermitian=True)
        widened = widen[:, None] * S_ii * widen[None, :]
        S_rr = S_rr + B @ (widened - S_ii) @ B.T
    return float(np.degrees(np.sqrt(max(np.trace(S_rr), 0.0))))


def rotation_std_deg(covariances: tuple, pose_cols: np.ndarray, intrinsic_cols: np.ndarray,
                     widen: tuple, folds: dict[int, float], model: dict[int, float], camera: int
                     ) -> Optional[float]:
    """The rotation sigma (deg) of `camera` (module docstring): the largest of
    covariance_rotation_std_deg over `covariances` (each with its own widening factors in
    `widen`) and the folds' (fold_rotation_std_deg), and the lens model's choice
    (decentering.lens_model_choice's rotation_deg) in quadrature. None for the reference camera
    (its rotation defines the rig frame)."""
    if pose_cols[camera][0] < 0:
        return None
    std = [covariance_rotation_std_deg(cov, pose_cols[camera][:3], intrinsic_cols, w)
           for cov, w in zip(covariances, widen)]
    statistical = max(std + [folds.get(camera, 0.0)])
    log.debug("camera %d: rotation sigma (deg) of the covariances, widened %s, of the folds "
              "%.4f, of the lens model's choice %.4f", camera, np.round(std, 4).tolist(),
              folds.get(camera, 0.0), model.get(camera, 0.0))
    return float(np.hypot(statistical, model.get(camera, 0.0)))


def fold_rotation_std_deg(state: SfMState, blocks: list[int], priors: Priors, noise_px: float
                          ) -> dict[int, float]:
    """Per camera but the reference the folds' standard deviation (deg) of the mean of its
    rotation: each spatial fold of `state` (image_folds.track_folds) adjusted on its own under
    the final `priors` at noise_px (_folds_std)."""
    fold = track_folds(state)

    def one(k: int) -> Optional[dict[int, np.ndarray]]:
        part = state.copy()
        part.active[fold != k] = False
        part.drop_weak_points()
        try:
            adjust_with_priors(part, blocks, priors, noise_px=noise_px)
        except (ValueError, np.linalg.LinAlgError):
            return None
        return relative_rotvecs(part, state)
    replicates = [r for r in map_threads(one, range(HOLDOUT_FOLDS)) if r is not None]
    return {c: float(np.degrees(s)) for c, s in _folds_std(replicates).items()}
