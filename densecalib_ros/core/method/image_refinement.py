"""The last stage of a calibration: the found rig refined on dense correspondences measured in the
images (core.method.dense_matches), with Gaussian priors on the principal point and the pixel aspect
(core.method.prior_adjustment), and the intrinsics' standard deviations from that adjustment.

Order: matches find the rig (sampling, SfM, consensus, refinement on all keypoint matches); this
stage only moves it within its basin. It runs where the registered cameras are RADIAL or
OPENCV_FISHEYE (the SfM's models; given intrinsics are held), as
focal_determination.lenses_adjusted allows, and the images are at hand (run_calibration), and
leaves the rig as it was when the dense correspondences do not reach every camera. A fisheye's four
distortion terms are tied between cameras as k1 and k2 are (docs/design-notes.md, Image refinement:
fisheye lenses).

Whether the images determine a camera's principal point (and pixel aspect) is decided from the
data, per camera: the dense tracks are split into HOLDOUT_FOLDS spatial folds, each fold is
adjusted on its own without priors, and the spread of the folds' estimates gives the uncertainty
of the estimate from all the data, systematic errors included (the adjustment's own covariance
assumes independent pixel noise; neighbouring patches and what the model cannot express make it
several times too small on real photographs: docs/design-notes.md, Image refinement: folds and
the aspect prior); where several cameras share the intrinsics (one camera moved around), at
least the spread of their estimates with each view left out in turn, which the folds, sharing
every view, cannot show. A parameter whose uncertainty is below ESTIMATED_FRACTION of its
prior's spread (the images carry at least four times the prior's information) is estimated with
its prior; otherwise it is held, and reported as held, where the images' estimate and the prior
weighed by their spreads put it: the precision-weighted mean of the estimate from all the images
(spread: the folds') and the prior's centre, per axis. Held at the centre itself, a point the
images place 1.7 % of the side off moved every camera of a generated rig (focal 6 % low, pair
rotations 3 deg off) although the folds' mean lay within 1 px of the truth (docs/design-notes.md,
Image refinement: a held principal point). The prior's centre is the image centre, or in a
recalibration the point the previous calibration of the same camera estimated from its images
(pp_centres): a bump or a refocus leaves it where it was, and the fold decision, near its
threshold, can go either way between runs (measured: docs/design-notes.md, Principal point prior
in a recalibration). Where three or more cameras of one image size were adjusted, the rig is
adjusted once more with their intrinsics tied (core.method.rig_pooling). First, whether they
are one camera (one camera moved around, frames of one video): the rig is adjusted on three of the
folds and scored on the fourth (its correspondences triangulated anew, mean squared reprojection
error), once as one camera (f, k1, k2 and the principal point tied tight) and once as separate
cameras (not where their estimates of f, k1 or k2 already scatter far beyond their sigmas:
ONE_CAMERA_MAX_SCATTER); where one camera fits the held-out correspondences no worse than separate
cameras by more than the folds' standard error of that difference (cross-validation's
one-standard-error rule: the simpler model unless the data prefer the other), they are adjusted as
one (their pixel aspect tied too: `_one_aspect_tie`), and judged as one: the sigmas that decide
and report a parameter are those of the estimate from all their images, and the principal point is
estimated or held for all of them alike, under one camera's prior (`_as_one_camera`). Otherwise f,
k1 and k2 are tied as far as they agree: the cameras' estimates, with the folds' sigmas, give the
spread between the cameras, and each camera's difference from the rig's mean gets a Gaussian of
that spread. Separately self-calibrated, each camera traded its intrinsics against its pose in its
own way (docs/design-notes.md, Image refinement: the rig's own spread; one camera or several). The
pixel aspect is estimated with its prior (holding a real sensor's aspect at 1 moves the
principal points far: docs/design-notes.md, Image refinement: folds and the aspect prior), but
held square where the fit puts it beyond what any real sensor has
(plausibility.UNLIKE_ASPECT_DEVIATION: design notes, a pixel aspect no real sensor has); the
cameras are written as OPENCV (fx, fy, cx, cy, k1, k2, p1, p2), "aspect" listed as estimated where
the folds determine it; p1 = p2 = 0 but where held-out folds ask for them (core.method.decentering).
The sigmas reported: per camera the largest of the adjustment's covariance, a sandwich over image
regions and the folds' (core.method.refinement_uncertainty)."""
from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace
from typing import Callable, Optional, Sequence

