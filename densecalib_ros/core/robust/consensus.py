"""Consensus over calibrations of the same matches from differently seeded track samples.

Stage 2 of the sampling draws tracks at random (score-proportional picks, paper Sec. 3.2), and on
weakly connected rigs (few 3-view tracks, converging optical axes, an end camera held by 2-view
tracks) the SfM outcome depends on that draw: one seed gives a right rig, the next a wrong one
(docs/design-notes.md, Consensus: best fit vs vote). Running the SfM on a few independent samples
and keeping the medoid (the run that disagrees least with the others in relative camera poses)
turns that lottery into a majority vote; on well-connected rigs all runs agree and the medoid is
any of them. How much the runs disagree is reported with the result: it is a direct measure of
how well the data determine the rig.

Before the vote, each run's cameras are scored on the same observations: a seeded sample of all
runs' tracks in the cameras that every run registered, triangulated from that run's cameras
(`common_track_costs`). Scoring only shared cameras lets a run that left out one hard camera
compete on equal terms: it can be the right run, the others fitting the remaining cameras worse
(same section). A run that fits them clearly worse than the best run is a wrong reconstruction,
not an equally good alternative, and is not kept even when it is the medoid (where most runs are
wrong).

Which observations judge the runs matters. Each run's tracks were drawn by its own seed and fitted
by its own SfM, so on a sample of all runs' tracks every run is partly judged on what it was built
from, and a wrong rig can fit them better than the right one (same section). Where the runs were
all refined last on the same keypoint-match tracks (pipeline.refine_on_all_matches), they are
local optima of one objective on one data set, and the run that fits those tracks best is kept,
as the focal multi-start inside each run keeps its best start: on development rigs the best fit
picked better runs than the vote did, near the best single run (same section). Only runs that
registered the most cameras among those fitting about as well as the best compete, so a run does
not win by leaving a camera out. Without such tracks (a dense matcher), runs that fit about
equally well, the near-ambiguous case of converging cameras with free focals, are left to the
vote.

Runs that disagree on the keypoint matches may still meet once refined on the images' dense
correspondences (core.method.image_refinement), whose minimum is far sharper than the keypoint
matches' flat valley: the pipeline then refines the runner-up run too, and the disagreement that
stands (standing_disagreement_deg) is that of the two refined rigs.
"""
from __future__ import annotations

from dataclasses import dataclass
from itertools import combinations
from typing import Optional, Sequence

import numpy as np

from ..method.multistart import (AGREEMENT_DEG, HELD_OUT_TRUNCATION_PX, MAX_AGREEMENT_DEG,
                                 WORSE_FIT_RATIO, truncated_cost)
from ..method.reconstruction import SfMState, triangulate_tracks
from ..types import RigCalibration, Tracks

# A camera pair that one of two runs placed and the other did not (a camera of it not registered)
# counts as this far apart. A pair that neither run placed is left out of their disagreement:
# two runs that leave the same camera out say the same about it.
UNREGISTERED_PAIR_DEG = 180.0
# Once this many runs have succeeded, stop if they agree (multistart.agreement_deg: mean over
# camera pairs): further runs could not make the rig more accurate. Well-connected rigs agree to a
# fraction of it, weak ones disagree by several times it (docs/design-notes.md, Consensus: best
# fit vs vote). Two runs on different track samples that land in one rig have answered the
# sampling's lottery, whether or not the first run's focal multi-start settled (Consensus: two
# agreeing runs). Judged once: runs that disagree stay apart however many more are made (their
# disagreement is the largest between any two). Where the first run settled and registered every
# camera, it alone answers (pipeline._settled_whole).
EARLY_STOP_RUNS = 2
# The kept run's median disagreement above which the user is warned: AUC@3's threshold, i.e. the
# other runs put the cameras where the kept one would count as wrong; runs closer than it can
# still count as one answer (multistart.agreement_deg), so both are that one threshold.
WARN_DISAGREEMENT_DEG = MAX_AGREEMENT_DEG
# The kept run's median disagreement with the other runs that fit the matches as well above which
# the calibration is refused, not warned: AUC@30's threshold, the bench's coarsest. Runs that fit
# equally well and stand this far apart disagree about where the cameras are, not how precisely,
# and nothing in the matches prefers one (rigs kept this far from their runs have all been wrong:
# 53-151 deg; right or partly right ones stood 22 deg apart at most: docs/design-notes.md,
# Refused, not warned).
REFUSE_DISAGREEMENT_DEG = 30.0
MAX_PAIRS_SAID = 3  # a warning names this many pairs at most: the rest is in the quality record
# A run whose truncated reprojection cost on the common tracks exceeds the best run's by
# WORSE_FIT_RATIO (multistart) is not kept: a wrong reconstruction, not an alternative.
COMMON_TRACKS_MAX = 3000  # the common tracks: a seeded sample of at most this many


