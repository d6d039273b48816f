"""Frames lost on their way to the node, told from gaps in a camera's header stamps.

A driver publishing at a steady rate stamps its frames one period apart, so a frame the node never
received leaves a gap of a whole number of periods. Image topics are best-effort (sensor-data
QoS): the middleware drops frames silently, and nothing else tells the operator that ~/sync's
motion signals have holes or that frame sets form from fewer frames than the cameras take.
They are a lower bound (a camera losing every other frame looks like one at half the rate), so
the middleware's own count of lost messages is taken beside them where it reports one
(docs/ros.md, Lost frames).

A stream is judged only while it is steady (most intervals a whole number of periods): triggered
cameras (camera traps) and replays that jump back are not, and count nothing."""
from __future__ import annotations

from collections import deque
from typing import Optional

import numpy as np

RECENT_INTERVALS = 100  # the intervals that the period, steadiness and recent loss come from
MIN_INTERVALS = 10  # fewer: no period yet
# The period is found again after this many new intervals, not on every message (it costs tens
# of microseconds, inside the synchroniser's lock on the intake thread: docs/design-notes.md, Lost
# frames from the stamps).
PERIOD_REFRESH = 10
# The frame period is taken from the shortest intervals (this percentile, then the mean of those
# within tolerance of one period): right as long as a tenth of consecutive frames both arrive,
# where a median would take the gaps for the period once half the frames are lost.
PERIOD_PERCENTILE = 10
MULTIPLE_TOLERANCE = 0.25  # an interval within this many periods of a whole multiple fits the rate
STEADY_FRACTION = 0.9  # fewer of the recent intervals fitting: not steady, not judged
MAX_GAP_S = 1.0  # longer: the driver paused or stopped (sync.why_few_sets says so), not a loss
# Recent loss above this is worth the operator's attention (diagnostics WARN and a log line).
WARN_LOSS_FRACTION = 0.05
LOSS_HINT = (
    "frames are lost between the camera driver and this node (image topics are best-effort: "
    "lost frames are dropped silently). Unless told otherwise this node receives over UDP (its "
    "start-up line says with which receive buffer): for images of a few MB raise "
    "net.core.rmem_max to 32 MB, or "
    "start the camera drivers with FASTRTPS_DEFAULT_PROFILES_FILE pointing at this package's "
    "config/fastdds_large_images.xml, or have them publish compressed images (image_topics "
    "ending in /compressed); `densecalib bench-node` measures what arrives on this computer. "
    "Frame sets form only where every camera's frame arrived; ~/sync's motion signals get holes")


class StampGaps:
    """One stream's header stamps -> its frame period and the frames missing between them."""

    def __init__(self):
        self._last_ns: Optional[int] = None
        self._intervals_s: deque[float] = deque(maxlen=RECENT_INTERVALS)
        self._recent: deque[tuple[int, int]] = deque(maxlen=RECENT_INTERVALS)  # (lost, periods)
        self._gap_lost = 0  # frames missing since the node started (while the stream was steady)
        # the middleware's own count (a subscription's message-lost events: sequence numbers it
        # never delivered), exact where the stamps cannot tell (few frames arrive, or unsteady)
        self._reported_lost = 0
        self._reported_recent: deque[tuple[int, int]] = deque(maxlen=RECENT_INTERVALS)
        self._period_s: Optional[float] = None
        self._unrefreshed = 0  # intervals added since the period was found

    @property
    def lost(self) -> int:
        """Frames lost since the node started: the larger of the two counts, both lower bounds."""
        return max(self._gap_lost, self._reported_lost)

    def add_reported(self, total_lost: int) -> None:
        """The middleware's running count of this stream's lost messages."""
        change = int(total_lost) - self._reported_lost
        if change > 0:
            self._reported_lost = int(total_lost)
            self._reported_recent.append((change, change))

    def add(self, stamp_ns: int) -> None:
        self._reported_recent.append((0, 1))
        last, self._last_ns = self._last_ns, int(stamp_ns)
        if last is None:
            return
        dt_s = (self._last_ns - last) * 1e-9
        if dt_s <= 0.0:  # a replay starting again, sim time reset, a frame out of order
            self._intervals_s.clear()
            self._recent.clear()
            self._period_s, self._unrefreshed = None, 0
            return
        self._intervals_s.append(dt_s)
        self._unrefreshed += 1
        if self._unrefreshed >= PERIOD_REFRESH or len(self._intervals_s) == MIN_INTERVALS:
            self._period_s, self._unrefreshed = self._find_period_s(), 0
        period_s = self._period_s
        periods = 1
        if period_s is not None and dt_s <= MAX_GAP_S:
            k = round(dt_s / period_s)
            if k >= 2 and abs(dt_s - k * period_s) < MULTIPLE_TOLERANCE * period_s:
                periods = k
        self._gap_lost += periods - 1
        self._recent.append((periods - 1, periods))

    def period_s(self) -> Optional[float]:
        """The stream's frame period [s] (header stamps), or None while it is unknown or the
        stream is not steady."""
        return self._period_s

    def _find_period_s(self) -> Optional[float]:
        if len(self._intervals_s) < MIN_INTERVALS:
            return None
        intervals = np.asarray(self._intervals_s)
        guess = float(np.percentile(intervals, PERIOD_PERCENTILE))
        one = np.abs(intervals - guess) < MULTIPLE_TOLERANCE * guess
        if not one.any():
            return None
        period = float(intervals[one].mean())
        k = np.maximum(np.round(intervals / period), 1.0)
        fits = (np.abs(intervals - k * period) < MULTIPLE_TOLERANCE * period) | \
            (intervals > MAX_GAP_S)
        return period if fits.mean() >= STEADY_FRACTION else None

    def recent_loss(self) -> float:
        """The fraction of frames lost lately: over the recent intervals of the stamps (0 when
        not judged) or of the middleware's count, whichever is larger."""
        fractions = [sum(k for k, _ in recent) / max(sum(n for _, n in recent), 1)
                     for recent in (self._recent, self._reported_recent)]
        return max(fractions)
