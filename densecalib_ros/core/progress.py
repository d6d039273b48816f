"""How a calibration is watched and stopped: one Progress object goes down the stages.

Each event is said once, by `Progress.say`, which logs it (INFO, under the stage's logger) and
passes it to the front end's message callback: the commands show the log (`-v`, or output
piped) or one updating line per stage, the node its ~/status topic and its action's feedback.

Beside the messages, the stages report where they are (`begin` a stage, `advance` within it):
the fraction of the whole run done and the seconds left, which `state()` gives any thread at
any time (the node's feedback timer, the terminal line's clock). The run's stages and their
shares of its time are planned first (`plan`); a second matcher adds its own (`extend`).

A StopToken set from another thread (a ROS cancel, Ctrl-C) stops the calibration at its next
check: `advance` and `check` raise CalibrationCancelled, between stages, consensus runs,
multi-start trials and matched image pairs. A cancelled calibration writes nothing.
"""
from __future__ import annotations

import contextlib
import contextvars
import logging
import threading
import time
from dataclasses import dataclass
from typing import Callable, Iterator, Optional, Sequence, Union

from .errors import CalibrationCancelled

# The stages of a calibration and their shares of its time, from the stage tables of the bench
# (docs/benchmarks.md): on Strecha's ten views and an 8-camera generated rig, matching took
# 0.16-0.21 of the time, sampling, the SfM runs and their refinement on the keypoint matches
# 0.55, the image refinement 0.24-0.29. Shares only set how the fraction done moves; the seconds
# left come from the time the run has taken so far.
STAGE_SHARES = {"match": 0.20, "calibrate": 0.55, "refine": 0.25}
# A stage begun that no plan named (a front end's own) counts this much of a planned run.
UNPLANNED_SHARE = 0.02
# Before the first step of a run is done, its length is estimated from the matching it has to
# do: this many seconds per image pair and megapixel (SIFT at up to 1024 px on one core of the
# 2-core development machine, detection included), scaled by the matching's share.
MATCH_S_PER_PAIR_MPIX = 0.5
# Fractions below this say too little about the whole run to extrapolate its time from.
MIN_FRACTION_FOR_ESTIMATE = 0.01

Listener = Callable[[str], None]


class StopToken:
    """Set from any thread (a ROS cancel, a signal handler); the calibration checks it between
    its steps (Progress.check) and stops with CalibrationCancelled."""

    def __init__(self) -> None:
        self._event = threading.Event()
        self.reason = "cancelled"

    def stop(self, reason: str = "cancelled") -> None:
        self.reason = reason
        self._event.set()

    @property
    def stopped(self) -> bool:
        return self._event.is_set()

    def check(self) -> None:
        if self._event.is_set():
            raise CalibrationCancelled(self.reason)


@dataclass(frozen=True)
class ProgressState:
    """Where a calibration is: its stage, the steps of the stage (0 of 0 where it has none to
    count), the fraction of the whole run done and the seconds left (None until estimable)."""

    stage: str
    label: str
    stage_done: int
    stage_total: int
    stage_fraction: float  # of the stage's steps, the next one's part done included
    fraction: float
    seconds_left: Optional[float]
    elapsed_s: float


class Progress:
    """The channel a calibration reports through and is stopped through (module docstring).

    on_message(text): each event said (say), once; on_stage(state): each stage begun and each
    step (advance): what a front end draws. Both are called in the calibrating thread."""

    def __init__(self, on_message: Optional[Listener] = None,
                 on_stage: Optional[Callable[[ProgressState], None]] = None,
                 stop: Optional[StopToken] = None) -> None:
        self.on_message = on_message
        self._run = _RunState(stop or StopToken(), on_stage)

    @classmethod
    def of(cls, progress: Union["Progress", Listener, None]) -> "Progress":
        """A Progress from what a caller gave: itself, a message callback, or None (silent)."""
        if isinstance(progress, Progress):
            return progress
        return cls(on_message=progress)

    @property
    def stop(self) -> StopToken:
        return self._run.stop

    def muted(self) -> "Progress":
        """This progress for work whose messages only the log needs (a consensus run after the
        first repeats its lines): its stages, steps and stop are this one's."""
        muted = Progress()
        muted._run = self._run
        return muted

    def say(self, msg: str, logger: Optional[logging.Logger] = None) -> None:
        """Log `msg` (INFO) and pass it to on_message: an event, said once."""
        (logger or logging.getLogger(__name__)).info(msg)
        if self.on_message is not None:
            self.on_message(msg)

    def check(self) -> None:
        """CalibrationCancelled where the stop token was set."""
        self._run.stop.check()

    def plan(self, stages: Sequence[str], prior_s: Optional[float] = None) -> None:
        """The run's stages (keys of STAGE_SHARES, in order); prior_s: the run's length as
        estimated before any step is done (estimated_run_s), used until steps tell better."""
        self._run.plan(stages, prior_s)

    def extend(self, stages: Sequence[str]) -> None:
        """Stages added to the run once it is under way (the second matcher's matching and
        calibration): the fraction done falls to what it is of the longer run."""
        self._run.extend(stages)

    def begin(self, stage: str, label: str, total: int = 0, waits_s: Optional[float] = None
              ) -> None:
        """Enter `stage` (ending the one before) with `total` steps to count; checks the stop.
        waits_s: seconds the stage will wait, beyond what its share plans, for work run ahead
        that is not yet done: its share grows by what the run does in that time at the pace it
        has kept so far (a share is a guess from other rigs; these seconds are this run's)."""
        self.check()
        self._run.begin(stage, label, total, waits_s)

    def advance(self, done: int, total: Optional[int] = None, label: Optional[str] = None,
                left_s: Optional[float] = None) -> None:
        """`done` steps of the stage are done (of `total`, where it changed); checks the stop.
        left_s: the stage's own measure of its seconds left (StageClock.seconds_left): its
        share becomes its seconds, taken and left, at the pace the stages before it kept (a
        share is a guess from other rigs; a stage that times its steps knows better: the second
        matcher's matching takes several times the first's)."""
        self.check()
        self._run.advance(done, total, label, left_s)

    def waited(self, fraction: float) -> None:
        """`fraction` (0-1) of the wait begin's waits_s announced is over; checks the stop."""
        self.check()
        self._run.waited(fraction)

    def substep(self, fraction: float) -> None:
        """`fraction` (0-1) of the stage's next step is done (a frame set's image pairs, a
        run's trials); checks the stop."""
        self.check()
        self._run.substep(fraction)

    def finish(self) -> None:
        """The run is done: every stage ended, the fraction done 1."""
        self._run.finish()

    def state(self) -> ProgressState:
        """Where the run is now (any thread)."""
        return self._run.state()


