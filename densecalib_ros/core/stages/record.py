"""The quality record and the warnings of a calibration, each made once from the finished rig and
the stages' outcomes: `assemble` when a matcher's calibration is finished (what the second
matcher's policy compares), `finish` once the calibration is kept (the run's inputs, the second
matcher, the warnings, the scene's colours)."""
from __future__ import annotations

import logging
from typing import Optional, Sequence

import numpy as np

from ..calibration_result import CalibrationResult
from ..config import PipelineConfig
from ..method.dense_matches import MIN_CAMERA_OBSERVATIONS
from ..method.focal_determination import (loose_focal_warning, one_camera_hint,
                                          weak_focal_warning)
from ..method.known_intrinsics import describe as describe_known
from ..method.known_intrinsics import given_intrinsics_warnings
from ..method.plausibility import corner_fold_warning, unlike_lens_warning
from ..method.reconstruction import colour_points
from ..method.uncertainty import camera_sigmas, with_runs_spread
from ..method.view_graph import named_pair_counts
from ..progress import Progress
from ..robust.consensus import (REFUSE_DISAGREEMENT_DEG, WARN_DISAGREEMENT_DEG, asift_hint,
                                disagreement_warning, refusal_message, standing_disagreement_deg)
from ..robust.consensus_runs import ConsensusRecord
from ..robust.one_model import intrinsics_shared
from ..robust.second_matcher import Rematch, perspective_on_sift
from ..types import RigCalibration, Tracks
from .inputs import RigImages

log = logging.getLogger(__name__)


def assemble(result: CalibrationResult, config: PipelineConfig, camera_names: Sequence[str],
             match_tracks: Optional[Tracks], consensus: Optional[ConsensusRecord],
             focal_hops: Sequence[str], refinement, too_few_dense: Optional[dict] = None
             ) -> None:
    """Write result.rig's quality record (beyond the fit, which rig_from_state gave it) from the
    run that made it (result.sfm), the consensus, the focal hops and the image refinement
    (stages.refinement.RefinementRecord or None; too_few_dense: RefinedRuns.thin_cameras where
    too few dense correspondences kept it from the rig), and each camera's standard
    deviations."""
    rig, quality = result.rig, result.rig.quality
    sfm = result.sfm
    quality.update(pipeline=sfm.pipeline, preset=sfm.preset, sfm_runtime_s=sfm.sfm_runtime_s,
                   view_order=sfm.view_order, match_tracks=sfm.match_tracks,
                   moved_cameras=sfm.moved_cameras, **sfm.global_sfm)
    if consensus is not None:
        quality.update(
            consensus_runs=consensus.num_runs, consensus_failed_runs=consensus.failed_runs,
            consensus_seed=consensus.seed, consensus_settled_starts=consensus.settled_starts,
            consensus_worse_fit_runs=consensus.worse_fit_runs,
            consensus_kept_by_fit=consensus.kept_by_fit,
            consensus_disagreement_deg=consensus.disagreement_deg,
            consensus_refined_disagreement_deg=consensus.refined_disagreement_deg)
        if consensus.least_determined_pairs:
            quality.consensus_least_determined_pairs_deg = {
                f"{a}/{b}": round(deg, 1) for a, b, deg in consensus.least_determined_pairs}
    if focal_hops:
        quality.focal_hops = list(focal_hops)
    if too_few_dense:
        quality.image_refinement_too_few_dense = dict(too_few_dense)
    if refinement is not None and refinement.apart:
        quality.image_refinement_groups_apart = [list(g) for g in refinement.apart]
    if refinement is not None:
        quality.update(image_refinement_tracks=refinement.num_tracks,
                       image_refinement_noise_px=refinement.noise_px,
                       principal_point_prior_std_fraction=refinement.pp_prior_std_fraction)
        for name, cam in rig.cameras.items():
            if name in refinement.estimated and cam.quality is not None:
                cam.quality.estimated_intrinsics = refinement.estimated[name]
    if rig.failed_cameras:
        quality.unregistered_best_partner = _best_partners(rig.failed_cameras, match_tracks,
                                                           camera_names)
    sigmas, held_fraction = camera_sigmas(rig, result.reconstruction, camera_names, config,
                                          refinement.sigmas if refinement is not None else None)
    if held_fraction is not None:
        quality.held_pp_std_fraction = held_fraction
    if consensus is not None and consensus.intrinsics_spread and sigmas and \
            standing_disagreement_deg(quality) > WARN_DISAGREEMENT_DEG:
        sigmas = with_runs_spread(sigmas, consensus.intrinsics_spread)
        quality.sigmas_runs_spread = consensus.num_runs
    for name, cam in rig.cameras.items():
        if name in sigmas and cam.quality is not None:
            cam.quality.focal_std_px = sigmas[name].focal_std_px
            cam.quality.principal_point_std_px = sigmas[name].principal_point_std_px
            cam.quality.projection_std_px = sigmas[name].projection_std_px
            cam.quality.rotation_std_deg = sigmas[name].rotation_std_deg
            if sigmas[name].principal_point_held:
                cam.quality.principal_point_held = True
    if config.cameras.known_intrinsics:
        quality.given_intrinsics = describe_known(config.cameras.known_intrinsics)
    if sfm.given_intrinsics_fit:
        quality.given_intrinsics_fit = sfm.given_intrinsics_fit


