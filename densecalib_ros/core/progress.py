"""One progress channel for the calibration's stages: each event is said once, by `say_progress`,
which logs it (INFO, under the stage's logger) and passes it to the caller's callback. Front ends
show one of the two: the commands the log, the node its ~/status topic (the log reaches /rosout
through ros.core_logs). A stage of many like steps (frame sets matched, SfM trials) says its
estimated time left with them (StageClock)."""
from __future__ import annotations

import logging
import time
from typing import Callable, Optional

Progress = Optional[Callable[[str], None]]


def say_progress(progress: Progress, msg: str, logger: Optional[logging.Logger] = None) -> None:
    (logger or logging.getLogger(__name__)).info(msg)
    if progress is not None:
        progress(msg)


class StageClock:
    """The time left of a stage of `total` steps that take alike (frame sets, SfM trials): the
    mean time of the steps done so far times the steps left, counted from the clock's start."""

    def __init__(self, total: int):
        self.total = total
        self._start = time.perf_counter()
        self._said = self._start

    def left(self, done: int) -> str:
        """", about N s left" after `done` steps; "" before the first and after the last."""
        if done <= 0 or done >= self.total:
            return ""
        now = time.perf_counter()
        self._said = now
        return f", about {(now - self._start) / done * (self.total - done):.0f} s left"

    def due(self, every_s: float) -> bool:
        """Whether `every_s` seconds went by since the clock last said its time left (or
        started): for stages whose steps are too many to say each."""
        return time.perf_counter() - self._said >= every_s