import numpy as np

from ..config import lens_of_model
from ..progress import check_stop
from ..types import Tracks
from .decentering import decentering_blocks, with_decentering, with_decentering_asked
from .dense_ahead import DenseAhead
from .dense_matches import (TooFewDenseCorrespondences, dense_groups, dense_tracks,
                            thin_cameras)
from .focal_determination import (FORWARD_SPREAD_DEG, axes_spread_deg, lenses_adjusted,
                                  probed_focal_scale_std)
from .image_folds import (FOLD_VALUE_OF, GATE_SIGMAS, HOLDOUT_FOLDS, determined_by_images,
                          held_out_errors, one_camera_jackknife, principal_point_determined)
from .plausibility import make_pixels_square, unlike_aspect_blocks
from .prior_adjustment import (FISHEYE_MODELS, INTRINSIC_NAMES, SUPPORTED_MODELS,
                               PriorAdjustment, Priors, adjust_with_priors, intrinsics_vector)
from .reconstruction import (SfMState, remove_outlier_observations, reprojection_errors,
                             triangulate_tracks)
from .rig_pooling import (MIN_POOLED_CAMERAS, POOLED_INTRINSICS, one_value, pooled_intrinsics,
                          random_effects, scatter_per_dof, spread_said, spread_ties)
from .refinement_uncertainty import held_point_weight, refinement_sigmas

log = logging.getLogger(__name__)

# Real lenses put the principal point 0.5-2 % of the image side off-centre (docs/design-notes.md,
# Real cameras' principal points): a prior of 1 % of the long side per axis holds 2 % at two sigma.
PP_PRIOR_STD_FRACTION = 0.01
# Square pixels to within a few tenths of a percent (docs/design-notes.md, Real cameras'
# principal points).
ASPECT_PRIOR_STD = 0.003
GATE_ROUNDS = 3
TRIANGULATION_GATE_PX = 4.0  # the found rig fits right correspondences to well under this
# Cameras that are one camera reach it from their separate estimates in a few steps (Strecha's
# ten: 8-9, the fox's six frames 11-14); a rig of different lenses would take all 50 to fit as one
# badly. Cut short, such a fit only fits worse, which is the verdict anyway; the cap bounds what
# reaching it costs.
ONE_CAMERA_ITERATIONS = 20
# The one-camera test is not run where its verdict is certain: where the cameras' estimates of
# f, k1 or k2 scatter beyond their folds' sigmas by this much (Cochran's Q per degree of freedom,
# rig_pooling.scatter_per_dof: ~30x the sigmas), one value cannot fit them all. Four folds'
# sigmas are rough and a phone's autofocus moves its focal between frames, so frames of one
# camera scatter beyond them several times over, not thirty (docs/design-notes.md, One camera
# or several: the test's cost).
ONE_CAMERA_MAX_SCATTER = 1000.0
PRINCIPAL_POINT_INTRINSICS = (1, 2)  # cx, cy as indices into INTRINSIC_NAMES
ASPECT = 5  # the pixel aspect's index into INTRINSIC_NAMES


@dataclass
class ImageRefinement:
    """What the stage did: the state after it, the adjustment, per camera name which intrinsics
    the images determined (INTRINSIC_NAMES; a principal point not listed was held between the
    images' estimate and the prior's centre, an aspect not listed rests on its prior) and its
    CameraUncertainty."""

    state: SfMState
    adjustment: PriorAdjustment
    num_tracks: int
    estimated: dict  # camera name -> list of INTRINSIC_NAMES the images pinned down
    uncertainty: dict  # camera name -> CameraUncertainty
    # The one-camera test's verdicts (rig_ties): the cameras of each group tested -> whether
    # they fit held-out correspondences as one camera does.
    one_camera: dict = field(default_factory=dict)
    # The cameras in groups the dense points do not connect (dense_matches.dense_groups), where
    # there are two or more; else empty.
    apart: list = field(default_factory=list)


def applies(state: SfMState) -> bool:
    """Whether every registered camera is one this stage adjusts (RADIAL, OPENCV_FISHEYE: as
    lenses_adjusted says) or holds (given intrinsics of a model it projects)."""
    registered = state.registered()
    if not all(state.camera(c).model in ("RADIAL", "OPENCV_FISHEYE") or (
            state.intrinsics_fixed(c) and state.camera(c).model in SUPPORTED_MODELS)
            for c in registered):
        return False
    return lenses_adjusted([state.camera(c).model for c in registered
                            if not state.intrinsics_fixed(c)],
                           [state.cam_from_world[c][:3, :3] for c in registered])


