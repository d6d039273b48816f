"""Consensus over calibrations of the same matches from differently seeded track samples.

Stage 2 of the sampling draws tracks at random (score-proportional picks, paper Sec. 3.2), and on
weakly connected rigs (few 3-view tracks, converging optical axes, an end camera held by 2-view
tracks) the SfM outcome depends on that draw: one seed gives AUC@3 100, the next 11 (measured in
`densecalib bench` scenes, seeds 0-4). Running the SfM on a few independent samples and keeping the
medoid (the run that disagrees least with the others in relative camera poses) turns that lottery
into a majority vote; on well-connected rigs all runs agree and the medoid is any of them. How much
the runs disagree is reported with the result: it is a direct measure of how well the data
determine the rig.
"""
from __future__ import annotations

from itertools import combinations
from typing import Optional, Sequence

import numpy as np

from .types import RigCalibration

# A camera pair that one of two runs did not register counts as this far apart.
UNREGISTERED_PAIR_DEG = 180.0
# After this many successful runs, stop if every two of them agree within AGREEMENT_DEG (mean over
# camera pairs): a third of AUC@3's strictest threshold, so further runs could not change which
# poses count as accurate. Measured on bench scenes: 3-camera s101 0.13 deg, 6-camera s101
# 0.05 deg; weak wide rigs 2.9-7.4 deg, the real fox 12.4 deg.
EARLY_STOP_RUNS = 3
AGREEMENT_DEG = 1.0
# The kept run's median disagreement above which the user is warned: AUC@3's threshold, i.e. the
# other runs put the cameras where the kept one would count as wrong.
WARN_DISAGREEMENT_DEG = 3.0


def _angle_deg(cos: float) -> float:
    return float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))


def pair_disagreement_deg(a: RigCalibration, b: RigCalibration, cam_i: str, cam_j: str) -> float:
    """max(angle between the relative rotations cam_j_from_cam_i of a and b, angle between their
    relative translation directions) in degrees: the pose error AUC@3 thresholds, between runs."""
    if not all(c in r.cameras for c in (cam_i, cam_j) for r in (a, b)):
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
    """Mean pair_disagreement_deg over all pairs of camera_names."""
    pairs = list(combinations(camera_names, 2))
    return float(np.mean([pair_disagreement_deg(a, b, i, j) for i, j in pairs])) if pairs else 0.0


def medoid(rigs: Sequence[RigCalibration], camera_names: Sequence[str]
           ) -> tuple[int, np.ndarray]:
    """Index of the rig with the smallest summed disagreement with the others (the first on ties)
    and the (R, R) disagreement matrix in degrees."""
    n = len(rigs)
    D = np.zeros((n, n))
    for i, j in combinations(range(n), 2):
        D[i, j] = D[j, i] = rig_disagreement_deg(rigs[i], rigs[j], camera_names)
    return int(np.argmin(D.sum(axis=1))), D


def disagreement_warning(disagreement_deg: float, num_runs: int) -> Optional[str]:
    """The message for a user whose runs disagree by more than WARN_DISAGREEMENT_DEG, else None."""
    if disagreement_deg <= WARN_DISAGREEMENT_DEG:
        return None
    return (f"the {num_runs} calibration runs disagree: the kept one is {disagreement_deg:.1f} deg "
            "(median over camera pairs) from the others, so the images allow quite different rigs "
            "and this one may be wrong. Add frame sets (time-aligned images of a changing scene) or "
            "more overlap between cameras, or use --share-intrinsics (node: share_intrinsics) if "
            "the cameras are identical units.")
