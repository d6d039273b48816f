"""Thread-safe adapter from image messages to buffered frame sets (core.sync does the matching).

Subscription callbacks call `add` (cheap: no decoding); the calibration worker takes a `snapshot`
and decodes it with `decode_frame_sets`.
"""
from __future__ import annotations

import threading

import numpy as np

from ..core.sync import ApproximateTimeSynchronizer, FrameSet, FrameSetBuffer
from .conversions import image_msg_to_numpy, message_stamp_ns


class MessageSynchronizer:
    """Image messages of N streams -> approximate-time frame sets in a bounded buffer."""

    def __init__(self, num_streams: int, slop_s: float, buffer_size: int,
                 min_interval_s: float = 0.0, queue_size: int = 10,
                 stamp_offsets_s: list[float] | None = None):
        """stamp_offsets_s[c]: how far stream c's stamping clock runs ahead of the others' (s),
        taken off its stamps before matching (the buffered sets carry the corrected stamps)."""
        self._offsets_ns = [int(round(o * 1e9)) for o in (stamp_offsets_s or [0.0] * num_streams)]
        self._lock = threading.Lock()
        self._sync = ApproximateTimeSynchronizer(num_streams, slop_s, queue_size)
        self._buffer = FrameSetBuffer(buffer_size, min_interval_s)
        self.received = [0] * num_streams

    def add(self, stream: int, msg, stamp_ns: int | None = None) -> int:
        """Add stream `stream`'s message (stamp from its header unless given); returns the number
        of frame sets it added to the buffer."""
        t = (message_stamp_ns(msg) if stamp_ns is None else int(stamp_ns)) \
            - self._offsets_ns[stream]
        with self._lock:
            self.received[stream] += 1
            return sum(self._buffer.push(s) for s in self._sync.add(stream, t, msg))

    def snapshot(self) -> list[FrameSet]:
        with self._lock:
            return self._buffer.snapshot()

    def __len__(self) -> int:
        with self._lock:
            return len(self._buffer)

    def stats(self) -> dict:
        with self._lock:
            return {"buffered": len(self._buffer), "received": list(self.received),
                    "matched": self._sync.stats.matched,
                    "dropped_unmatched": self._sync.stats.dropped_unmatched,
                    "dropped_overflow": self._sync.stats.dropped_overflow,
                    "pending": self._sync.pending(),
                    "dropped_oldest": self._buffer.dropped_oldest,
                    "skipped_interval": self._buffer.skipped_interval}


def decode_frame_sets(frame_sets: list[FrameSet]) -> list[list[np.ndarray]]:
    """Buffered message sets -> images[t][c], uint8 RGB (H, W, 3) or gray (H, W)."""
    return [[image_msg_to_numpy(m) for m in s.items] for s in frame_sets]