def refine_on_images(state: SfMState, frame_sets: Sequence[Sequence[np.ndarray]],
                     seeds: Tracks, camera_names: Sequence[str],
                     masks: Optional[Sequence] = None, seed: int = 0,
                     say: Callable[[str], None] = lambda m: None,
                     pp_centres: Optional[dict] = None,
                     ahead: Optional[DenseAhead] = None,
                     px_scale: Optional[np.ndarray] = None) -> Optional[ImageRefinement]:
    """The refined state (module docstring), or None where the stage does not apply; raises
    dense_matches.TooFewDenseCorrespondences where the dense correspondences leave a registered
    camera with too few observations. `state` is not modified. seeds: correspondences (tracks
    with their frame set) the dense ones are predicted from; masks: per camera bool (H, W)
    regions to ignore, or None; pp_centres: camera name ->
    (cx, cy, width, height) px, the principal point prior's centre where not the image centre
    (used where the camera's images still have that size); ahead: the dense correspondences on
    these frame sets, seeds and masks as far as they were found ahead (DenseAhead), or None;
    px_scale: per camera, dense_matches.keypoint_px_scale (None: 1 for every camera)."""
    if not applies(state):
        return None
    try:
        return _refine(state, frame_sets, seeds, camera_names, masks, seed, say,
                       pp_centres or {}, ahead, px_scale)
    except (ValueError, np.linalg.LinAlgError) as exc:  # a degenerate problem: keep the rig
        log.warning("image refinement skipped: %s", exc)
        say("the dense refinement did not apply; the rig is kept as found")
        return None


def _refine(state, frame_sets, seeds, camera_names, masks, seed, say, pp_centres, ahead,
            px_scale=None) -> Optional[ImageRefinement]:
    tracks = ahead.tracks(state) if ahead is not None \
        else dense_tracks(frame_sets, state, seeds, masks, px_scale=px_scale)
    check_stop()
    refined = state.on_tracks(tracks)
    # the found rig's fit to right correspondences, in pixels of the images it was matched on
    gate_px = TRIANGULATION_GATE_PX * (np.ones(state.num_cameras) if px_scale is None
                                       else np.asarray(px_scale, float))
    triangulate_tracks(refined, float(gate_px.max()), seed=seed)
    remove_outlier_observations(refined, gate_px)
    thin = thin_cameras(refined, camera_names)
    if thin:
        raise TooFewDenseCorrespondences(thin)
    blocks = sorted({int(refined.camera_block[c]) for c in refined.registered()
                     if not refined.intrinsics_fixed(c)})
    centres = {}  # block -> (cx, cy): a previous estimate of the same camera, at this size
    for c in refined.registered():
        b, given = int(refined.camera_block[c]), pp_centres.get(camera_names[c])
        cam = refined.intrinsics[b]
        if given is not None and tuple(given[2:]) == (cam.width, cam.height):
            centres[b] = (float(given[0]), float(given[1]))
    priors = Priors(
        principal_point_std_px={b: PP_PRIOR_STD_FRACTION * max(refined.intrinsics[b].width,
                                                               refined.intrinsics[b].height)
                                for b in blocks},
        principal_point_centre_px={b: centres[b] for b in blocks if b in centres},
        aspect_std={b: ASPECT_PRIOR_STD for b in blocks})
    start = refined.copy()
    adjustment = adjust_and_gate(refined, blocks, priors)
    start.active &= refined.active  # the gated observations
    start.drop_weak_points()
    check_stop()
    determined, fold_sigmas = determined_by_images(start, blocks, priors)
    ties, one_cameras, judged = rig_ties(refined, blocks, fold_sigmas, priors,
                                         adjustment.noise_px, camera_names, say)
    for members in one_cameras:
        priors = _as_one_camera(refined, members, determined, fold_sigmas, priors,
                                one_camera_jackknife(start, blocks, members, ties))
    check_stop()
    lens_blocks, lens_ones = decentering_blocks(refined.intrinsics, blocks, one_cameras)
    in_place = with_decentering_asked(
        replace(priors, ties=ties), lens_blocks, lens_ones, refined.intrinsics, say,
        lambda p: held_out_errors(refined, blocks, p, adjustment.noise_px, camera_names, None)) \
        if lens_blocks else replace(priors, ties=ties)
    held = replace(in_place, principal_point_std_px={
        b: (v if "principal point" in determined[b] else None)
        for b, v in priors.principal_point_std_px.items()})
    if held != priors:
        _hold_principal_points(refined, blocks, held, priors, fold_sigmas)
        adjustment = _readjusted(refined, blocks, held, adjustment.noise_px)
    in_place, held, adjustment = _held_square(refined, blocks, (in_place, held), adjustment,
                                              determined, camera_names, say)
    say(f"refined on {int(refined.point_mask().sum())} dense image correspondences "
        f"(noise {adjustment.noise_px:.2f} px)")
    check_stop()
    scale_std = 0.0  # of the focal lengths' common scale, where the layout leaves it open
    if axes_spread_deg([refined.cam_from_world[c][:3, :3] for c in refined.registered()]) \
            < FORWARD_SPREAD_DEG:
        scale_std = probed_focal_scale_std(refined, blocks, held, adjustment.noise_px)
    per_camera = refinement_sigmas(refined, blocks, (in_place, held), adjustment.noise_px,
                                   determined, fold_sigmas, one_cameras, PP_PRIOR_STD_FRACTION,
                                   scale_std)
    estimated, sigmas = {}, {}
    for c, sigma in per_camera.items():
        b = int(refined.camera_block[c])
        estimated[camera_names[c]] = ["f", "k1", "k2"] + \
            (["cx", "cy"] if "principal point" in determined[b] else []) + \
            (["aspect"] if "aspect" in determined[b] else []) + \
            (["p1", "p2"] if b in in_place.tangential_std else []) + \
            (["k3", "k4"] if refined.intrinsics[b].model in FISHEYE_MODELS else [])
        sigmas[camera_names[c]] = sigma
    verdicts = {tuple(camera_names[c] for c in refined.registered()
                      if int(refined.camera_block[c]) in members): members in one_cameras
                for members in judged}
    groups = dense_groups(refined, camera_names)
    return ImageRefinement(refined, adjustment, tracks.num_tracks, estimated, sigmas, verdicts,
                           groups if len(groups) > 1 else [])