class _RunState:
    """The run's stages and steps behind a Progress and its muted views, under one lock."""

    def __init__(self, stop: StopToken, on_stage: Optional[Callable[[ProgressState], None]]):
        self.stop, self._on_stage = stop, on_stage
        self._lock = threading.Lock()
        self._start = time.perf_counter()
        self._shares: dict[str, float] = {}  # stage key -> share; a repeated stage's key has "+"
        self._ended: set[str] = set()
        self._done_share = 0.0  # shares of the stages ended
        self._stage, self._label = "start", "starting"
        self._done, self._total, self._sub = 0, 0, 0.0
        self._prior_s: Optional[float] = None
        self._wait_share, self._waited = 0.0, 0.0  # the stage's share for its wait, part over
        self._pace: Optional[float] = None  # share per second of the stages before this one
        self._stage_start = 0.0  # seconds into the run when this stage began
        # the stage's part done by its own seconds taken and left (advance's left_s), or None
        self._timed_fraction: Optional[float] = None

    def plan(self, stages: Sequence[str], prior_s: Optional[float]) -> None:
        with self._lock:
            self._shares = {}
            self._add(stages)
            self._prior_s = prior_s

    def extend(self, stages: Sequence[str]) -> None:
        with self._lock:
            self._add(stages)

    def begin(self, stage: str, label: str, total: int, waits_s: Optional[float] = None
              ) -> None:
        with self._lock:
            self._end_stage()
            key = next((k for k in self._shares if k.rstrip("+") == stage and
                        k not in self._ended), None)
            if key is None:
                key = self._add([stage], UNPLANNED_SHARE)[0]
            elapsed = time.perf_counter() - self._start
            self._wait_share, self._waited = 0.0, 0.0
            # the pace of the stages done: share per second
            self._pace = self._done_share / elapsed if self._done_share > 0 and elapsed > 0 \
                else None
            self._stage_start = elapsed
            if waits_s and self._pace is not None:
                self._wait_share = waits_s * self._pace
                self._shares[key] += self._wait_share
            self._stage, self._label = key, label
            self._done, self._total, self._sub = 0, total, 0.0
            self._timed_fraction = None
        self._tell()

    def advance(self, done: int, total: Optional[int], label: Optional[str],
                left_s: Optional[float] = None) -> None:
        with self._lock:
            self._done, self._sub = done, 0.0
            if total is not None:
                self._total = total
            if label is not None:
                self._label = label
            if left_s is not None and self._pace is not None and self._stage in self._shares:
                taken_s = time.perf_counter() - self._start - self._stage_start
                self._shares[self._stage] = self._wait_share + (taken_s + left_s) * self._pace
                # its part done by its seconds too: its steps need not take alike
                self._timed_fraction = taken_s / max(taken_s + left_s, 1e-9)
            if self._timed_fraction is not None and 0 < self._total <= done:
                self._timed_fraction = 1.0
        self._tell()

    def waited(self, fraction: float) -> None:
        with self._lock:
            self._waited = min(max(float(fraction), self._waited), 1.0)

    def substep(self, fraction: float) -> None:
        with self._lock:
            self._sub = min(max(float(fraction), 0.0), 1.0)

    def finish(self) -> None:
        with self._lock:
            self._end_stage()
            self._done_share = sum(self._shares.values())
            self._stage, self._label, self._done, self._total = "done", "done", 0, 0
        self._tell()

    def _end_stage(self) -> None:
        if self._stage in self._shares and self._stage not in self._ended:
            self._ended.add(self._stage)
            self._done_share += self._shares[self._stage]

    def state(self) -> ProgressState:
        with self._lock:
            elapsed = time.perf_counter() - self._start
            fraction = self._fraction()
            if fraction >= MIN_FRACTION_FOR_ESTIMATE:
                left = elapsed * (1.0 - fraction) / fraction
            elif self._prior_s is not None:
                left = max(self._prior_s - elapsed, 0.0)
            else:
                left = None
            stage_fraction = min((self._done + self._sub) / self._total, 1.0) \
                if self._total > 0 else 0.0
            return ProgressState(self._stage.rstrip("+"), self._label, self._done, self._total,
                                 stage_fraction, fraction, left, elapsed)

    def _add(self, stages: Sequence[str], share: Optional[float] = None) -> list[str]:
        keys = []
        for stage in stages:
            key = stage
            while key in self._shares:
                key += "+"
            self._shares[key] = share if share is not None else \
                STAGE_SHARES.get(stage, UNPLANNED_SHARE)
            keys.append(key)
        return keys

    def _fraction(self) -> float:
        total = sum(self._shares.values())
        if total <= 0:
            return 1.0 if self._stage == "done" else 0.0
        current = 0.0
        if self._stage in self._shares and self._stage not in self._ended:
            current = self._wait_share * self._waited
            if self._timed_fraction is not None:
                current += (self._shares[self._stage] - self._wait_share) * self._timed_fraction
            elif self._total > 0:
                current += (self._shares[self._stage] - self._wait_share) * \
                    min((self._done + self._sub) / self._total, 1.0)
        return min((self._done_share + current) / total, 1.0)

    def _tell(self) -> None:
        if self._on_stage is not None:
            self._on_stage(self.state())


