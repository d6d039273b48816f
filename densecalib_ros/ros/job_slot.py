"""The node's one job slot, the stop of a calibration, and the shutdown hand-over.

A calibration (in a worker thread), a check and a reload hold the slot in turn, so that no
calibration publishes over a reload or swaps the matcher under a check. A calibration carries its
core Progress: what it reports (read by the action's feedback) and its stop token. cancel() (a
cancelled goal, ~/cancel) sets that token: the core stops at its next check, and the calibration
writes nothing. At shutdown (stop()) the token is set too, a ~/calibrate caller still waiting is
answered that its calibration was abandoned, and the calibration writes nothing; one already
writing its files ends that (the files become current either way) and its caller is told what
happened. The write lock orders the write against stop() and cancel(): a calibration either
writes or is stopped, never half of each.
"""
from __future__ import annotations

import threading
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Iterator, Optional

from ..core.errors import CalibrationCancelled
from ..core.progress import Progress

if TYPE_CHECKING:
    from ..core.types import RigCalibration
    from .settings import Settings

CHECK_JOB = "check"  # the reasons of the slot a ~/check and a ~/reload hold
RELOAD_JOB = "reload"
# How long a ~/calibrate caller waits, once the node stops, for a calibration that is writing its
# files (well under a second) to end: main() gives the callers 2 s to be answered.
WRITE_GRACE_S = 1.5
# What a calibration abandoned at shutdown answers its caller (wait_for, or the job itself).
ABANDONED = ("the node is shutting down: the calibration was abandoned; the last calibration "
             "stays as it was")


@dataclass
class Outcome:
    """How a job ended; a calibration written also gives its folder, rig, frame sets and time."""

    success: bool
    message: str
    cancelled: bool = False  # stopped (cancel() or shutdown) before anything was written
    folder: Optional[Path] = None
    rig: Optional["RigCalibration"] = None
    frame_sets: int = 0
    elapsed_s: float = 0.0


@dataclass
class Job:
    """A job holding the slot. A calibration's: the settings it runs with (None: the node's at
    its start), whether it ignores the published calibration, and its Progress (stop token)."""

    reason: str
    settings: Optional["Settings"] = None
    from_scratch: bool = False
    progress: Optional[Progress] = None
    done: threading.Event = field(default_factory=threading.Event)
    outcome: Optional[Outcome] = None
    committed: bool = False  # its files are being, or were, written: too late to cancel


class JobSlot:
    """The one job at a time, the worker thread of calibrations and the callers waiting on them."""

    def __init__(self):
        self._lock = threading.Lock()
        self._job: Optional[Job] = None
        self._worker: Optional[threading.Thread] = None
        self.stopping = threading.Event()  # stop(): answer waiting callers, write nothing
        self.writing = threading.Event()  # a calibration's files are being written
        self._write_lock = threading.Lock()
        self._callers = threading.Condition()
        self._num_callers = 0

    @property
    def reason(self) -> Optional[str]:
        """The reason of the job holding the slot; None when it is free."""
        with self._lock:
            return None if self._job is None else self._job.reason

    def take(self, reason: str, **job_fields) -> Optional[Job]:
        """Hold the slot for a job of `reason` (and Job's other fields); None when another job
        holds it or the node is stopping."""
        with self._lock:
            if self._job is not None or self.stopping.is_set():
                return None
            job = self._job = Job(reason, **job_fields)
            return job

    def release(self) -> None:
        with self._lock:
            self._job = None

    @contextmanager
    def held(self, reason: str) -> Iterator[bool]:
        """The slot for the `with` block (a check or reload in its caller's thread): yields False,
        holding nothing, when another job holds it."""
        job = self.take(reason)
        try:
            yield job is not None
        finally:
            if job is not None:
                self.release()

    def start_worker(self, reason: str, run: Callable[[Job], None], **job_fields
                     ) -> Optional[Job]:
        """run(job) in the worker thread holding the slot; None when another job holds it. `run`
        sets job.outcome; the slot is released and job.done set after it, whatever it raised.
        job_fields: Job's (settings, from_scratch, progress)."""
        job = self.take(reason, **job_fields)
        if job is None:
            return None

        def work() -> None:
            try:
                run(job)
            finally:
                if job.outcome is None:  # run raised: its caller still gets an answer
                    job.outcome = Outcome(False, "the calibration job crashed (see the log)")
                self.release()
                job.done.set()
        self._worker = threading.Thread(target=work, name="densecalib-worker", daemon=True)
        self._worker.start()
        return job

    def wait_for(self, job: Job, on_wait: Optional[Callable[[], None]] = None,
                 period_s: float = 0.2) -> Outcome:
        """What a ~/calibrate caller (service or action) is answered: the job's outcome, or at
        shutdown what became of it (a calibration writing its files is given WRITE_GRACE_S to
        end). on_wait() is called every period_s while the job runs (the action's feedback)."""
        with self._callers:
            self._num_callers += 1
        try:
            while not job.done.wait(period_s):
                if self.stopping.is_set():  # main() waits for this answer, not for the job
                    if self.writing.is_set() and job.done.wait(WRITE_GRACE_S):
                        break  # it was writing its files: its own outcome says what happened
                    return Outcome(False, (
                        "the node is shutting down while the calibration's files are written: "
                        "if the write completes, `latest` points at them and the node publishes "
                        "them at its next start" if self.writing.is_set() else ABANDONED),
                        cancelled=not self.writing.is_set())
                if on_wait is not None:
                    on_wait()
            return job.outcome
        finally:
            with self._callers:
                self._num_callers -= 1
                self._callers.notify_all()

    def answer_waiting_callers(self, timeout_s: float) -> None:
        """At shutdown, after stop(): wait (up to timeout_s) until every caller waiting for the
        abandoned calibration has had its answer returned."""
        with self._callers:
            self._callers.wait_for(lambda: self._num_callers == 0, timeout_s)

    @contextmanager
    def writing_files(self, job: Job) -> Iterator[None]:
        """The block that writes and publishes `job`'s calibration; CalibrationCancelled,
        writing nothing, when it was cancelled or the node stopped before it (its caller was
        told the calibration was abandoned)."""
        with self._write_lock:
            if self.stopping.is_set():
                raise CalibrationCancelled(ABANDONED)
            if job.progress is not None:
                job.progress.check()
            job.committed = True
            self.writing.set()
        try:
            yield
        finally:
            self.writing.clear()

    def cancel(self, reason: str, job: Optional[Job] = None) -> Optional[str]:
        """Stop the running calibration (or `job`, where it is the one running) at its next
        check: it writes nothing. None when it was told to, else why not (none running, or its
        files are already written)."""
        with self._write_lock:
            with self._lock:
                running = self._job
            if job is not None and running is not job:
                return "the calibration has ended"
            if running is None or running.progress is None:
                return ("no calibration is running" if running is None else
                        f"no calibration is running (a {running.reason} is, which cannot be "
                        "cancelled: it takes seconds)")
            if running.committed:
                return "too late: the calibration is written and published"
            running.progress.stop.stop(reason)
            return None

    @property
    def running(self) -> Optional[Job]:
        """The job holding the slot, if any."""
        with self._lock:
            return self._job

    def stop(self) -> None:
        """Shutdown: callers are answered, nothing more is written; a calibration still
        running is stopped at its next check."""
        with self._write_lock:
            self.stopping.set()
            with self._lock:
                job = self._job
            if job is not None and job.progress is not None and not job.committed:
                job.progress.stop.stop(ABANDONED)

    @property
    def worker_running(self) -> bool:
        return self._worker is not None and self._worker.is_alive()