def _held_square(state: SfMState, blocks: list[int], priors: tuple[Priors, Priors],
                 adjustment: PriorAdjustment, determined: dict, camera_names: Sequence[str],
                 say: Callable[[str], None]) -> tuple[Priors, Priors, PriorAdjustment]:
    """Where the fit left a pixel aspect no real sensor has (plausibility.unlike_aspect_blocks):
    those blocks' pixels made square and held, the rig adjusted again under the second of
    `priors` (the in-place and the held ones) so changed, and so on while that moves another's
    beyond the bound (in place, `determined` too; said). Both priors with those aspects held,
    and the last adjustment (`adjustment` where there was none)."""
    square, unlike = [], unlike_aspect_blocks(state, blocks)
    while unlike:
        make_pixels_square(state, unlike)
        square += unlike
        priors = tuple(replace(p, aspect_std={**p.aspect_std, **dict.fromkeys(square)})
                       for p in priors)
        adjustment = _readjusted(state, blocks, priors[1], adjustment.noise_px)
        unlike = unlike_aspect_blocks(state, [b for b in blocks if b not in square])
    for b in square:
        determined[b].discard("aspect")
    if square:
        say("pixel aspect held square for " + ", ".join(
            camera_names[c] for c in state.registered() if state.camera_block[c] in square)
            + ": the images had moved it where no real sensor's is")
    return priors[0], priors[1], adjustment


def _readjusted(state: SfMState, blocks: list[int], priors: Priors, noise_px: float
                ) -> PriorAdjustment:
    """adjust_with_priors at noise_px after a prior changed, in place; then the observations it
    leaves beyond the gate (a point pushed behind a camera) are no part of the fit, nor of the
    camera's reported RMS."""
    adjustment = adjust_with_priors(state, blocks, priors, noise_px=noise_px)
    remove_outlier_observations(state, GATE_SIGMAS * adjustment.residual_scale_px)
    return adjustment


