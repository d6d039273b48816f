"""Whether the image refinement frees the lenses' decentering (tangential) distortion p1, p2.

A decentering the model lacks is not left in the residuals: the principal point and the camera's
yaw and pitch trade off against it, so the folds agree on a principal point that is off and the
sigmas cannot show it (docs/design-notes.md, Image refinement: a decentering the images carry).
Freed everywhere, p1 and p2 trade off against the principal point where the images carry none,
and the point moves off instead. So they are freed only where the correspondences held out of the
adjustment (image_refinement.held_out_errors, its spatial folds) fit better with them than
without by more than chance (the folds' mean relative excess below -T_95_3DOF standard errors)
and by more than fitting correlated noise gains (MIN_HELD_OUT_GAIN).
Cameras adjusted as one camera (one lens) get one decentering, tied across them; where separate
cameras of one image size do not ask for one each, one shared by them is tested as well.

Whichever model is chosen, the other one says how much the choice matters (lens_model_choice):
the two nested models put what the lens does beyond them in different places, the principal
points and the cameras' yaw and pitch, alike in every fold and every resample of the same
correspondences; how far apart they put them is the size of that error, which the sigmas add in
quadrature (core.method.refinement_uncertainty, core.method.rotation_spread)."""
from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace
from typing import Callable, Optional, Sequence

import numpy as np

from ..metrics import principal_point_px, projection_map_error
from .prior_adjustment import INTRINSIC_NAMES, Priors, adjust_with_priors, perspective_blocks
from .reconstruction import SfMState
from .rig_pooling import MIN_POOLED_CAMERAS
from .rotation_spread import relative_rotvecs

# Prior sigma of p1 and p2 (normalised image coordinates): real lenses' decentering coefficients,
# where target-based calibrations give them, are within about 1e-3.
TANGENTIAL_PRIOR_STD = 1e-3
# One-sided 95 % point of Student's t with 3 degrees of freedom: the four folds' mean excess over
# its standard error must pass it (four folds' standard error is itself rough).
T_95_3DOF = 2.353
# Its 97.5 % point, for the shared decentering tested where each camera's own was not asked for
# (decentering_test's one_size): a second look at the same folds, held stricter, so that the two
# together call a decentering falsely at most about 7.5 % of the time (5 + 2.5).
T_975_3DOF = 3.182
# And the held-out error must fall by at least this fraction: two free parameters per camera gain
# a few tenths of a percent from what the folds share (neighbouring patches' correlated errors)
# where the images carry no decentering (docs/design-notes.md, same section).
MIN_HELD_OUT_GAIN = 0.005
# Cameras adjusted as one: their p1, p2 tied to a hundredth of the prior's spread (one lens).
ONE_LENS_TIE_FRACTION = 0.01
_TANGENTIAL = (INTRINSIC_NAMES.index("p1"), INTRINSIC_NAMES.index("p2"))

log = logging.getLogger(__name__)


def decentering_blocks(intrinsics: Sequence, blocks: Sequence[int],
                       one_cameras: Sequence[list[int]]) -> tuple[list[int], list[list[int]]]:
    """The blocks of `blocks` whose lens model has a decentering (prior_adjustment.
    perspective_blocks; intrinsics: per block), and the groups of one_cameras made of them."""
    lens = perspective_blocks(intrinsics, blocks)
    return lens, [m for m in one_cameras if set(m) <= set(lens)]


def with_decentering(priors: Priors, blocks: Sequence[int], one_cameras: Sequence[list[int]]
                     ) -> Priors:
    """`priors` with p1, p2 free under TANGENTIAL_PRIOR_STD in `blocks`, tied across each group
    of one_cameras."""
    tight = ONE_LENS_TIE_FRACTION * TANGENTIAL_PRIOR_STD
    ties = [(i, {b: tight for b in members}) for members in one_cameras if len(members) > 1
            for i in _TANGENTIAL]
    return replace(priors, tangential_std={b: TANGENTIAL_PRIOR_STD for b in blocks},
                   ties=list(priors.ties) + ties)


def other_lens_model(priors: Priors, blocks: Sequence[int], one_cameras: Sequence[list[int]]
                     ) -> Priors:
    """The nested lens model decentering_test did not choose: `priors` without p1, p2 (and
    their ties) where they are free, with them (with_decentering) where they are held."""
    if priors.tangential_std:
        return replace(priors, tangential_std={},
                       ties=[t for t in priors.ties if t[0] not in _TANGENTIAL])
    return with_decentering(priors, blocks, one_cameras)


@dataclass
class LensModelChoice:
    """How far the answer moves when the rig is adjusted under the nested lens model the
    decentering test did not choose (lens_model_choice): per camera but the reference its
    rotation relative to the reference camera (deg), per block its principal point (the larger
    axis) and projection map (the mean over the image), in px."""

    rotation_deg: dict = field(default_factory=dict)  # camera -> deg
    intrinsics_px: dict = field(default_factory=dict)  # block -> (principal point, map)


