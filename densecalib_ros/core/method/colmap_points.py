"""The per-point half of the pycolmap glue (reconstruction.py): a reconstruction's 3D points put
into a pycolmap Reconstruction, one Python call per point and nothing more.

A calibration builds a Reconstruction for every bundle adjustment (thousands in a hard rig's
runs), and most of the points it adds are the same tracks seen by the same cameras as in the
adjustment before. A point's pycolmap Track (its cameras and each observation's index among its
camera's points2D) depends only on the tracks' observations, which never change, and on which
cameras' observations are active, so each is made once per tracks and set of cameras and reused;
add_point3D copies it into the reconstruction, so the result is the same as making it anew.
"""
from __future__ import annotations

import weakref

import numpy as np
import pycolmap

from ..types import Tracks

# id(tracks.xy_px) -> (the array, weakly; (T, C) point2D index of each observation; the Tracks
# made: (track row, active cameras' bits) -> pycolmap.Track). Entries leave with their array.
_MADE: dict[int, tuple] = {}


def camera_bits(active: np.ndarray) -> np.ndarray:
    """int64 (N,): each row of the bool (N, C) `active` as a bit pattern (bit c: camera c)."""
    return active.astype(np.int64) @ (np.int64(1) << np.arange(active.shape[1], dtype=np.int64))


def _made_for(tracks: Tracks) -> tuple[np.ndarray, dict]:
    """The point2D indices and the Tracks made so far for `tracks` (by its observations' array,
    which is never modified: SfMState.copy)."""
    key = id(tracks.xy_px)
    entry = _MADE.get(key)
    if entry is not None and entry[0]() is tracks.xy_px:
        return entry[1], entry[2]
    # Point2D index of track t in camera c = its rank among c's observed tracks.
    point2d = np.cumsum(tracks.observed(), axis=0) - 1
    entry = (weakref.ref(tracks.xy_px), point2d, {})
    _MADE[key] = entry
    weakref.finalize(tracks.xy_px, _MADE.pop, key, None)
    return entry[1], entry[2]


def add_points(rec: pycolmap.Reconstruction, tracks: Tracks, rows: np.ndarray,
               active: np.ndarray, xyz: np.ndarray) -> list[int]:
    """Add track rows `rows` as points at xyz[rows], observed in the cameras where `active`
    (bool (len(rows), C)) holds (camera c is image c + 1); returns their point3D ids in order."""
    point2d, made = _made_for(tracks)
    add, element = rec.add_point3D, pycolmap.TrackElement
    ids = []
    for k, (t, bits) in enumerate(zip(rows.tolist(), camera_bits(active).tolist())):
        track = made.get((t, bits))
        if track is None:
            track = made[(t, bits)] = pycolmap.Track(
                [element(c + 1, int(point2d[t, c])) for c in np.flatnonzero(active[k]).tolist()])
        ids.append(add(xyz[t], track))
    return ids