def finish(result: CalibrationResult, images: RigImages, config: PipelineConfig,
           consensus: Optional[ConsensusRecord], rematch: Optional[Rematch],
           match_tracks: Optional[Tracks], runtime_s: float, progress: Progress,
           keypoints: bool = False, units_apart_deg: Optional[float] = None) -> None:
    """The kept calibration made whole: what it was made from (the matcher of `config`, the
    frame sets, the lenses, masks, info strips and EXIF focals), the second matcher's record,
    the warnings (warnings; keypoints and units_apart_deg as its) and the scene points'
    colours."""
    quality = result.rig.quality
    quality.update(matcher=config.matcher, num_frame_sets=len(images.frame_sets),
                   runtime_s=runtime_s)
    cameras = config.cameras
    if cameras.lens:
        quality.camera_lens = dict(cameras.lens)
    if cameras.masks:
        quality.masked_cameras = sorted(cameras.masks)
    if images.strips:
        quality.info_strips = {n: ", ".join(s.describe() for s in found)
                               for n, found in images.strips.items()}
    if cameras.exif_focal_px:
        quality.exif_focal_px = {n: round(float(f), 1) for n, f in cameras.exif_focal_px.items()}
    if cameras.identical_units:
        quality.identical_units = [{"cameras": list(names), "why": why}
                                   for names, why in cameras.identical_units]
    if rematch is not None:
        quality.rematch = rematch.record()
    for warning in warnings(result.rig, config, images.camera_names, consensus, rematch,
                            match_tracks, keypoints, units_apart_deg):
        log.warning("%s", warning)
        if progress.on_message is not None:
            progress.on_message(warning)
        quality.warnings.append(warning)
    with_point_colours(result, images.frame_sets)


