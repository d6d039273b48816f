"""Thread-safe adapter from image messages to buffered frame sets (core.io.sync does the matching).

Subscription callbacks call `add` (cheap: no decoding, unless motion is tracked for measuring
stamp offsets); the calibration worker takes a `snapshot` and decodes it with
`decode_frame_sets`.
"""
from __future__ import annotations

import threading
import time
from typing import Callable, Optional

import numpy as np

from ..core.errors import InputError
from ..core.io.motion_sync import MotionEnergy, OffsetEstimate, stream_offsets
from ..core.io.sync import ApproximateTimeSynchronizer, FrameSet, FrameSetBuffer
from .conversions import image_msg_to_numpy, message_stamp_ns, motion_image
from .frame_loss import LOSS_HINT, StampGaps

BY_HAND = "set stamp_offsets_s by hand"
# A camera whose last image is this much older than another's has stopped publishing (a live
# camera at 1 Hz or faster is well within it).
_STOPPED_S = 5.0


class MessageSynchronizer:
    """Image messages of N streams -> approximate-time frame sets in a bounded buffer; with
    motion_window_s > 0, also each stream's motion over its latest motion_window_s seconds (by
    its own header stamps), from which `measure_offsets` finds the streams' stamp offsets."""

    def __init__(self, num_streams: int, slop_s: float, buffer_size: int,
                 min_interval_s: float = 0.0, queue_size: int = 10,
                 stamp_offsets_s: list[float] | None = None, motion_window_s: float = 0.0,
                 clock: Callable[[], float] = time.monotonic):
        """stamp_offsets_s[c]: how far stream c's stamping clock runs ahead of the others' (s),
        taken off its stamps before matching (the buffered sets carry the corrected stamps);
        clock: the arrival time of a message [s]."""
        self._clock = clock
        self._slop_s, self._queue_size = slop_s, queue_size
        self._offsets_ns = [int(round(o * 1e9)) for o in (stamp_offsets_s or [0.0] * num_streams)]
        self._lock = threading.Lock()
        self._sync = ApproximateTimeSynchronizer(num_streams, slop_s, queue_size)
        self._buffer = FrameSetBuffer(buffer_size, min_interval_s)
        self.received = [0] * num_streams
        # per stream, for telling why frame sets are missing: when its last message arrived
        # (monotonic s) and that message's stamp (offset taken off, ns)
        self._last_arrival_s: list[Optional[float]] = [None] * num_streams
        self._last_stamp_ns: list[Optional[int]] = [None] * num_streams
        self._gaps = [StampGaps() for _ in range(num_streams)]  # frames lost on the way
        # images that did not decode when a calibration or check took their set (per stream),
        # and the last reason
        self.malformed = [0] * num_streams
        self.last_malformed: list[Optional[str]] = [None] * num_streams
        self.motion_window_s = motion_window_s
        self._motion_lock = threading.Lock()
        self._motion = ([MotionEnergy(motion_window_s) for _ in range(num_streams)]
                        if motion_window_s > 0 else None)
        self._motion_t0_ns: Optional[int] = None  # the first stamp: float seconds stay exact

    def add(self, stream: int, msg, stamp_ns: int | None = None) -> int:
        """Add stream `stream`'s message (stamp from its header unless given); returns the number
        of frame sets it added to the buffer."""
        stamp = message_stamp_ns(msg) if stamp_ns is None else int(stamp_ns)
        if self._motion is not None:
            self._add_motion(stream, stamp, msg)
        t = stamp - self._offsets_ns[stream]
        with self._lock:
            self.received[stream] += 1
            self._last_arrival_s[stream], self._last_stamp_ns[stream] = self._clock(), t
            self._gaps[stream].add(stamp)
            return sum(self._buffer.push(s) for s in self._sync.add(stream, t, msg))

    def add_lost(self, stream: int, total_lost: int) -> None:
        """The middleware's running count of stream `stream`'s lost messages (a message-lost
        event of its subscription)."""
        with self._lock:
            self._gaps[stream].add_reported(total_lost)

    def _add_motion(self, stream: int, stamp_ns: int, msg) -> None:
        try:
            image = motion_image(msg)
        except InputError:
            return  # an undecodable image: the calibration reports it when it decodes the sets
        with self._motion_lock:
            if self._motion_t0_ns is None:
                self._motion_t0_ns = stamp_ns
            self._motion[stream].add((stamp_ns - self._motion_t0_ns) * 1e-9, image)

    def measure_offsets(self, names: list[str]) -> dict[str, OffsetEstimate]:
        """Each stream's stamp offset from the first's (core.io.motion_sync's convention, that of
        stamp_offsets_s) from the motion in its latest motion_window_s seconds; InputError when
        motion is not tracked or does not determine them."""
        if self._motion is None:
            raise InputError("Motion is not tracked: set sync_window_s > 0 (e.g. 60) when the "
                             "node starts, let something move in view of every camera, then "
                             f"call sync; or {BY_HAND}.")
        with self._motion_lock:
            signals = {name: m.signal() for name, m in zip(names, self._motion)}
        return stream_offsets(signals, self.motion_window_s, BY_HAND)

    def set_offsets(self, stamp_offsets_s: list[float]) -> int:
        """Match from now on with new stamp offsets. Sets already matched with the old ones, and
        messages still waiting for partners, are dropped: they may pair the wrong frames.
        Returns the number of buffered frame sets dropped."""
        with self._lock:
            self._offsets_ns = [int(round(o * 1e9)) for o in stamp_offsets_s]
            return self._clear()

    def clear(self) -> int:
        """Drop the buffered frame sets and the messages waiting for partners (the motion
        signals stay); returns the number of frame sets dropped."""
        with self._lock:
            return self._clear()

    def _clear(self) -> int:
        dropped = len(self._buffer)
        self._sync = ApproximateTimeSynchronizer(len(self._offsets_ns), self._slop_s,
                                                 self._queue_size)
        self._buffer = FrameSetBuffer(self._buffer.capacity, self._buffer.min_interval_s)
        return dropped

    def snapshot(self) -> list[FrameSet]:
        with self._lock:
            return self._buffer.snapshot()

    def decode(self, frame_sets: list[FrameSet]
               ) -> tuple[list[FrameSet], list[list[np.ndarray]], list[int]]:
        """The sets whose images all decode, their images[t][c] (uint8 RGB or gray), and per
        stream how many sets its images made this call drop. A set holding an image that does
        not decode is taken out of the buffer and counted against its stream (`malformed`), so
        that one bad frame does not fail every later calibration.
        Decoding happens here, when a set is used, rather than on arrival: the subscription
        callbacks stay cheap at full frame rate, and only the few buffered sets are decoded."""
        kept, images, dropped = [], [], [0] * len(self.malformed)
        for frame_set in frame_sets:
            try:
                images.append(self._decode_set(frame_set))
            except _MalformedImage as bad:
                dropped[bad.stream] += 1
                with self._lock:
                    self._buffer.discard(frame_set)
                    self.malformed[bad.stream] += 1
                    self.last_malformed[bad.stream] = bad.reason
                continue
            kept.append(frame_set)
        return kept, images, dropped

    @staticmethod
    def _decode_set(frame_set: FrameSet) -> list[np.ndarray]:
        out = []
        for stream, msg in enumerate(frame_set.items):
            try:
                out.append(image_msg_to_numpy(msg))
            except InputError as e:
                raise _MalformedImage(stream, str(e)) from e
        return out

    def __len__(self) -> int:
        with self._lock:
            return len(self._buffer)

    def why_few_sets(self, names: list[str], topics: list[str]) -> str:
        """What keeps frame sets from forming, in the operator's terms: a camera that published
        nothing or stopped publishing, or latest stamps further apart than the slop."""
        with self._lock:
            arrivals, stamps = list(self._last_arrival_s), list(self._last_stamp_ns)
            received = list(self.received)
            lost = [g.lost for g in self._gaps]
        reason = self._why_few_sets(names, topics, arrivals, stamps, received)
        if any(lost):  # sets need a frame from every camera: scattered losses leave few whole
            reason += ("; and frames were lost on the way (at least " + ", ".join(
                f"{n} {k}" for n, k in zip(names, lost) if k) + ", from gaps in the header "
                f"stamps): {LOSS_HINT}")
        return reason

    def _why_few_sets(self, names, topics, arrivals, stamps, received) -> str:
        counts = ", ".join(f"{n} {k}" for n, k in zip(names, received))
        silent = [f"{n} ({t})" for n, t, a in zip(names, topics, arrivals) if a is None]
        if silent:
            return (f"no image received from {', '.join(silent)}: check that the driver publishes "
                    f"on that topic and the topic in image_topics (messages per camera: {counts})")
        newest = max(arrivals)
        stopped = [f"{n} ({t}) {newest - a:.0f} s ago" for n, t, a in zip(names, topics, arrivals)
                   if newest - a > _STOPPED_S]
        if stopped:
            return (f"camera(s) stopped publishing while others go on: last image from "
                    f"{', '.join(stopped)}; check the driver (messages per camera: {counts})")
        spread_s = (max(stamps) - min(stamps)) * 1e-9
        if spread_s > self._slop_s:
            ahead = ", ".join(f"{n} {(t - min(stamps)) * 1e-9:+.3f}" for n, t in zip(names, stamps))
            return (f"the cameras' latest header stamps are {spread_s:.3f} s apart, more than "
                    f"slop_s {self._slop_s} (s after the earliest: {ahead}): if their clocks "
                    "disagree, set stamp_offsets_s or measure them with ~/sync and "
                    f"sync_window_s > 0 (messages per camera: {counts})")
        return (f"every camera publishes (messages per camera: {counts}, slop {self._slop_s} "
                "s): wait for more frame sets (min_interval_s spaces them), or if they do not "
                "come, check that the cameras stamp their images with close header stamps")

    def stats(self) -> dict:
        with self._lock:
            return {"buffered": len(self._buffer), "received": list(self.received),
                    "matched": self._sync.stats.matched,
                    "dropped_unmatched": self._sync.stats.dropped_unmatched,
                    "dropped_overflow": self._sync.stats.dropped_overflow,
                    "pending": self._sync.pending(),
                    "dropped_oldest": self._buffer.dropped_oldest,
                    "skipped_interval": self._buffer.skipped_interval,
                    "lost": [g.lost for g in self._gaps],
                    "malformed": list(self.malformed),
                    "recent_loss": [g.recent_loss() for g in self._gaps],
                    "period_s": [g.period_s() for g in self._gaps]}


class _MalformedImage(Exception):
    def __init__(self, stream: int, reason: str):
        super().__init__(reason)
        self.stream, self.reason = stream, reason


def malformed_note(names: list[str], dropped: list[int], reasons: list[Optional[str]]) -> str:
    """'' when no set was dropped (decode's per-stream counts), else which cameras sent frames
    that do not decode, how many, the last reason and what to do."""
    bad = [f"{n} {k} ({r})" for n, k, r in zip(names, dropped, reasons) if k]
    if not bad:
        return ""
    return ("frame sets dropped: images that do not decode from " + "; ".join(bad)
            + ": check that camera's driver (encoding, compression format)")


def offsets_line(names: list[str], offsets_s: list[float],
                 correlations: Optional[list[Optional[float]]] = None) -> str:
    """The cameras' stamp offsets in one line, each with the correlation it was measured with
    where given (None for the reference camera)."""
    correlations = correlations or [None] * len(names)
    return "stamp offsets [s]: " + ", ".join(
        f"{n} {o:+.4f}" + (f" (correlation {c:.2f})" if c is not None else "")
        for n, o, c in zip(names, offsets_s, correlations))