def _angle_deg(cos: float) -> float:
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))


def pair_disagreement_deg(a: RigCalibration, b: RigCalibration, cam_i: str, cam_j: str
                          ) -> Optional[float]:
    """max(angle between the relative rotations cam_j_from_cam_i of a and b, angle between their
    relative translation directions) in degrees: the pose error AUC@3 thresholds, between runs.
    UNREGISTERED_PAIR_DEG where only one of the runs registered both cameras; None where
    neither did."""
    placed = [cam_i in r.cameras and cam_j in r.cameras for r in (a, b)]
    if not any(placed):
        return None
    if not all(placed):
        return UNREGISTERED_PAIR_DEG
    rel = [r.cameras[cam_j].cam_from_rig @ np.linalg.inv(r.cameras[cam_i].cam_from_rig)
           for r in (a, b)]
    rotation = _angle_deg((np.trace(rel[0][:3, :3] @ rel[1][:3, :3].T) - 1.0) / 2.0)
    ta, tb = rel[0][:3, 3], rel[1][:3, 3]
    norm = np.linalg.norm(ta) * np.linalg.norm(tb)
    direction = _angle_deg(float(ta @ tb) / norm) if norm > 0 else 0.0
    return max(rotation, direction)


def rig_disagreement_deg(a: RigCalibration, b: RigCalibration,
                         camera_names: Sequence[str]) -> float:
    """Mean pair_disagreement_deg over the pairs of camera_names that either run placed; 0 where
    neither placed any."""
    degs = [d for d in (pair_disagreement_deg(a, b, i, j)
                        for i, j in combinations(camera_names, 2)) if d is not None]
    return float(np.mean(degs)) if degs else 0.0


def medoid(rigs: Sequence[RigCalibration], camera_names: Sequence[str],
           candidates: Optional[Sequence[int]] = None) -> tuple[int, np.ndarray]:
    """Index of the rig among `candidates` (default: all) with the smallest summed disagreement
    with all the others (the first on ties) and the (R, R) disagreement matrix in degrees."""
    n = len(rigs)
    D = np.zeros((n, n))
    for i, j in combinations(range(n), 2):
        D[i, j] = D[j, i] = rig_disagreement_deg(rigs[i], rigs[j], camera_names)
    keep = list(range(n)) if candidates is None else list(candidates)
    return keep[int(np.argmin(D[keep].sum(axis=1)))], D


def common_track_costs(rigs: Sequence[RigCalibration], runs_tracks: Sequence[Tracks],
                       camera_names: Sequence[str], truncation_px, seed: int = 0
                       ) -> np.ndarray:
    """Per rig, the truncated reprojection cost (multistart.truncated_cost, px) of the common
    tracks (a seeded sample of at most COMMON_TRACKS_MAX of all runs' tracks) triangulated from
    that rig's cameras, held fixed, over the cameras that every rig registered: so every rig is
    scored on the same observations, and a run that left out a hard camera is not favoured for
    fitting fewer of them. All NaN when fewer than two cameras are shared."""
    shared = [c for c, n in enumerate(camera_names) if all(n in r.cameras for r in rigs)]
    if len(shared) < 2:
        return np.full(len(rigs), np.nan)
    common = Tracks.concatenate(list(runs_tracks), len(camera_names)).sample(COMMON_TRACKS_MAX,
                                                                            seed)
    costs = []
    for rig in rigs:
        any_camera = rig.cameras[camera_names[shared[0]]].intrinsics
        state = SfMState.create(common, [rig.cameras[n].intrinsics if n in rig.cameras
                                         else any_camera for n in camera_names])
        for c in shared:
            state.cam_from_world[c] = rig.cameras[camera_names[c]].cam_from_rig
        triangulate_tracks(state, max_error_px=float(np.max(truncation_px)), seed=seed)
        costs.append(truncated_cost(state, truncation_px))
    return np.array(costs)


