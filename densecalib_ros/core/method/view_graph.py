"""The rig's view graph: which cameras share enough tracks to be related, and whether that joins
them all (a rig in two unrelated groups cannot be calibrated as one)."""
from __future__ import annotations

from typing import Optional, Sequence

import numpy as np

from ..errors import DisconnectedViewGraphError
from ..types import Tracks


def pair_track_counts(tracks: Tracks) -> np.ndarray:
    """int (C, C): number of tracks observed by both cameras (diagonal 0)."""
    return shared_counts(tracks.observed())


def named_pair_counts(tracks: Optional[Tracks], camera_names: Sequence[str]) -> dict:
    """{(a, b): tracks observed by both cameras} for each pair of camera_names in their order;
    {} without tracks."""
    if tracks is None or not tracks.num_tracks:
        return {}
    shared = pair_track_counts(tracks)
    return {(a, b): int(shared[i, j]) for i, a in enumerate(camera_names)
            for j, b in enumerate(camera_names) if i < j}


def shared_counts(observed: np.ndarray) -> np.ndarray:
    """int (C, C) from bool (T, C): the rows observed by both cameras (diagonal 0)."""
    obs = np.asarray(observed).astype(np.int64)
    counts = obs.T @ obs
    np.fill_diagonal(counts, 0)
    return counts


def connected_components(num_cameras: int, edges: Sequence[tuple[int, int]]) -> list[list[int]]:
    """Camera groups (each sorted, groups by their first camera) of an undirected graph."""
    parent = list(range(num_cameras))

    def root(c: int) -> int:
        while parent[c] != c:
            parent[c] = parent[parent[c]]
            c = parent[c]
        return c

    for i, j in edges:
        parent[root(i)] = root(j)
    groups: dict[int, list[int]] = {}
    for c in range(num_cameras):
        groups.setdefault(root(c), []).append(c)
    return sorted(groups.values(), key=lambda g: g[0])


def check_connected(num_cameras: int, edges: Sequence[tuple[int, int]],
                    camera_names: Sequence[str], what: str) -> None:
    """Raise DisconnectedViewGraphError naming the camera groups when `edges` split the cameras."""
    groups = connected_components(num_cameras, edges)
    if len(groups) > 1:
        raise disconnected_error(groups, camera_names, what)


def disconnected_error(groups: Sequence[Sequence[int]], camera_names: Sequence[str],
                       what: str) -> DisconnectedViewGraphError:
    text = "; ".join("{" + ", ".join(camera_names[c] for c in g) + "}" for g in groups)
    return DisconnectedViewGraphError(
        f"The cameras split into {len(groups)} groups that share no {what}: {text}. A rig can "
        "only be calibrated as one: make the groups' fields of view overlap (or add frame sets "
        "where they see common, textured content), or calibrate each group on its own.")
