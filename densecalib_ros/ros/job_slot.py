"""The node's one job slot and its shutdown hand-over.

A calibration (in a worker thread), a check and a reload hold the slot in turn, so that no
calibration publishes over a reload or swaps the matcher under a check. At shutdown (stop()) a
~/calibrate caller still waiting is answered that its calibration was abandoned, and the
calibration writes nothing; one already writing its files ends that (the files become current
either way) and its caller is told what happened. The write lock orders the write against stop():
a calibration either writes or is abandoned, never half of each.
"""
from __future__ import annotations

import threading
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Callable, Iterator, Optional

from ..core.errors import CalibrationError

CHECK_JOB = "check"  # the reasons of the slot a ~/check and a ~/reload hold
RELOAD_JOB = "reload"
# How long a ~/calibrate caller waits, once the node stops, for a calibration that is writing its
# files (well under a second) to end: main() gives the callers 2 s to be answered.
WRITE_GRACE_S = 1.5


@dataclass
class Outcome:
    success: bool
    message: str


@dataclass
class Job:
    reason: str
    done: threading.Event = field(default_factory=threading.Event)
    outcome: Optional[Outcome] = None


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

    def take(self, reason: str) -> Optional[Job]:
        """Hold the slot for a job of `reason`; None when another job holds it."""
        with self._lock:
            if self._job is not None:
                return None
            job = self._job = Job(reason)
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

    def start_worker(self, reason: str, run: Callable[[Job], None]) -> Optional[Job]:
        """run(job) in the worker thread holding the slot; None when another job holds it. `run`
        sets job.outcome; the slot is released and job.done set after it, whatever it raised."""
        job = self.take(reason)
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

    def wait_for(self, job: Job) -> Outcome:
        """What a ~/calibrate caller is answered: the job's outcome, or at shutdown what became
        of it (a calibration writing its files is given WRITE_GRACE_S to end)."""
        with self._callers:
            self._num_callers += 1
        try:
            while not job.done.wait(0.2):
                if self.stopping.is_set():  # main() waits for this answer, not for the job
                    if self.writing.is_set() and job.done.wait(WRITE_GRACE_S):
                        break  # it was writing its files: its own outcome says what happened
                    return Outcome(False, (
                        "the node is shutting down while the calibration's files are written: "
                        "if the write completes, `latest` points at them and the node publishes "
                        "them at its next start" if self.writing.is_set() else
                        "the node is shutting down: the calibration was abandoned; the last "
                        "calibration stays as it was"))
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
    def writing_files(self) -> Iterator[None]:
        """The block that writes and publishes a calibration; CalibrationError, writing nothing,
        when the node stopped before it (its caller was told the calibration was abandoned)."""
        with self._write_lock:
            if self.stopping.is_set():
                raise CalibrationError("the node shut down during the calibration; nothing "
                                       "written")
            self.writing.set()
        try:
            yield
        finally:
            self.writing.clear()

    def stop(self) -> None:
        with self._write_lock:
            self.stopping.set()

    @property
    def worker_running(self) -> bool:
        return self._worker is not None and self._worker.is_alive()
