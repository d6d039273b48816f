"""View order of the incremental pipeline (paper Sec. 3.3 "View Order").

The score of a 3-cycle (camera triplet) is the sum of the scores of the tracks observed by all
three cameras; with scoring off (all scores 0) each track counts 1. The order starts with the
highest-scoring triplet and then repeatedly appends the camera that adds the most triplet score
with the cameras already ordered. Cameras in no scored triplet are appended by their pair
score with the ordered cameras (they can only be registered from 2-cycle points).
"""
from __future__ import annotations

import itertools

import numpy as np

from ..types import Tracks


def track_weights(tracks: Tracks) -> np.ndarray:
    """float64 (T,): the score of each track, or 1 for every track when scoring is off."""
    if tracks.num_tracks and np.any(tracks.score > 0):
        return np.asarray(tracks.score, dtype=np.float64)
    return np.ones(tracks.num_tracks)


def triplet_scores(tracks: Tracks) -> np.ndarray:
    """float64 (C, C, C) symmetric: summed track weight of tracks seen by cameras i, j and k."""
    obs = tracks.observed().astype(np.float64)
    w = track_weights(tracks)
    return np.einsum("t,ti,tj,tk->ijk", w, obs, obs, obs, optimize=True)


def pair_scores(tracks: Tracks) -> np.ndarray:
    """float64 (C, C) symmetric: summed track weight of tracks seen by cameras i and j."""
    obs = tracks.observed().astype(np.float64)
    return np.einsum("t,ti,tj->ij", track_weights(tracks), obs, obs, optimize=True)


def view_order(tracks: Tracks) -> list[int]:
    """All cameras that share any track with another camera, in registration order (the first
    three are the best triplet when one exists)."""
    C = tracks.num_cameras
    S3 = triplet_scores(tracks)
    S2 = pair_scores(tracks)
    np.fill_diagonal(S2, 0.0)
    connected = [c for c in range(C) if S2[c].sum() > 0]
    best, best_score = None, 0.0
    for tri in itertools.combinations(connected, 3):
        if S3[tri] > best_score:
            best, best_score = list(tri), S3[tri]
    if best is None:  # no 3-cycle anywhere: start from the best pair
        if not connected:
            return []
        i, j = np.unravel_index(np.argmax(S2), S2.shape)
        best = [int(i), int(j)]
    order = best
    remaining = [c for c in connected if c not in order]
    while remaining:
        gains = [sum(S3[a, b, c] for a, b in itertools.combinations(order, 2))
                 for c in remaining]
        if max(gains) <= 0:
            gains = [S2[order, c].sum() for c in remaining]
        if max(gains) <= 0:
            break  # the rest shares nothing with the ordered cameras
        order.append(remaining.pop(int(np.argmax(gains))))
    return order