def adjust_and_gate(state: SfMState, blocks: list[int], priors: Priors) -> PriorAdjustment:
    """adjust_with_priors, then observations beyond GATE_SIGMAS dropped and adjusted again, at
    most GATE_ROUNDS times; in place."""
    adjustment = adjust_with_priors(state, blocks, priors)
    for _ in range(GATE_ROUNDS):
        gate_px = GATE_SIGMAS * adjustment.residual_scale_px
        bad = np.nan_to_num(reprojection_errors(state), nan=0.0) > gate_px
        if not bad.any():
            break
        state.active[bad] = False
        state.drop_weak_points()
        adjustment = adjust_with_priors(state, blocks, priors)
    return adjustment


def _as_one_camera(state: SfMState, members: list[int], determined: dict, fold_sigmas: dict,
                   priors: Priors, jackknife: Optional[np.ndarray]) -> Priors:
    """What `determined_by_images` says of the blocks `members`, made what it says of one camera
    where `rig_ties` adjusts them as one: its estimate rests on all their images, so each sigma
    of the folds becomes that of the members' precision-weighted mean (rig_pooling.one_value),
    and the principal point is determined, for all of them or none, by that sigma (where the tie
    holds it: every member's folds gave it one). One camera has one prior: determined, the
    members' principal point priors, which the tie makes act together, widen by
    sqrt(len(members)), as do their aspect priors (one camera, one aspect: `_one_aspect_tie`);
    held, each member starts from their precision-weighted mean (in `state`), which
    `_hold_principal_points` weighs against one prior. The sigmas are then at least the
    jackknife's over their views (image_folds.one_camera_jackknife, fold_values' order), which
    unlike a shared block's does not decide: deciding, it held the point of the fox's six frames
    where the folds place it well, and they ended 0.70 deg off instead of 0.30
    (docs/design-notes.md, Image refinement: one camera's views left out in turn). `state`,
    `determined` and `fold_sigmas` in place; returns the priors."""
    def pooled_std(stds) -> float:  # of the mean: the values do not enter it
        return one_value(np.zeros(len(stds)), stds).mean_std

    point = [[fold_sigmas[b]["principal_point_axes_px"][axis] for b in members]
             for axis in range(2)]
    point_tied = all(np.isfinite(s) and s > 0 for axis in point for s in axis)
    one = dict(focal_px=pooled_std([fold_sigmas[b]["focal_px"] for b in members]),
               intrinsics={i: pooled_std([fold_sigmas[b]["intrinsics"][i] for b in members])
                           for i in pooled_intrinsics(state.intrinsics[members[0]].model)})
    point_std = dict(priors.principal_point_std_px)
    if point_tied:
        pp = np.array([_principal_point(state.intrinsics[b]) for b in members])
        means = [one_value(pp[:, axis], point[axis]) for axis in range(2)]
        one["principal_point_axes_px"] = tuple(m.mean_std for m in means)
        estimated = principal_point_determined(one["principal_point_axes_px"],
                                               point_std[members[0]])
    if jackknife is not None:  # widens the sigmas; the folds decided (docstring)
        one["focal_px"] = max(one["focal_px"], jackknife[3])
        one["intrinsics"] = {i: max(v, jackknife[FOLD_VALUE_OF[i]])
                             for i, v in one["intrinsics"].items()}
        if point_tied:
            one["principal_point_axes_px"] = tuple(
                np.maximum(one["principal_point_axes_px"], jackknife[:2]))
    for b in members:
        fold_sigmas[b] = {**fold_sigmas[b], **one}
        if not point_tied:
            continue
        determined[b].discard("principal point")
        if estimated:
            determined[b].add("principal point")
            point_std[b] *= np.sqrt(len(members))
        else:
            _set_principal_point(state, b, [m.mean for m in means])
    aspect_std = {**priors.aspect_std, **{b: priors.aspect_std[b] * np.sqrt(len(members))
                                          for b in members if priors.aspect_std[b] is not None}}
    return replace(priors, principal_point_std_px=point_std, aspect_std=aspect_std)