def warnings(rig: RigCalibration, config: PipelineConfig, camera_names: Sequence[str],
             consensus: Optional[ConsensusRecord], rematch: Optional[Rematch],
             match_tracks: Optional[Tracks], keypoints: bool = False,
             units_apart_deg: Optional[float] = None) -> list[str]:
    """What the user is warned of about the finished rig: runs that still disagree as it stands,
    a camera not registered, cameras placed by pairs alone or loosely, given intrinsics that do
    not fit, lenses unlike a real one or folding before the image corner, focal lengths the
    images leave open or looser than the aim; after a second matcher, what it gave. keypoints:
    pose keypoints joined the matches (named with them); units_apart_deg: as
    consensus.disagreement_warning's."""
    with_keypoints = " and the keypoints" if keypoints else ""
    on_sift = perspective_on_sift(config, camera_names) and not config.second_matcher
    out = []
    if consensus is not None:
        standing = standing_disagreement_deg(rig.quality)
        if standing is not None and standing > WARN_DISAGREEMENT_DEG:
            out.append(disagreement_warning(
                consensus.disagreement_deg, consensus.num_runs, on_sift,
                consensus.least_determined_pairs, named_pair_counts(match_tracks, camera_names),
                len(rig.cameras), units_apart_deg, intrinsics_shared(config)))
    if rematch is None:
        out.append(unregistered_warning(rig, on_sift))
    out.append(pairwise_only_warning(rig))
    out += [unrefined_warning(rig), groups_apart_warning(rig)]
    out += given_intrinsics_warnings(rig.quality.given_intrinsics_fit or {})
    # the loose rotations after the causes that may explain them
    out += [unlike_lens_warning(rig), weak_focal_warning(rig), loose_rotation_warning(rig),
            corner_fold_warning(rig)]
    if rematch is None:
        out.append(loose_focal_warning(rig, f"{config.matcher}'s matches{with_keypoints}"))
    else:
        out.append(unregistered_warning(rig))
        if not rematch.kept_second:
            # Above the weak bound the weak warning has given the hint already.
            hint = "" if weak_focal_warning(rig) else one_camera_hint(rig)
            out.append(f"{rematch.second}'s matches were tried as well and gave no better "
                       f"determined rig ({rematch.second_result}).{hint}")
        else:
            out.append(loose_focal_warning(rig, f"{rematch.second}'s matches (kept over "
                                                f"{rematch.first}'s){with_keypoints}"))
    return [w for w in out if w]


# A camera with fewer observations than this of points a third camera sees is placed by one pair's
# matches alone: nothing in the rig checks them (the floor known_intrinsics judges a focal by, for
# the same reason: two views do not pin it down).
MIN_CROSS_CHECKED_OBSERVATIONS = 30


def refusal(rig: RigCalibration, config: PipelineConfig, camera_names: Sequence[str],
            consensus: Optional[ConsensusRecord], match_tracks: Optional[Tracks],
            units_apart_deg: Optional[float] = None) -> Optional[str]:
    """Why the finished rig is refused: a rig of three or more cameras left with one pair
    (pair_alone_refusal), a camera whose own rotation sigma exceeds UNPLACED_ROTATION_STD_DEG
    (unplaced_refusal) or whose projection sigma reaches OPEN_PROJECTION_FRACTION of its image
    (open_lens_refusal), or (consensus.REFUSE_DISAGREEMENT_DEG) the other runs that fit the
    matches about as well stand that far from it, and so does the runner-up where both were
    refined on the images; None where it is not refused. units_apart_deg: as
    consensus.disagreement_warning's."""
    on_sift = perspective_on_sift(config, camera_names) and not config.second_matcher
    alone = pair_alone_refusal(rig, config, camera_names, on_sift) or \
        unplaced_refusal(rig, match_tracks, camera_names, config.cameras.known_intrinsics) or \
        open_lens_refusal(rig, match_tracks, camera_names)
    if alone:
        return alone
    if consensus is None or consensus.fitting_disagreement_deg is None or \
            consensus.fitting_disagreement_deg <= REFUSE_DISAGREEMENT_DEG:
        return None
    refined = rig.quality.consensus_refined_disagreement_deg  # the runner-up's, both refined
    if refined is not None and refined <= REFUSE_DISAGREEMENT_DEG:
        return None
    return refusal_message(consensus.fitting_disagreement_deg,
                           consensus.num_runs - consensus.worse_fit_runs, on_sift,
                           consensus.least_determined_pairs,
                           named_pair_counts(match_tracks, camera_names), len(rig.cameras),
                           units_apart_deg, intrinsics_shared(config))