def well_fitting_runs(costs: np.ndarray) -> list[int]:
    """The runs whose common-track cost is within WORSE_FIT_RATIO of the best; every run when
    the costs could not be computed (NaN)."""
    if not np.isfinite(costs).any():
        return list(range(len(costs)))
    bar = WORSE_FIT_RATIO * np.nanmin(costs)
    return [k for k, c in enumerate(costs) if c <= bar]


@dataclass
class Choice:
    best: int  # the run to keep
    disagreement_deg: np.ndarray  # (R, R) rig_disagreement_deg between runs
    costs_px: np.ndarray  # (R,) common-track costs; NaN when the runs agree and none was needed
    worse_fit: list[int]  # runs not kept because they fit the common tracks clearly worse
    by_fit: bool = False  # kept as the best fit to the tracks all runs were refined on (not the vote)


def choose_run(rigs: Sequence[RigCalibration], runs_tracks: Sequence[Tracks],
               camera_names: Sequence[str], truncation_px, seed: int = 0,
               refined_on: Optional[Tracks] = None, agree_deg: float = AGREEMENT_DEG,
               first_searched_more: bool = False) -> Choice:
    """The run to keep (module docstring). When all runs agree within agree_deg
    (multistart.agreement_deg), simply the medoid; two runs are a tie, kept by the first where it
    searched more focal starts than the second (`first_searched_more`: the later runs of a settled
    multi-start try only its best starts), else by the fit to refined_on as below: runs that
    agree still differ by up to agree_deg, which the image refinement need not close.
    Otherwise, among the runs that fit about as well as the best one (well_fitting_runs) and
    registered the most cameras among those: with refined_on (tracks every run was refined on
    last, e.g. all keypoint matches), the one that fits them best, its cost truncated at most at
    HELD_OUT_TRUNCATION_PX as they are raw matches; without, the medoid of the costs on a sample
    of all runs' own tracks (runs_tracks)."""
    best, D = medoid(rigs, camera_names)
    judge = refined_on is not None and refined_on.num_tracks > 0
    agree = len(rigs) < 2 or D.max() < agree_deg
    tie = agree and len(rigs) == 2 and judge and not first_searched_more
    if agree and not tie:
        return Choice(best, D, np.full(len(rigs), np.nan), [])
    if judge:
        costs = common_track_costs(rigs, [refined_on], camera_names,
                                   np.minimum(truncation_px, HELD_OUT_TRUNCATION_PX), seed)
    else:
        costs = common_track_costs(rigs, runs_tracks, camera_names, truncation_px, seed)
    if tie:  # the better fit, where both runs could be judged
        by_fit = bool(np.isfinite(costs).all())
        return Choice(int(np.argmin(costs)) if by_fit else best, D, costs, [], by_fit)
    fitting = well_fitting_runs(costs)
    most = max(len(rigs[k].cameras) for k in fitting)
    complete = [k for k in fitting if len(rigs[k].cameras) == most]
    by_fit = judge and bool(np.isfinite(costs[complete]).all())
    if by_fit:
        best = complete[int(np.argmin(costs[complete]))]
    else:
        best = medoid(rigs, camera_names, complete)[0]
    return Choice(best, D, costs, [k for k in range(len(rigs)) if k not in fitting], by_fit)


def least_determined_pairs(kept: RigCalibration, others: Sequence[RigCalibration],
                           camera_names: Sequence[str]) -> list[tuple[str, str, float]]:
    """(camera, camera, deg) for the camera pairs whose relative pose the other runs put more than
    WARN_DISAGREEMENT_DEG from the kept run's (pair_disagreement_deg, the median over the other
    runs), the least determined first. Only pairs of cameras the kept run registered: the others
    are failed cameras, reported as such."""
    if not others:
        return []
    pairs = []
    for a, b in combinations([n for n in camera_names if n in kept.cameras], 2):
        deg = float(np.median([pair_disagreement_deg(kept, o, a, b) for o in others]))
        if deg > WARN_DISAGREEMENT_DEG:
            pairs.append((a, b, deg))
    return sorted(pairs, key=lambda p: -p[2])


def standing_disagreement_deg(quality) -> Optional[float]:
    """The runs' disagreement (deg) as the calibration stands (a RigQuality's): that of the kept
    and the runner-up rigs refined on the dense image correspondences where both were
    (consensus_refined_disagreement_deg), else the runs' own; None without consensus runs."""
    if quality.consensus_refined_disagreement_deg is not None:
        return quality.consensus_refined_disagreement_deg
    return quality.consensus_disagreement_deg