def rig_ties(state: SfMState, blocks: list[int], fold_sigmas: dict, priors: Priors,
              noise_px: float, camera_names: Sequence[str], say: Callable[[str], None]
              ) -> tuple[list, list[list[int]], list[list[int]]]:
    """Priors.ties among the blocks of one image size, where at least MIN_POOLED_CAMERAS of them
    have the folds' sigmas (the estimates: `state`'s, adjusted under `priors`): as one camera
    where correspondences held out of the adjustment do not tell them apart (`_one_camera_excess`,
    module docstring; not tested where an estimate scatters beyond ONE_CAMERA_MAX_SCATTER), else
    each of POOLED_INTRINSICS as far as they agree
    (core.method.rig_pooling: the rig's own spread; from fewer than MIN_SPREAD_CAMERAS, a spread
    of 0 ties nothing: spread_ties). Also the groups of blocks tied as one, and
    the groups judged (those tied as one among them)."""
    ties, groups, one_cameras, judged = [], {}, [], []
    for b in blocks:
        sigmas = fold_sigmas.get(b, {}).get("intrinsics", {})
        if all(np.isfinite(sigmas.get(i, np.nan)) and sigmas[i] > 0 for i in POOLED_INTRINSICS):
            cam = state.intrinsics[b]
            groups.setdefault((lens_of_model(cam.model), cam.width, cam.height), []).append(b)
    for (lens, width, height), members in groups.items():
        if len(members) < MIN_POOLED_CAMERAS:
            continue
        judged.append(members)
        values = np.array([intrinsics_vector(state.intrinsics[b]) for b in members])
        same_size = [b for b in blocks if (lens_of_model(state.intrinsics[b].model),
                                           state.intrinsics[b].width,
                                           state.intrinsics[b].height) == (lens, width, height)]
        pooled = pooled_intrinsics(state.intrinsics[members[0]].model)
        stds = {i: [fold_sigmas[b]["intrinsics"][i] for b in members] for i in pooled}
        effects = {i: random_effects(values[:, i], stds[i]) for i in pooled}
        spread, untied = spread_ties(effects, same_size, len(members))
        one_ties = _one_camera_ties(state, members, fold_sigmas)
        scatter = {i: scatter_per_dof(values[:, i], stds[i]) for i in pooled}
        widest = max(scatter, key=scatter.get)
        if scatter[widest] >= ONE_CAMERA_MAX_SCATTER:
            excess = standard_error = None
            tested = (f"; their {INTRINSIC_NAMES[widest]} estimates scatter "
                      f"{np.sqrt(scatter[widest]):.0f}x their own sigmas, not one camera's")
        else:
            excess, standard_error = _one_camera_excess(state, blocks, priors, spread,
                                                        one_ties, noise_px, camera_names)
            tested = (f"; as one camera they fit held-out correspondences "
                      f"{100 * np.mean(excess):.1f} % worse" if np.isfinite(excess).all() else "")
        if excess is not None and float(np.mean(excess)) <= standard_error:
            ties += one_ties + _one_aspect_tie(state, members, fold_sigmas)
            one_cameras.append(members)
            say(f"the {len(members)} cameras of {width}x{height} fit the correspondences held "
                f"out of their adjustment as well as one camera does ({100 * np.mean(excess):+.2f}"
                f" %, folds' standard error {100 * standard_error:.2f} %): their focal length, "
                f"principal point and distortion are estimated as one")
        else:
            ties += spread
            say(f"focal length and distortion {'tied' if spread else 'left untied'} across the "
                f"{len(members)} cameras of {width}x{height}"
                f"{' as far as they agree' if spread else ''} ("
                f"{spread_said(effects, untied, state.intrinsics[members[0]].model)}{tested})")
    return ties, one_cameras, judged


def _one_camera_excess(state: SfMState, blocks: list[int], priors: Priors, spread_ties: list,
                       one_ties: list, noise_px: float, camera_names: Sequence[str]
                       ) -> tuple[np.ndarray, float]:
    """The one-camera test (module docstring): per fold, the relative excess of the held-out
    error with the cameras tied as one (one_ties) over theirs tied as far as they agree
    (spread_ties), NaN where a fold left a camera without data (which keeps them apart); and
    the folds' standard error of its mean. Both with each camera's decentering free under its
    prior (decentering.with_decentering): separate principal points absorb a decentering that
    one camera's cannot, which would decide against one lens for what the test is not about
    (entry-P10 at 1536 px: ten cameras by 0.5 % without it, one with it)."""
    priors = with_decentering(priors, decentering_blocks(state.intrinsics, blocks, [])[0], [])
    try:
        held_out = {name: held_out_errors(state, blocks, replace(priors, ties=group_ties),
                                           noise_px, camera_names, iterations)
                    for name, group_ties, iterations in (
                        ("apart", spread_ties, None), ("one", one_ties, ONE_CAMERA_ITERATIONS))}
    except (ValueError, np.linalg.LinAlgError) as exc:  # a fold left a camera without data
        log.debug("no one-camera test: %s", exc)
        held_out = {"apart": np.ones(HOLDOUT_FOLDS), "one": np.full(HOLDOUT_FOLDS, np.nan)}
    log.debug("held-out errors apart %s and as one %s px^2",
              np.round(held_out["apart"], 6).tolist(), np.round(held_out["one"], 6).tolist())
    excess = held_out["one"] / held_out["apart"] - 1.0
    return excess, float(np.std(excess, ddof=1) / np.sqrt(len(excess)))