def pair_alone_refusal(rig: RigCalibration, config: PipelineConfig,
                       camera_names: Sequence[str], perspective_on_sift: bool = False
                       ) -> Optional[str]:
    """Why a rig of three or more cameras that came out with two of them registered, not both
    with given intrinsics, is refused; None otherwise. What is left is one pair's geometry: its
    self-calibrated focal lengths rest on that pair's epipolar geometry alone, which leaves them
    open where the optical axes meet (the degeneracy of focal lengths from a fundamental
    matrix: cameras aimed at one spot, as a ring around a room is), and no third camera checks
    the pair, so a wrong pair (mirrored, on something that moved) fits as well as a right one.
    A rig of three or more cameras each placed by pairs alone is warned, not refused
    (pairwise_only_warning; docs/design-notes.md, One pair left of a rig: refused).
    perspective_on_sift: as unregistered_warning's."""
    own = [n for n in camera_names if n in rig.cameras
           and n not in config.cameras.known_intrinsics]
    if len(camera_names) < 3 or len(rig.cameras) != 2 or not own:
        return None
    a, b = sorted(rig.cameras, key=list(camera_names).index)
    focal, them = ((f"{own[0]}'s self-calibrated focal length rests", "it") if len(own) == 1
                   else ("their self-calibrated focal lengths rest", "them"))
    return (f"the calibration is refused: of the {len(camera_names)} cameras only {a} and {b} "
            f"were registered, and one pair does not determine a rig: {focal} on that pair's "
            f"epipolar geometry alone, which leaves {them} open where the optical axes meet "
            "(cameras aimed at one spot), and no third camera checks the pair's geometry. "
            f"{_unregistered_said(rig)} Add frame sets in which three or more cameras see the "
            "same things (a person crossing the middle), give keypoints of what moves "
            f"(--keypoints), or give {' and '.join(own)}'s intrinsics from a lab calibration "
            "(--intrinsics NAME=FILE) to calibrate the pair alone."
            + asift_hint(perspective_on_sift))


def pairwise_only_warning(rig: RigCalibration) -> Optional[str]:
    """The warning for a rig of three or more cameras in which some camera's pose rests on
    points only two cameras see (CameraQuality.num_multiview_observations, in the final fit or
    the SfM's that placed it, whichever is more, below MIN_CROSS_CHECKED_OBSERVATIONS): a pair's
    wrong geometry (matches on repeated structure or on something that moved, a mirrored pose)
    is then consistent with everything else and goes unnoticed, whatever the runs and the fit
    say. None otherwise."""
    if len(rig.cameras) < 3:
        return None
    counts = {name: max((n for n in (cam.quality.num_multiview_observations,
                                     cam.quality.sfm_multiview_observations) if n is not None),
                        default=None)
              for name, cam in rig.cameras.items() if cam.quality is not None}
    weak = [f"{name} ({n})" for name, n in counts.items()
            if n is not None and n < MIN_CROSS_CHECKED_OBSERVATIONS]
    if not weak:
        return None
    return (f"cameras placed by camera pairs alone: {', '.join(weak)} observations of points "
            f"a third camera sees (fewer than {MIN_CROSS_CHECKED_OBSERVATIONS}), so no other "
            "camera checks the pairs' geometry and a wrong one (matches on repeated structure or on "
            "something that moved) would look as good as a right one. Add frame sets in which "
            "three or more cameras see the same things (a person crossing the middle), give "
            "keypoints of what moves (--keypoints), or check the layout (densecalib report "
            "--plot) before relying on it.")


def unrefined_warning(rig: RigCalibration) -> Optional[str]:
    """The warning for a rig the image refinement left as the SfM found it because a camera kept
    too few dense correspondences (RigQuality.image_refinement_too_few_dense); None otherwise.
    The refinement is the step that pins down each camera's principal point and focal length,
    and with them its rotation, on unbiased correspondences (core.method.dense_matches); without
    it the rig rests on keypoint matches, whose bias it was built to remove."""
    thin = rig.quality.image_refinement_too_few_dense
    if not thin:
        return None
    them, one = " and ".join(thin), len(thin) == 1
    return (f"not refined on the images: {them} kept "
            f"{' and '.join(str(k) for k in thin.values())} dense observations, fewer than the "
            f"{MIN_CAMERA_OBSERVATIONS} a camera needs, so "
            "the rig rests on the keypoint matches alone, without the refinement that pins down "
            "each camera's principal point and focal length and with them its rotation. Add "
            f"frame sets in which {them} {'sees' if one else 'see'} textured things the other "
            f"cameras see as well, or give {'its' if one else 'their'} intrinsics from a lab "
            "calibration (--intrinsics NAME=FILE).")