def disagreement_warning(disagreement_deg: float, num_runs: int,
                         perspective_on_sift: bool = False,
                         pairs: Sequence[tuple[str, str, float]] = (),
                         shared_matches: Optional[dict] = None,
                         num_cameras: int = 0, units_apart_deg: Optional[float] = None,
                         units_shared: bool = False) -> Optional[str]:
    """The message for a user whose runs disagree by more than WARN_DISAGREEMENT_DEG, else None.
    perspective_on_sift: perspective cameras matched with sift, whose matches a wide viewpoint
    change or a long lens thins out (docs/benchmarks.md): the message suggests asift. pairs: the
    least determined camera pairs (least_determined_pairs), named with their shared keypoint
    matches (shared_matches: {(a, b): count}) and, where one camera is in each of them, that
    camera: it is the one the images do not place. num_cameras: how many the kept run calibrated
    (every pair of them named: the whole rig is undetermined). units_apart_deg: how far apart
    the runs stood with the cameras calibrated as units of one model as well (robust.one_model;
    None where that was not tried or its runs agreed); units_shared: the cameras' intrinsics were
    shared already. Either way sharing them is not suggested."""
    if disagreement_deg <= WARN_DISAGREEMENT_DEG:
        return None
    return (f"the {num_runs} calibration runs disagree: the kept one is {disagreement_deg:.1f} deg "
            "(median over camera pairs) from the others, so the images allow quite different rigs "
            "and this one may be wrong." + _pairs_said(pairs, shared_matches or {}, num_cameras)
            + _remedies(perspective_on_sift, units_apart_deg, units_shared))


def refusal_message(disagreement_deg: float, num_runs: int, perspective_on_sift: bool = False,
                    pairs: Sequence[tuple[str, str, float]] = (),
                    shared_matches: Optional[dict] = None, num_cameras: int = 0,
                    units_apart_deg: Optional[float] = None, units_shared: bool = False) -> str:
    """Why a calibration whose runs disagree beyond REFUSE_DISAGREEMENT_DEG is refused, with the
    pairs and remedies of disagreement_warning (its arguments)."""
    return (f"the calibration is refused: its {num_runs} runs, which fit the matches about as "
            f"well, place the cameras {disagreement_deg:.0f} deg apart (median over camera "
            "pairs), so these images do not determine the rig and any of the runs' rigs could be "
            "that far off." + _pairs_said(pairs, shared_matches or {}, num_cameras)
            + _remedies(perspective_on_sift, units_apart_deg, units_shared))


def asift_hint(perspective_on_sift: bool) -> str:
    """The sentence suggesting asift to perspective cameras matched with sift, else ""."""
    return (" With cameras far apart or long lenses, --matcher asift (node: matcher asift) finds "
            "the matches a wide viewpoint change leaves sift." if perspective_on_sift else "")


def _remedies(perspective_on_sift: bool, units_apart_deg: Optional[float] = None,
              units_shared: bool = False) -> str:
    units = ("" if units_shared else
             f" (as units of one model, which they could be, the runs stood "
             f"{units_apart_deg:.0f} deg apart too)" if units_apart_deg is not None else
             ", or use --share-intrinsics (node: share_intrinsics; SfMConfig.share_intrinsics) "
             "if the cameras are identical units")
    return (" Add frame sets (time-aligned images of a changing scene) or more overlap between "
            "cameras" + units + "." + asift_hint(perspective_on_sift))


def _pairs_said(pairs: Sequence[tuple[str, str, float]], shared: dict, num_cameras: int) -> str:
    if not pairs:
        return ""
    def said(a: str, b: str, deg: float) -> str:
        count = shared.get((a, b), shared.get((b, a)))
        return f"{a}/{b} ({deg:.0f} deg" + (f"; {count} shared matches)" if count is not None
                                            else ")")
    named = ", ".join(said(*p) for p in pairs[:MAX_PAIRS_SAID])
    if num_cameras >= 3 and len(pairs) == num_cameras * (num_cameras - 1) // 2:
        return " The runs disagree about every pair of the cameras calibrated: the rig is not " \
               f"determined (most about {named})."
    text = " Least determined: " + named + "."
    common = set(pairs[0][:2]).intersection(*(set(p[:2]) for p in pairs))
    if len(common) == 1:
        camera = common.pop()
        text += (f" {camera} is in each: a frame set in which {camera} and the others see the "
                 f"same textured things, or {camera}'s intrinsics from a lab calibration "
                 f"(--intrinsics {camera}=FILE; a focal length alone, --focal-px, is only a "
                 "start), would place it.")
    return text
