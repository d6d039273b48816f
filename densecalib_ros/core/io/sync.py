"""Approximate-time synchronisation of N streams by header stamps (ROS-free; shared by the bag
reader and the ROS node).

Each stream keeps a small queue sorted by stamp. Whenever every stream has a pending item, the
queue heads are compared: if their stamps span at most `slop_s`, they form a frame set and are
consumed; otherwise the earliest head can no longer be matched (every other stream's pending items
are later by more than the slop) and is dropped. Arrival order within a stream may be slightly
out of order (items are inserted sorted). Deterministic: the same arrival sequence gives the same
frame sets.
"""
from __future__ import annotations

import bisect
import logging
from dataclasses import dataclass, field
from typing import Any, Optional

import numpy as np

from ..errors import InputError

log = logging.getLogger(__name__)


@dataclass
class FrameSet:
    """One synchronised set: `items[c]` is stream c's payload; `stamps_ns[c]` its header stamp."""

    stamps_ns: list[int]
    items: list[Any]

    @property
    def stamp_ns(self) -> int:
        """The set's stamp: the latest of its members' stamps."""
        return max(self.stamps_ns)


@dataclass
class SyncStats:
    matched: int = 0
    dropped_unmatched: int = 0  # items that found no partner within the slop
    dropped_overflow: int = 0  # items pushed out of a full stream queue


@dataclass
class ApproximateTimeSynchronizer:
    """Groups items of `num_streams` streams whose stamps lie within `slop_s` of each other."""

    num_streams: int
    slop_s: float
    queue_size: int = 10  # pending items per stream; the oldest is dropped when full
    stats: SyncStats = field(default_factory=SyncStats)

    def __post_init__(self):
        if self.num_streams < 1:
            raise InputError(f"Synchronisation needs at least one stream, got {self.num_streams}.")
        if not self.slop_s >= 0.0:
            raise InputError(f"slop_s must be >= 0 seconds, got {self.slop_s}.")
        if self.queue_size < 1:
            raise InputError(f"queue_size must be >= 1, got {self.queue_size}.")
        self._slop_ns = int(round(self.slop_s * 1e9))
        self._stamps: list[list[int]] = [[] for _ in range(self.num_streams)]
        self._items: list[list[Any]] = [[] for _ in range(self.num_streams)]

    def add(self, stream: int, stamp_ns: int, item: Any) -> list[FrameSet]:
        """Add stream `stream`'s item stamped `stamp_ns`; returns the frame sets it completed."""
        if not 0 <= stream < self.num_streams:
            raise InputError(f"Stream index {stream} out of range 0..{self.num_streams - 1}.")
        stamps, items = self._stamps[stream], self._items[stream]
        pos = bisect.bisect_right(stamps, stamp_ns)
        stamps.insert(pos, int(stamp_ns))
        items.insert(pos, item)
        if len(stamps) > self.queue_size:
            del stamps[0], items[0]
            self.stats.dropped_overflow += 1
        out = []
        while all(self._stamps):
            heads = [s[0] for s in self._stamps]
            if max(heads) - min(heads) <= self._slop_ns:
                out.append(FrameSet(heads, [q.pop(0) for q in self._items]))
                for s in self._stamps:
                    s.pop(0)
                self.stats.matched += 1
            else:
                oldest = heads.index(min(heads))
                del self._stamps[oldest][0], self._items[oldest][0]
                self.stats.dropped_unmatched += 1
        return out

    def pending(self) -> list[int]:
        """Number of pending (not yet matched) items per stream."""
        return [len(s) for s in self._stamps]


@dataclass
class FrameSetBuffer:
    """A bounded buffer of frame sets: when full, the oldest set is dropped. A set stamped less
    than `min_interval_s` after the last accepted one is skipped (a 30 Hz stream would otherwise
    fill the buffer with near-identical views)."""

    capacity: int
    min_interval_s: float = 0.0
    dropped_oldest: int = 0
    skipped_interval: int = 0

    def __post_init__(self):
        if self.capacity < 1:
            raise InputError(f"Buffer capacity must be >= 1, got {self.capacity}.")
        self._sets: list[FrameSet] = []
        self._last_ns: int | None = None

    def push(self, frame_set: FrameSet) -> bool:
        """Buffer `frame_set`; False when it was skipped for the minimum interval."""
        t = frame_set.stamp_ns
        if self._last_ns is not None and abs(t - self._last_ns) < self.min_interval_s * 1e9:
            self.skipped_interval += 1
            return False
        self._last_ns = t
        self._sets.append(frame_set)
        if len(self._sets) > self.capacity:
            del self._sets[0]
            self.dropped_oldest += 1
        return True

    def snapshot(self) -> list[FrameSet]:
        return list(self._sets)

    def discard(self, frame_set: FrameSet) -> None:
        """Take `frame_set` out (by identity) if it is still buffered."""
        self._sets = [s for s in self._sets if s is not frame_set]

    def __len__(self) -> int:
        return len(self._sets)


# Frame sets a calibration reads from an image folder or a bag unless told otherwise: past a few
# tens, sets add matching time and memory (every image is held decoded) more than information,
# and a long bag or trail-camera folder would otherwise be read whole.
DEFAULT_MAX_FRAME_SETS = 20


def evenly_spaced(items: list, max_count: Optional[int], what: str = "frame sets") -> list:
    """At most max_count items evenly spaced over `items` (first and last kept); None = all.
    Logs when it leaves some out."""
    if max_count is None or len(items) <= max_count:
        return list(items)
    if max_count < 1:
        raise InputError(f"The number of {what} to use must be at least 1, got {max_count}.")
    keep = np.unique(np.round(np.linspace(0, len(items) - 1, max_count)).astype(int))
    log.info("Using %d of %d %s, evenly spaced (--max-frame-sets, or the node's max_frame_sets, "
             "to change).", len(keep), len(items), what)
    return [items[i] for i in keep]