# A camera placed to this (1 sigma, relative to the reference camera) may well be twice as far
# off: 3 deg, where a pair of cameras stops counting as right (AUC@3) and a tracker's rays
# from the two miss by 5 cm at a metre; the calibration reaches a tenth of a degree where the
# images determine the rig.
LOOSE_ROTATION_STD_DEG = 1.5


# A camera placed to this (1 sigma) may be three times as far off: as far as the runs that
# refuse a calibration stand apart (REFUSE_DISAGREEMENT_DEG), so the images place it no better.
UNPLACED_ROTATION_STD_DEG = REFUSE_DISAGREEMENT_DEG / 3


def _own_rotation_sigmas(rig: RigCalibration, above_deg: float) -> list[tuple[float, str]]:
    """(the image refinement's rotation sigma, camera) above above_deg, loosest first; [] where
    the runs' disagreement or groups the dense points leave apart widened the sigmas (their own
    warnings say why)."""
    quality = rig.quality
    if quality.sigmas_runs_spread or quality.image_refinement_groups_apart:
        return []
    return sorted(((cam.quality.rotation_std_deg, name) for name, cam in rig.cameras.items()
                   if cam.quality is not None and cam.quality.rotation_std_deg is not None
                   and cam.quality.rotation_std_deg > above_deg), reverse=True)


def _sigma_words(rig: RigCalibration) -> tuple[str, str]:
    """How the rotation sigmas are named: ("own ", "") where they are the image refinement's
    alone, ("", naming the other matcher's calibration) where comparing it may have widened them
    (second_matcher.with_matchers_apart)."""
    other = rig.quality.sigmas_matchers_spread
    return ("", f", the calibration on {other}'s matches compared with it") if other \
        else ("own ", "")


def unplaced_refusal(rig: RigCalibration, match_tracks: Optional[Tracks] = None,
                     camera_names: Sequence[str] = (), known_intrinsics: Sequence[str] = ()
                     ) -> Optional[str]:
    """Why a rig in which the images place some camera's rotation more loosely than
    UNPLACED_ROTATION_STD_DEG (its own sigma, relative to the reference camera) is refused, naming
    that camera with the reference camera and the matches they share; None otherwise. Warned
    instead, such a rig came out wrong (a generated room of three fisheye units 120 deg apart: 3.7
    deg off, sigmas 15 and 8.7 deg; docs/design-notes.md, Cameras the images do not place).
    known_intrinsics: the cameras whose intrinsics were given (not suggested again)."""
    loose = _own_rotation_sigmas(rig, UNPLACED_ROTATION_STD_DEG)
    if not loose:
        return None
    std, camera = loose[0]
    ref = rig.reference_camera
    shared = named_pair_counts(match_tracks, camera_names)
    count = shared.get((ref, camera), shared.get((camera, ref)))
    others = "".join(f", {n}'s {s:.1f} deg" for s, n in loose[1:])
    own, compared = _sigma_words(rig)
    return (f"the calibration is refused: the images place {camera} only to within "
            f"{std:.1f} deg of {ref} (the calibration's {own}rotation sigma{others}"
            f"{compared}), so at three sigmas {camera} may be {3 * std:.0f} deg off, "
            f"beyond the {REFUSE_DISAGREEMENT_DEG:.0f} deg at which runs that disagree refuse a "
            "calibration."
            + (f" {camera} and {ref} share {count} keypoint matches." if count is not None else "")
            + f" Add frame sets in which {ref} and {camera} see the same textured things (a "
            "person crossing between them), give keypoints of what moves (--keypoints)"
            + (f", or give {camera}'s intrinsics from a lab calibration (--intrinsics "
               f"{camera}=FILE)." if camera not in known_intrinsics else "."))


# A camera whose own projection sigma (where a ray lands, mean over the image) is this fraction
# of its image's long side may put a ray half the image away at two sigma: the images leave its
# focal length and distortion open, whatever its pose came out as.
OPEN_PROJECTION_FRACTION = 0.25


