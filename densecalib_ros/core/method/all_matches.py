"""The last refinement of a calibration: on every keypoint match, not only the sampled tracks.

Cycle sampling (sampling.py) summarises a matcher's output into tracks spread over the images and
biased towards wide triangulation angles: the right input to *find* the rig (registration, the
focal multi-start, the consensus). With a keypoint matcher (SIFT, XFeat + LighterGlue) the summary
also discards most of the matches, and with them information the found cameras could use: a camera
the sampled tracks tie in weakly keeps its pairs degrees off while the matches would hold it
(docs/design-notes.md, Refinement on all keypoint matches).

So once the cameras are found, every match takes part once more: the matches of all pairs of a
frame set join into tracks (connected components over mutual matches; a component holding two
keypoints of one camera is ambiguous and dropped), each track is triangulated from the found
cameras (RANSAC, as the pipelines' own re-triangulation), the observations above a gate (the
preset's B_err, at most 20 px) are dropped, and a final bundle adjustment refines poses and
intrinsics on them (filtered against the adjusted cameras and adjusted again while observations
above the gate remain, at most 3 rounds). The found cameras decide which matches are inliers, so
a wrong match cannot pull the rig far; what it cannot do is move a rig out of a wrong basin (the
consensus and the focal multi-start do that before). Measured with and without this step:
docs/design-notes.md (Refinement on all keypoint matches).

Dense matchers (RoMa, XFeat*) give sub-pixel target positions and grid or coarse sites that do
not compose into exact keypoint tracks; their output is what the sampling exists to summarise, so
they skip this step (`keypoint_tracks` returns None).
"""
from __future__ import annotations

import logging
from typing import Optional, Sequence

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from ..config import SfMConfig
from ..types import SiteMatchSet, Tracks
from .incremental import final_adjustment, retriangulate_and_adjust
from .reconstruction import TRIANGULATION_MAX_ERROR_PX, SfMState, remove_outlier_observations

log = logging.getLogger(__name__)

# Tracks kept for the refinement (a seeded subsample beyond this): bounds the BA's time and
# memory when many frame sets are calibrated together (10 generated cameras: ~7500 per frame set).
MAX_TRACKS = 20000
# Raw matches are not cycle-verified, so the found cameras gate them even where the preset keeps
# every observation (B_err off) or allows much (fisheye B_err 100 px: room for the incremental
# stages' rough fisheye distortion, while these cameras are final). 20 px = the regular B_err.
# The fisheye gate left the same rig but raw-match outliers in its reported RMS
# (docs/design-notes.md, Refinement on all keypoint matches).
RAW_MATCH_MAX_GATE_PX = 20.0
GATE_REFINEMENTS = 3  # filter + BA rounds after the first BA (refine_on_tracks)


def keypoint_tracks(match_sets: Sequence[SiteMatchSet], num_cameras: int,
                    max_tracks: int = MAX_TRACKS, seed: int = 0) -> Optional[Tracks]:
    """All matches of every frame set as tracks (module docstring), at most max_tracks of them
    (seeded subsample). None when the matcher is not a keypoint matcher (sub-pixel targets)."""
    if any(m.target_xy_px is not None for ms in match_sets for m in ms.pairs.values()):
        return None
    parts = [_frame_set_tracks(ms, num_cameras, t) for t, ms in enumerate(match_sets)]
    return Tracks.concatenate(parts, num_cameras).sample(max_tracks, seed)


def _frame_set_tracks(match_set: SiteMatchSet, num_cameras: int, time_index: int) -> Tracks:
    offsets = np.concatenate([[0], np.cumsum([len(s) for s in match_set.sites])])
    src, dst = [], []
    for (i, j), m in match_set.pairs.items():
        if i > j and (j, i) in match_set.pairs:
            continue  # each unordered pair once, from its (i < j) map
        s = np.flatnonzero(m.target >= 0)
        t = m.target[s]
        back = match_set.pairs.get((j, i))
        if back is not None:  # mutual matches only (detector matchers: all of them)
            keep = back.target[t] == s
            s, t = s[keep], t[keep]
        src.append(s + offsets[i])
        dst.append(t + offsets[j])
    num_sites = int(offsets[-1])
    src = np.concatenate(src) if src else np.zeros(0, np.int64)
    dst = np.concatenate(dst) if dst else np.zeros(0, np.int64)
    graph = coo_matrix((np.ones(len(src)), (src, dst)), shape=(num_sites, num_sites))
    _, label = connected_components(graph, directed=False)
    camera = np.repeat(np.arange(num_cameras), np.diff(offsets))
    size = np.bincount(label)
    # Components with two keypoints in one camera are ambiguous: which is the scene point?
    per_camera = np.bincount(label * num_cameras + camera, minlength=len(size) * num_cameras)
    ok = (size >= 2) & (per_camera.reshape(-1, num_cameras).max(axis=1) == 1)
    new_index = np.full(len(size), -1)
    new_index[ok] = np.arange(int(ok.sum()))
    xy = np.full((int(ok.sum()), num_cameras, 2), np.nan)
    site_xy = np.concatenate(match_set.sites) if num_sites else np.zeros((0, 2))
    keep = ok[label]
    xy[new_index[label[keep]], camera[keep]] = site_xy[keep]
    n = len(xy)
    return Tracks(xy, np.full(n, 2, np.int32), np.zeros(n), np.full(n, time_index, np.int32))


def raw_match_gate_px(config: SfMConfig) -> float:
    """Reprojection gate (px) of the raw matches against the found cameras: the preset's B_err,
    or the triangulation gate where B_err is off, and never above RAW_MATCH_MAX_GATE_PX."""
    gate_px = config.b_err_px if config.b_err_px is not None else TRIANGULATION_MAX_ERROR_PX
    return min(gate_px, RAW_MATCH_MAX_GATE_PX)


def refine_on_tracks(state: SfMState, tracks: Tracks, camera_names: Sequence[str],
                     config: SfMConfig, seed: int = 0) -> SfMState:
    """A new state with `state`'s cameras refined on `tracks` (module docstring); `state` is
    left as it is. Unregistered cameras stay unregistered."""
    refined = state.on_tracks(tracks)
    gate_px = raw_match_gate_px(config)
    retriangulate_and_adjust(refined, camera_names, config, seed, outlier_px=gate_px)
    # A wrong 2-view match within the gate splits its error between its two views; the BA's
    # Cauchy loss then fits one view and leaves the other far off, above the gate
    # (docs/design-notes.md, Refinement on all keypoint matches). As COLMAP's global
    # refinement: filter against the adjusted cameras, adjust again.
    for _ in range(GATE_REFINEMENTS):
        if not remove_outlier_observations(refined, gate_px):
            break
        final_adjustment(refined, camera_names, config)
    log.debug("refined on %d match tracks: %d points", tracks.num_tracks,
              int(refined.point_mask().sum()))
    return refined