def lens_model_choice(state: SfMState, blocks: list[int], other: Priors, noise_px: float
                      ) -> LensModelChoice:
    """The LensModelChoice of `state` (adjusted under the chosen lens model) against a copy
    adjusted under the `other` one (other_lens_model); empty where that adjustment fails."""
    part = state.copy()
    for b in blocks:
        if not other.tangential_std.get(b) and part.intrinsics[b].model == "OPENCV":
            part.intrinsics[b].params[6:8] = 0.0  # held where the other model has none
    try:
        adjust_with_priors(part, blocks, other, noise_px=noise_px)
    except (ValueError, np.linalg.LinAlgError):
        return LensModelChoice()
    rotation = {c: float(np.degrees(np.linalg.norm(v)))
                for c, v in relative_rotvecs(part, state).items()}
    intrinsics = {}
    for b in blocks:
        chosen, moved = state.intrinsics[b], part.intrinsics[b]
        projection = projection_map_error(chosen, moved)["mean_px"]
        point = np.abs(principal_point_px(moved) - principal_point_px(chosen)).max()
        intrinsics[b] = (float(point), projection if np.isfinite(projection) else 0.0)
    return LensModelChoice(rotation, intrinsics)


def decentering_test(priors: Priors, blocks: Sequence[int], one_cameras: Sequence[list[int]],
                     held_out: Callable[[Priors], np.ndarray],
                     one_size: Sequence[list[int]] = ()
                     ) -> tuple[Priors, float, float, bool]:
    """(`priors`, with decentering free where the held-out folds ask for it (module
    docstring); the folds' mean relative excess of the held-out error with it free over without;
    its standard error; whether it is one decentering shared by the cameras of one size).
    held_out(priors): per fold the held-out mean squared error under those priors; where it
    fails (a fold left a camera without data) decentering stays held.

    one_size: groups of separate cameras of one image size. Where a decentering of each camera's
    own is not asked for, one shared by each group is tested next, at T_975_3DOF (two parameters,
    not two a camera: views of one lens judged separate cameras by a fraction of a percent,
    entry-P10 at 1536 px)."""
    try:
        without = held_out(priors)
        decided = _tested(priors, with_decentering(priors, blocks, one_cameras), without,
                          held_out, T_95_3DOF)
        if not decided[0].tangential_std and one_size:
            shared = with_decentering(priors, blocks, list(one_cameras) + list(one_size))
            tested = _tested(priors, shared, without, held_out, T_975_3DOF)
            if tested[0].tangential_std:
                return (*tested, True)
    except (ValueError, np.linalg.LinAlgError):
        return priors, float("nan"), float("nan"), False
    return (*decided, False)


def with_decentering_asked(priors: Priors, blocks: Sequence[int],
                           one_cameras: Sequence[list[int]], intrinsics: Sequence,
                           say: Callable[[str], None],
                           held_out: Callable[[Priors], np.ndarray]) -> Priors:
    """decentering_test's priors for the image refinement's blocks (intrinsics: per block), the
    separate cameras of one size tested for a shared decentering as well (one_size_groups); said
    where the decentering is freed."""
    freed, excess, standard_error, shared = decentering_test(
        priors, blocks, one_cameras, held_out, one_size_groups(intrinsics, blocks, one_cameras))
    if freed.tangential_std:
        say(f"decentering distortion (p1, p2) estimated{', one per image size' * shared}: "
            f"correspondences held out of the adjustment fit {-100 * excess:.2f} % better with "
            f"it (folds' standard error {100 * standard_error:.2f} %)")
    return freed


def _tested(priors: Priors, free: Priors, without: np.ndarray,
            held_out: Callable[[Priors], np.ndarray], t_point: float
            ) -> tuple[Priors, float, float]:
    """(free where the folds' held-out error under it falls below `without` by more than
    t_point standard errors and MIN_HELD_OUT_GAIN, else priors; the mean relative excess; its
    standard error)."""
    excess = held_out(free) / without - 1.0
    if not np.isfinite(excess).all():
        return priors, float("nan"), float("nan")
    mean = float(np.mean(excess))
    standard_error = float(np.std(excess, ddof=1) / np.sqrt(len(excess)))
    asked = mean < -max(t_point * standard_error, MIN_HELD_OUT_GAIN)
    if not asked:  # where it is, the image refinement says so
        log.debug("decentering held: held-out error %+.2f %% with it free (folds' standard "
                  "error %.2f %%)", 100 * mean, 100 * standard_error)
    return (free if asked else priors), mean, standard_error


def one_size_groups(intrinsics: Sequence, blocks: Sequence[int],
                    one_cameras: Sequence[list[int]]) -> list[list[int]]:
    """The blocks not adjusted as one camera, grouped by image size, in groups of at least
    MIN_POOLED_CAMERAS (as the rig pools them); intrinsics: per block."""
    tied = {b for members in one_cameras for b in members}
    groups: dict = {}
    for b in blocks:
        if b not in tied:
            groups.setdefault((intrinsics[b].width, intrinsics[b].height), []).append(b)
    return [members for members in groups.values() if len(members) >= MIN_POOLED_CAMERAS]
