"""Which frame sets, and which parts of them, the dense correspondences (dense_matches) come
from.

Of a static scene filmed over many frame sets, more sets repeat the same geometry, so a few are
densified whole. What moves through the rig's view (a person, an animal, a board carried
around) stands elsewhere in every set and is seen by several cameras at the same instant: each
other frame set is densified where it shows what no earlier set of the camera showed
(new_content), which is what carries the intrinsics of a few cameras far apart in a plain room
(docs/design-notes.md, Dense correspondences, What moves through later frame sets)."""
from __future__ import annotations

from typing import Iterator, Optional, Sequence

import numpy as np

from ..types import Tracks
from .new_content import new_content_regions

# Frame sets densified whole (evenly spaced); more repeat the static rig's geometry. The others
# are densified on what they show new (later_frame_sets), at most this many images' worth.
MAX_FRAME_SETS = 4


def densified_times(keypoint_tracks: Tracks) -> np.ndarray:
    """The frame sets dense_tracks densifies whole: at most MAX_FRAME_SETS, evenly spaced."""
    times = np.unique(keypoint_tracks.time_index)
    if len(times) > MAX_FRAME_SETS:
        times = times[np.round(np.linspace(0, len(times) - 1, MAX_FRAME_SETS)).astype(int)]
    return times


def later_frame_sets(frame_sets: Sequence[Sequence[np.ndarray]], keypoint_tracks: Tracks
                     ) -> dict[int, float]:
    """The frame sets with keypoint matches, other than densified_times', that dense_tracks
    densifies where they show what no earlier frame set of the camera showed
    (new_content.new_content_regions), each with its share of the images (of each image, averaged
    over the cameras): what moved through the rig's view (a person, an animal, a board) adds
    correspondences there, where the static scene only repeats itself. At most MAX_FRAME_SETS
    whole images' worth, evenly spaced where more, so the dense stage takes at most twice as
    long."""
    whole = set(int(t) for t in densified_times(keypoint_tracks))
    matched = set(int(t) for t in np.unique(keypoint_tracks.time_index))
    shares = {}
    for t, regions in enumerate(new_content_regions(frame_sets)):
        if t in matched and t not in whole and regions is not None:
            share = float(np.mean([1.0 if r is None else r.mean() for r in regions]))
            if share > 0.0:
                shares[t] = share
    later = sorted(shares)
    total = sum(shares.values())
    if total > MAX_FRAME_SETS:
        keep = max(int(len(later) * MAX_FRAME_SETS / total), 1)
        later = [later[i] for i in np.unique(np.round(np.linspace(0, len(later) - 1, keep))
                                             .astype(int))]
    return {t: shares[t] for t in later}


def densified_frame_sets(frame_sets: Sequence[Sequence[np.ndarray]], keypoint_tracks: Tracks,
                         later: dict) -> Iterator[tuple[int, Optional[list]]]:
    """(frame set, None: densified whole, or per camera the bool (H, W) region of what is new in
    it) for densified_times' frame sets and `later`'s (later_frame_sets), in time order. The
    regions are found again here, one frame set at a time, rather than kept by later_frame_sets:
    full-size masks of every later frame set would be held at once (0.17 s for 20 frame sets of
    four 1280x720 cameras)."""
    whole = set(int(t) for t in densified_times(keypoint_tracks))
    for t, regions in enumerate(new_content_regions(frame_sets)):
        if t in whole:
            yield t, None
        elif t in later:
            yield t, regions
