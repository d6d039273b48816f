"""The rig's own spread of intrinsics: each camera's estimate borrows strength from the others'
(empirical Bayes, a random-effects model).

Why: ten separately self-calibrated cameras each trade their focal length and distortion (and
principal point) against their pose on what their images cannot tell apart, and each trades
differently, so their relative rotations inherit independent errors. Rigs are mostly built from
one camera model (often one camera moved around), whose cameras differ by far less than real
lenses in general do; where they differ, their images say so. So per intrinsic the cameras'
estimates y_i, each with its standard deviation s_i, are taken as draws around a rig mean with
a spread tau between cameras: tau estimated from how much the estimates scatter beyond their own
s_i (DerSimonian-Laird, the standard moment estimator of meta-analysis). The adjustment then ties
the cameras (prior_adjustment.Priors.ties): a Gaussian of sigma tau on each camera's difference
from the rig's weighted mean, the mean itself left free, so that the tie moves the cameras
towards one another but not the rig's level (its common focal scale stays what the images say).
A rig of one model is pulled together as far as its cameras agree; a rig of different lenses
(tau much larger than the s_i) keeps its cameras' own estimates."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ..config import lens_of_model
from .prior_adjustment import INTRINSIC_NAMES

# Intrinsics tied, as indices into prior_adjustment.INTRINSIC_NAMES: f, k1, k2. Not the principal
# point: where the images leave it open, the rig's mean of such points is as open, and tied to it
# the long-lens rigs' points moved further off (docs/design-notes.md, Image refinement: the rig's
# own spread); it keeps its own prior and hold (core.method.image_refinement).
POOLED_INTRINSICS = (0, 3, 4)
# A fisheye's k3, k4 (in p1's and p2's places: prior_adjustment.FISHEYE_MODELS) are its
# distortion as its k1, k2 are, and tied with them.
FISHEYE_POOLED_INTRINSICS = POOLED_INTRINSICS + (6, 7)


def pooled_name(i: int, model: str) -> str:
    """The name of intrinsic i (INTRINSIC_NAMES) of a camera of this model: a fisheye's k3, k4."""
    if lens_of_model(model) == "fisheye" and i in FISHEYE_POOLED_INTRINSICS[-2:]:
        return f"k{i - 3}"
    return INTRINSIC_NAMES[i]


def pooled_intrinsics(model: str) -> tuple[int, ...]:
    """The intrinsics tied across cameras of this COLMAP model (indices into INTRINSIC_NAMES)."""
    return FISHEYE_POOLED_INTRINSICS if lens_of_model(model) == "fisheye" else POOLED_INTRINSICS


# The spread between cameras rests on the scatter of their estimates: with two cameras on one
# difference, too little to tell one model from two.
MIN_POOLED_CAMERAS = 3
# Below this many cameras a spread estimated at 0 ties nothing: from 2-3 differences the moment
# estimate (random_effects) comes out 0 about a third of the time for cameras whose values differ
# by their own sigmas (four cameras: Cochran's Q is then twice a chi-square of 3 degrees of
# freedom, below its 3 with probability 0.32), and would share one value between different
# lenses. Whether they are one camera is the one-camera test's to say.
MIN_SPREAD_CAMERAS = 5
# A spread of 0 says the estimates scatter no more than their own errors explain: the cameras are
# one model and share the value. Their tie's sigma is then this fraction of the rig mean's
# standard error: tight enough to hold them together as one shared parameter would, not zero,
# which the normal equations could not take.
SHARED_FRACTION = 0.01


@dataclass
class RandomEffects:
    """One intrinsic across the rig: the rig mean, the spread between cameras (tau), the standard
    error of the mean, and the sigma of a camera's tie to the others."""

    mean: float
    spread: float
    mean_std: float

    @property
    def sigma(self) -> float:
        return max(self.spread, SHARED_FRACTION * self.mean_std)


def _cochran_q(values: Sequence[float], stds: Sequence[float]) -> tuple[float, np.ndarray]:
    """(Cochran's Q: the estimates' squared deviations from their precision-weighted mean, each
    over its own variance; the weights 1 / std^2). Q is about len(values) - 1 where the
    estimates are one value."""
    y, w = np.asarray(values, float), 1.0 / np.asarray(stds, float) ** 2
    fixed_mean = float(np.sum(w * y) / np.sum(w))
    return float(np.sum(w * (y - fixed_mean) ** 2)), w


def scatter_per_dof(values: Sequence[float], stds: Sequence[float]) -> float:
    """How far the estimates scatter beyond what their standard deviations allow: Cochran's Q per
    degree of freedom (about 1 for one value; 100 for a scatter ten times their sigmas)."""
    return _cochran_q(values, stds)[0] / (len(values) - 1)


def random_effects(values: Sequence[float], stds: Sequence[float]) -> RandomEffects:
    """DerSimonian-Laird estimate (module docstring) from per-camera estimates and their
    standard deviations (finite, positive)."""
    y, s2 = np.asarray(values, float), np.asarray(stds, float) ** 2
    q, w = _cochran_q(y, stds)  # w = 1 / s2
    tau2 = max(0.0, (q - (len(y) - 1)) / (np.sum(w) - np.sum(w * w) / np.sum(w)))
    w_random = 1.0 / (s2 + tau2)
    return RandomEffects(float(np.sum(w_random * y) / np.sum(w_random)), float(np.sqrt(tau2)),
                         float(np.sqrt(1.0 / np.sum(w_random))))


def one_value(values: Sequence[float], stds: Sequence[float]) -> RandomEffects:
    """The cameras taken as one (spread 0): the precision-weighted mean of their estimates, its
    standard error, and the tie SHARED_FRACTION of that (what a shared parameter would do)."""
    y, w = np.asarray(values, float), np.asarray(stds, float) ** -2.0
    return RandomEffects(float(np.sum(w * y) / np.sum(w)), 0.0, float(np.sqrt(1.0 / np.sum(w))))


def spread_ties(effects: dict, blocks: Sequence[int], num_estimates: int
                ) -> tuple[list, list[int]]:
    """(Priors.ties of each intrinsic in `effects` (index -> RandomEffects, from num_estimates
    cameras) across `blocks` at its sigma, the intrinsics left untied): below
    MIN_SPREAD_CAMERAS estimates, those whose spread came out 0."""
    untied = [i for i, e in effects.items()
              if num_estimates < MIN_SPREAD_CAMERAS and e.spread <= 0.0]
    return [(i, {b: e.sigma for b in blocks}) for i, e in effects.items()
            if i not in untied], untied


def spread_said(effects: dict, untied: Sequence[int], model: str) -> str:
    """The spreads of f, k1 and k2 (effects: index -> RandomEffects) and the intrinsics left
    untied (spread_ties), said."""
    said = (f"spread between them: focal {effects[0].spread:.1f} px, k1 {effects[3].spread:.4f}, "
            f"k2 {effects[4].spread:.4f}")
    if untied:
        said += (f"; {', '.join(pooled_name(i, model) for i in untied)} left untied: a spread "
                 "of 0 from so few cameras is as likely lenses that differ")
    return said