def open_lens_refusal(rig: RigCalibration, match_tracks: Optional[Tracks] = None,
                      camera_names: Sequence[str] = ()) -> Optional[str]:
    """Why a rig in which some camera's projection sigma is OPEN_PROJECTION_FRACTION of its
    image's long side or more is refused, naming the loosest such camera and the camera it shares
    the most keypoint matches with; None otherwise. Only the image refinement's sigmas are judged
    (the cameras it recorded estimated_intrinsics for): a final bundle adjustment's covariance
    alone, where it holds a focal length weakly, can be near singular on a right rig
    (docs/design-notes.md, Lenses the images leave open); given intrinsics have no sigma."""
    open_ = sorted(((cam.quality.projection_std_px / max(cam.intrinsics.width,
                                                         cam.intrinsics.height), name)
                    for name, cam in rig.cameras.items() if cam.quality is not None
                    and cam.quality.estimated_intrinsics is not None
                    and cam.quality.projection_std_px is not None), reverse=True)
    open_ = [(fraction, name) for fraction, name in open_ if fraction >= OPEN_PROJECTION_FRACTION]
    if not open_:
        return None
    fraction, camera = open_[0]
    cam = rig.cameras[camera]
    shared = {pair: n for pair, n in named_pair_counts(match_tracks, camera_names).items()
              if camera in pair and n > 0}
    partner = max(shared, key=shared.get) if shared else None
    others = "".join(f", {n}'s {100 * f:.0f} %" for f, n in open_[1:])
    return (f"the calibration is refused: the images leave {camera}'s lens open: where a ray "
            f"lands in its image is known to {cam.quality.projection_std_px:.0f} px only (the "
            f"calibration's projection sigma, mean over the image: {100 * fraction:.0f} % of its "
            f"{max(cam.intrinsics.width, cam.intrinsics.height)} px side{others}), so its focal "
            "length and distortion, and the rig placed with them, may be anything near what came "
            "out."
            + (f" It shares the most keypoint matches, {shared[partner]}, with "
               f"{[n for n in partner if n != camera][0]}." if partner else "")
            + f" Give {camera}'s intrinsics from a lab calibration (--intrinsics {camera}=FILE), "
            "calibrate units of one model together (--share-intrinsics), or add frame sets in "
            f"which {camera} sees, over more of its image, what the other cameras see."
            + (" A fisheye wider than 180 deg needs its intrinsics given: the SfM's lens model "
               "(pycolmap's) projects nothing more than 90 deg off the axis."
               if "FISHEYE" in cam.intrinsics.model else ""))


def loose_rotation_warning(rig: RigCalibration) -> Optional[str]:
    """The warning for a rig in which the image refinement's own sigmas place some camera's
    rotation more loosely than LOOSE_ROTATION_STD_DEG; None otherwise, and where another warning
    says why already: runs that disagree (their spread is in the sigmas,
    RigQuality.sigmas_runs_spread) or groups the dense points leave apart
    (groups_apart_warning)."""
    loose = _own_rotation_sigmas(rig, LOOSE_ROTATION_STD_DEG)
    if not loose:
        return None

    def listed(items: list) -> str:
        return ", ".join(items[:-1]) + " and " + items[-1] if len(items) > 1 else items[0]

    them = listed([name for _, name in loose])
    own, compared = _sigma_words(rig)
    return (f"cameras placed loosely: the calibration's {own}rotation sigmas are "
            f"{listed([f'{name} {std:.1f} deg' for std, name in loose])} (relative to "
            f"{rig.reference_camera}{compared}), so a pair may be "
            f"{2 * LOOSE_ROTATION_STD_DEG:.0f} deg or more off. The images leave "
            f"{'its' if len(loose) == 1 else 'their'} rotation open against the principal point "
            f"and focal length: add frame sets in which {them} "
            f"{'sees' if len(loose) == 1 else 'see'} textured things the other cameras see as "
            "well, or give the intrinsics from a lab calibration (--intrinsics NAME=FILE).")