# The stop token of the calibration running in this context (stoppable): what the loops deep
# inside a stage check (check_stop) without being handed its Progress. parallel.map_threads runs
# its items in the caller's context, so they see it too; work run ahead on its own threads does
# not (it is cancelled by its owner).
_running: contextvars.ContextVar[Optional[StopToken]] = contextvars.ContextVar(
    "densecalib_stop", default=None)


@contextlib.contextmanager
def stoppable(progress: Progress) -> Iterator[Progress]:
    """The block in which progress's stop token is the one check_stop checks."""
    reset = _running.set(progress.stop)
    try:
        yield progress
    finally:
        _running.reset(reset)


def check_stop() -> None:
    """CalibrationCancelled where the calibration running in this context was stopped; nothing
    outside one. For loops inside a stage (an adjustment's iterations, the dense alignments)."""
    token = _running.get()
    if token is not None:
        token.check()


def estimated_run_s(image_sizes: Sequence[tuple[int, int]], num_frame_sets: int,
                    max_image_side_px: int) -> float:
    """A run's length before any of it is done: its matching (MATCH_S_PER_PAIR_MPIX per image
    pair and megapixel matched) over the matching's share of a run."""
    C = len(image_sizes)
    mpix = 0.0
    for w, h in image_sizes:
        scale = min(1.0, max_image_side_px / max(w, h)) if max_image_side_px else 1.0
        mpix += w * h * scale * scale / 1e6
    pairs = C * (C - 1) / 2
    match_s = num_frame_sets * pairs * MATCH_S_PER_PAIR_MPIX * (mpix / max(C, 1))
    return match_s / STAGE_SHARES["match"]


class StageClock:
    """The time left of a stage of `total` steps that take alike (frame sets, SfM trials): the
    mean time of the steps done so far times the steps left, counted from the clock's start.
    first_apart: the first step is unlike the rest (a frame set matched whole before the others'
    new content only, several times their time), so the mean is of the steps after it, and
    nothing is said after the first alone."""

    def __init__(self, total: int, first_apart: bool = False):
        self.total = total
        self._start = time.perf_counter()
        self._said = self._start
        self._first_apart = first_apart
        self._first_done: Optional[float] = None

    def seconds_left(self, done: int) -> Optional[float]:
        """The stage's seconds left after `done` steps; None before the first and after the last
        (and after the first alone where it is apart)."""
        now = time.perf_counter()
        if self._first_apart and done == 1 and self._first_done is None:
            self._first_done = now
        if done <= 0 or done >= self.total:
            return None
        start, counted = self._start, done
        if self._first_apart:
            if done < 2 or self._first_done is None:
                return None
            start, counted = self._first_done, done - 1
        self._said = now
        return (now - start) / counted * (self.total - done)

    def left(self, done: int) -> str:
        """", about N s left" after `done` steps (seconds_left); "" where it is None."""
        return self.said(self.seconds_left(done))

    @staticmethod
    def said(left_s: Optional[float]) -> str:
        """", about N s left", or "" for None."""
        return "" if left_s is None else f", about {left_s:.0f} s left"

    def due(self, every_s: float) -> bool:
        """Whether `every_s` seconds went by since the clock last said its time left (or
        started): for stages whose steps are too many to say each."""
        return time.perf_counter() - self._said >= every_s
