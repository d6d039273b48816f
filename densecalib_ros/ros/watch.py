"""The node's watch: with check_interval_s > 0 its calibration is checked on the frame sets that
arrived since the last check; with recalibrate_on_change it recalibrates once a change is
confirmed."""
from __future__ import annotations

import math
import time
from typing import Optional

from ..core.io.sync import FrameSet
from .settings import Settings

# The watch recalibrates on a change seen in at least this many frame sets: a frame set alone can
# be odd (few matches, something that moved between the shots of unsynchronised cameras), and is
# not worth replacing a good calibration.
WATCH_CONFIRM_SETS = 2


class Watch:
    """Which frame sets the watch checks next."""

    def __init__(self):
        # the newest frame set a check has seen (by identity: stamps may jump back when a bag is
        # replayed again or sim time restarts; the buffer only appends and drops)
        self._last_seen: Optional[FrameSet] = None
        self._last_at = -math.inf  # time.monotonic() of the last check

    def sets_to_check(self, s: Settings, buffered: list[FrameSet]) -> Optional[list[FrameSet]]:
        """The frame sets of `buffered` to check now, or None: the watch is off, it is not time
        yet, or nothing is new (the verdict would be the last one). The new frame sets only
        (matching is the cost), and the one before them: when it fits and they do not, the
        check says the change came in between."""
        if s.check_interval_s <= 0 or time.monotonic() - self._last_at < s.check_interval_s:
            return None
        first_new = next((i + 1 for i, fs in enumerate(buffered) if fs is self._last_seen), 0)
        if first_new >= len(buffered):
            return None
        return buffered[max(first_new - 1, 0):]

    def checked(self, sets: list[FrameSet]) -> None:
        """The check of `sets` (what sets_to_check gave) was made."""
        self._last_at, self._last_seen = time.monotonic(), sets[-1]