def groups_apart_warning(rig: RigCalibration) -> Optional[str]:
    """The warning for a rig refined on dense correspondences that leave its cameras in groups
    sharing too few points (RigQuality.image_refinement_groups_apart): how the groups stand to
    one another rests on the keypoint matches alone, and their rotation sigmas, which the dense
    correspondences give, say they are not determined. None otherwise."""
    groups = rig.quality.image_refinement_groups_apart
    if not groups:
        return None
    said = " and ".join("{" + ", ".join(g) + "}" for g in groups)
    return (f"the dense correspondences leave the cameras in {len(groups)} groups that share "
            f"too few points, {said}: each group is refined on the images, but how the groups "
            "stand to one another rests on the keypoint matches alone (their rotation sigmas say "
            "the images leave it open). Add frame sets in which cameras of different groups see "
            "the same textured things.")


def unregistered_warning(rig: RigCalibration, perspective_on_sift: bool = False
                         ) -> Optional[str]:
    """The message for a user whose rig came out without some of its cameras: which, the camera
    each shares the most keypoint matches with (quality.unregistered_best_partner), and what
    would place them (more overlap, or given intrinsics where the camera was left out for
    implausible ones: plausibility.drop_implausible_cameras); None where every camera was
    registered. perspective_on_sift: as consensus.disagreement_warning's (the message suggests
    asift)."""
    failed = rig.failed_cameras
    if not failed:
        return None
    one = len(failed) == 1
    it, its, subject = ("it", "its", failed[0]) if one else ("them", "their", "they")
    return (f"{_unregistered_said(rig)} The other "
            f"{len(rig.cameras)} cameras are calibrated without {it}. Add frame sets in which "
            f"{subject} and the neighbouring cameras see the same textured things, or turn {it} "
            f"to overlap more with them. If {'it does' if one else 'they do'} overlap, {its} "
            f"intrinsics from a lab calibration (--intrinsics {failed[0] if one else 'NAME'}"
            f"=FILE) would place {it}: a camera whose self-calibrated intrinsics come out "
            "implausible is left out as well." + asift_hint(perspective_on_sift))


def _unregistered_said(rig: RigCalibration) -> str:
    """The sentence naming the cameras left out and, where known, the most keypoint matches each
    shares with another camera (quality.unregistered_best_partner); "" where none was."""
    failed = rig.failed_cameras
    if not failed:
        return ""
    partners = rig.quality.unregistered_best_partner or {}
    one = len(failed) == 1
    shared = ""
    if all(c in partners for c in failed):
        counts = (f"{partners[failed[0]][1]}" if one else " and ".join(
            f"{partners[c][1]} ({c}, with {partners[c][0]})" for c in failed))
        shared = (f": {'it shares' if one else 'they share'} at most {counts} keypoint matches "
                  "with another camera" + (f" ({partners[failed[0]][0]})" if one else ""))
    return f"{' and '.join(failed)} could not be registered{shared}."


def with_point_colours(result: CalibrationResult,
                       frame_sets: Sequence[Sequence[np.ndarray]]) -> None:
    """Colour the result's reconstruction points from the images (reconstruction.colour_points)."""
    if result.reconstruction is None or result.state is None:
        return
    try:
        colour_points(result.reconstruction, result.state, frame_sets)
    except Exception as exc:  # colours are for viewing: they never cost a calibration
        log.warning("scene points left uncoloured: %r", exc)


def _best_partners(cameras: Sequence[str], tracks: Optional[Tracks],
                   camera_names: Sequence[str]) -> Optional[dict]:
    """{camera: [the other camera it shares the most keypoint-match tracks with, how many]} for
    `cameras` (view_graph.named_pair_counts); None without keypoint-match tracks (a dense
    matcher)."""
    shared = named_pair_counts(tracks, camera_names)
    if not shared:
        return None
    out = {}
    for name in cameras:
        counts = {(b if a == name else a): n for (a, b), n in shared.items() if name in (a, b)}
        partner = max(counts, key=counts.get)
        out[name] = [partner, counts[partner]]
    return out