def _one_camera_ties(state: SfMState, members: list[int], fold_sigmas: dict) -> list:
    """Priors.ties that hold f, k1, k2 and the principal point of `members` together as one lens
    would (rig_pooling.one_value); the principal point where the folds gave it a sigma (the
    adjustment leaves a held one out of its tie). What the one-camera test ties."""
    ties = []
    values = np.array([intrinsics_vector(state.intrinsics[b]) for b in members])
    stds = {i: [fold_sigmas[b]["intrinsics"][i] for b in members]
            for i in pooled_intrinsics(state.intrinsics[members[0]].model)}
    for axis, i in enumerate(PRINCIPAL_POINT_INTRINSICS):
        pp_stds = [fold_sigmas[b]["principal_point_axes_px"][axis] for b in members]
        if all(np.isfinite(pp_stds)) and min(pp_stds) > 0:
            stds[i] = pp_stds
    for i, i_stds in stds.items():
        sigma = one_value(values[:, i], i_stds).sigma
        ties.append((i, {b: sigma for b in members}))
    return ties


def _one_aspect_tie(state: SfMState, members: list[int], fold_sigmas: dict) -> list:
    """The Priors.tie (a list of none or one) that holds the pixel aspect of `members`, judged
    one camera, together as one value (rig_pooling.one_value), where the folds gave it a sigma.
    Each member's aspect left free traded its own view's focal length and principal point
    against it: entry-P10 at 3072 px put cx 5.4 px off with fy / fx 1.0000-1.0008 against the
    lab's 1.0017. The one-camera test asks without it whether the images show one lens: the
    fox's 8 phone-video frames (a rolling shutter may give each frame an apparent aspect of its
    own) fitted held-out correspondences 3.5 % worse with one aspect than with eight, and one
    lens no worse than eight."""
    stds = [fold_sigmas[b]["intrinsics"][ASPECT] for b in members]
    if not (all(np.isfinite(stds)) and min(stds) > 0):
        return []
    values = [intrinsics_vector(state.intrinsics[b])[ASPECT] for b in members]
    return [(ASPECT, dict.fromkeys(members, one_value(values, stds).sigma))]


def _hold_principal_points(state: SfMState, blocks: list[int], held: Priors, priors: Priors,
                           fold_sigmas: dict) -> None:
    """The principal point of the blocks whose prior `held` leaves out (None: held by the next
    adjustment) set, per axis, to the precision-weighted mean of its estimate from all the
    images (in `state`, adjusted with `priors`; its sigma the folds', fold_sigmas) and the
    prior's centre (its sigma the prior's); at the centre where the folds gave no sigma. In
    place."""
    for b in blocks:
        if held.principal_point_std_px.get(b) is not None:
            continue
        cam = state.intrinsics[b]
        centre = np.array(priors.principal_point_centre_px.get(
            b, (cam.width / 2.0, cam.height / 2.0)), float)
        images_std = np.array(fold_sigmas.get(b, {}).get("principal_point_axes_px",
                                                          (np.inf, np.inf)), float)
        weight = held_point_weight(priors.principal_point_std_px[b], images_std)
        _set_principal_point(state, b, centre + weight * (_principal_point(cam) - centre))


def _principal_point(cam) -> np.ndarray:
    """(cx, cy) px of a camera of SUPPORTED_MODELS."""
    return intrinsics_vector(cam)[list(PRINCIPAL_POINT_INTRINSICS)]


def _set_principal_point(state: SfMState, block: int, xy_px) -> None:
    """Block's principal point set to xy_px (cx, cy), where its model keeps it; in place."""
    cam = state.intrinsics[block]
    p = np.array(cam.params, float)
    p[list(cam.to_pycolmap().principal_point_idxs())] = xy_px
    state.intrinsics[block] = type(cam)(cam.model, cam.width, cam.height, p)
