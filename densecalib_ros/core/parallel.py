"""Independent pieces of a calibration spread over the machine's cores.

Bundle adjustments of a few cameras keep Ceres on one core (the problems are too small for its
threads), so the parallel work is coarser: whole SfM trials (the focal multi-start) run in worker
processes, each single-threaded. A trial's result does not depend on where it ran, so a
calibration gives the same rig with one job or many. Smaller seeded pieces that release the GIL
(the sampling's two-view RANSACs, the placement repair's absolute poses) run on threads instead
(map_threads), with the loop's results.

The workers come from one pool per calibrating process, started once (forkserver: forked from a
clean server process, never from a process running ROS or Ceres threads) and reused by every
later calibration. Unlike multiprocessing's own workers they do not run the caller's main script
again (a user's script calibrating without an `if __name__ == "__main__":` guard would otherwise
calibrate once more in every worker): the tasks are functions of this package. They ignore
Ctrl-C; an interrupted calibration stops them at once. A pool that broke (a worker killed, e.g.
out of memory) is replaced, and the pieces it lost run here.
"""
from __future__ import annotations

import atexit
import contextvars
import logging
import multiprocessing
import os
import signal
import threading
import time
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor
from concurrent.futures import TimeoutError as FuturesTimeout
from concurrent.futures.process import BrokenProcessPool
from multiprocessing import popen_forkserver, spawn
from typing import Any, Callable, Optional, Sequence

from .progress import check_stop

log = logging.getLogger(__name__)

PACKAGE_LOGGER = "densecalib_ros"
# What the workers import before the first task, so that a task starts without import time.
PRELOAD_MODULES = ["densecalib_ros.core.method.incremental"]
# The signals the fork server and its workers never act on: they start with them blocked
# (_PopenWithoutMain), as `timeout`, systemd and a terminal send them to the whole process group and
# the calibrating process decides what stops (pycolmap's glog would answer a SIGTERM in them with a
# crash report, Python a SIGINT with a KeyboardInterrupt traceback).
STOP_SIGNALS = {signal.SIGINT, signal.SIGTERM}

# While workers or work run ahead run, the calibrating thread looks this often whether it was stopped (a
# cancelled goal must end within a couple of seconds; a trial can take tens of them).
STOP_CHECK_S = 0.2


_lock = threading.Lock()
_lock_start = threading.Lock()  # spawn.get_preparation_data is swapped while a worker starts
_pool: Optional[ProcessPoolExecutor] = None
_pool_workers = 0
_no_workers = False  # set where worker processes cannot be started


def available_cores() -> int:
    """Cores this process may run on (its CPU affinity, e.g. a container's share)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # not Linux
        return max(1, os.cpu_count() or 1)


def descendant_pids(pid: int) -> list[int]:
    """The processes below `pid` (children, their children, ...), read from /proc ([] where there
    is none)."""
    children: dict[int, list[int]] = {}
    try:
        entries = os.listdir("/proc")
    except OSError:
        return []
    for entry in entries:
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as f:
                    ppid = int(f.read().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
            children.setdefault(ppid, []).append(int(entry))
    found = list(children.get(pid, ()))
    for child in found:  # grows while it is walked
        found.extend(children.get(child, ()))
    return found


def map_threads(fn: Callable, items: Sequence, workers: Optional[int] = None,
                on_done: Optional[Callable[[], None]] = None) -> list:
    """[fn(item) for item in items], the items side by side in threads (at most `workers`, default
    every available core). For pieces of work that release the GIL (OpenCV's and pycolmap's
    estimators) and whose result does not depend on the thread that ran them (each seeds its own
    RANSAC): the results are those of the loop, in its order. on_done() hears of each result in
    turn, in the calling thread; what it raises (a cancelled calibration) cancels the items not
    yet started and is raised once the running ones returned."""
    items = list(items)
    workers = min(workers or available_cores(), len(items))
    if workers <= 1:
        results = []
        for item in items:
            results.append(fn(item))
            if on_done is not None:
                on_done()
        return results
    pool = ThreadPoolExecutor(workers)
    try:
        # each item in a copy of the caller's context (what core.progress.check_stop reads)
        futures = [pool.submit(contextvars.copy_context().run, fn, item) for item in items]
        results = []
        for future in futures:
            results.append(future.result())
            if on_done is not None:
                on_done()
        return results
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def job_count(jobs: int) -> int:
    """jobs as configured (-1 or 0 = every available core) as a number of processes."""
    return available_cores() if jobs <= 0 else int(jobs)



# The nice value of work run ahead (RunAhead): the lowest, so that it takes only the CPU time
# nothing else in the calibration (or on the machine) wants.
AHEAD_NICE = 19


def lower_this_thread() -> None:
    """Give the calling thread alone the lowest CPU priority (AHEAD_NICE; on Linux a nice value
    belongs to a thread). Without privileges a thread cannot raise it again: call it only in
    threads that end with their work. A no-op where the system does not allow it."""
    try:
        os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), AHEAD_NICE)
    except (AttributeError, OSError):
        pass


class RunAhead:
    """fn(*args, cancelled=<threading.Event>, thread_start=lower_this_thread) started at once on a
    thread of the lowest priority (lower_this_thread; fn runs thread_start first in any thread
    it starts): work a later stage needs that does not depend on what is computed before it, done
    on cores the calibration leaves idle (a multi-start's last trial, a single-threaded
    adjustment) instead of after it. result() waits for it and gives its value, or None where it
    failed (the stage then does the work itself, and meets the error itself); cancel() asks fn
    to stop (fn raises to stop, and is not waited for: a failed calibration returns at once).
    pause() holds fn at its next look at `cancelled` until resume() or result() (work for a
    calibration set aside while another runs: a nice value does not keep its Python parts off
    the interpreter lock). What still runs when the interpreter ends is cancelled and waited
    for then (_stop_work_ahead)."""

    def __init__(self, fn: Callable, *args: Any, name: str = "densecalib-ahead") -> None:
        self._cancelled = threading.Event()
        self._going = threading.Event()
        self._going.set()
        self._value: Any = None
        self._thread = threading.Thread(target=self._run, args=(fn, args), name=name,
                                        daemon=True)
        _running_ahead.add(self)
        self._thread.start()

    def _run(self, fn: Callable, args: tuple) -> None:
        lower_this_thread()
        try:
            self._value = fn(*args, cancelled=_Gate(self._cancelled, self._going),
                             thread_start=lower_this_thread)
        except Exception as exc:  # noqa: BLE001 - the stage that needs it does the work itself
            if not self._cancelled.is_set():
                log.debug("work run ahead failed (%r); it is done when needed", exc)
        finally:
            _running_ahead.discard(self)

    def result(self) -> Any:
        """Its value once it returned (the calibration's stop checked while it is waited for:
        core.progress.check_stop)."""
        while not self.returned_within(STOP_CHECK_S):
            pass
        return None if self._cancelled.is_set() else self._value

    def returned_within(self, timeout_s: float) -> bool:
        """Whether fn has returned, waiting for it at most timeout_s (resumed, the calibration's
        stop checked first)."""
        self.resume()
        check_stop()
        self._thread.join(timeout_s)
        return not self._thread.is_alive()

    def cancel(self) -> None:
        self._cancelled.set()

    def pause(self) -> None:
        self._going.clear()

    def resume(self) -> None:
        self._going.set()


class _Gate:
    """RunAhead's `cancelled` as its fn sees it (threading.Event's is_set and wait): whether the
    work was cancelled, once it is not paused (it waits while it is)."""

    def __init__(self, cancelled: threading.Event, going: threading.Event) -> None:
        self._cancelled, self._going = cancelled, going

    def is_set(self) -> bool:
        while not self._going.wait(STOP_CHECK_S) and not self._cancelled.is_set():
            pass
        return self._cancelled.is_set()

    def wait(self, timeout: float) -> bool:
        self._cancelled.wait(timeout)
        return self.is_set()


_running_ahead: set = set()  # RunAheads whose work has not returned


@atexit.register
def _stop_work_ahead() -> None:
    """Cancel the work still run ahead and wait for it before the interpreter ends: Python
    ends a daemon thread that comes back from C++ (OpenCV) after finalization began by unwinding
    it through that C++, which aborts the process (SIGABRT, exit code 134, instead of the
    command's own: a calibration that failed or was interrupted while dense correspondences
    were being found ahead). Cancelled work stops at its next check, within one image pair."""
    for ahead in list(_running_ahead):
        ahead.cancel()
    for ahead in list(_running_ahead):
        ahead._thread.join()


# How often a worker looks whether the process that started it is still there (seconds).
PARENT_CHECK_S = 1.0


def _worker_start(calibrating_pid: int) -> None:
    """Ctrl-C and a SIGTERM sent to the process group (timeout, systemd) reach the workers too:
    the calibrating process decides what stops, and stops them (glog's handler, which pycolmap
    installs, would answer a SIGTERM with a crash report and stack trace). A worker whose
    calibrating process was killed outright (SIGKILL, the OOM killer) would wait for tasks for
    ever, and keep the fork server alive (each worker holds the server's keep-alive pipe so that
    it could start processes itself); it ends instead."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)

    def watch() -> None:
        while is_running(calibrating_pid):
            time.sleep(PARENT_CHECK_S)
        os._exit(1)

    threading.Thread(target=watch, name="densecalib-parent-watch", daemon=True).start()


def is_running(pid: int) -> bool:
    """Whether process pid exists and is not a zombie (dead, not yet reaped)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] not in ("Z", "X")
    except OSError:
        try:
            os.kill(pid, 0)  # no /proc: existence only
        except ProcessLookupError:
            return False
        except PermissionError:
            pass
        return True


class _Records(logging.Handler):
    """A worker's log records, kept to be handled in the calibrating process."""

    def __init__(self) -> None:
        super().__init__()
        self.records: list[logging.LogRecord] = []

    def emit(self, record: logging.LogRecord) -> None:
        record.msg, record.args = record.getMessage(), None  # arguments may not pickle
        record.exc_info = record.exc_text = None
        self.records.append(record)


def _run_task(colmap_log_level: int, log_level: int, fn: Callable, args: tuple
              ) -> tuple[Any, list]:
    """(fn(*args), the package's log records at log_level or above that it made)."""
    import pycolmap

    pycolmap.logging.minloglevel = colmap_log_level  # the caller's setting (quiet_colmap)
    package = logging.getLogger(PACKAGE_LOGGER)
    records = _Records()
    package.addHandler(records)
    package.setLevel(log_level)
    try:
        return fn(*args), records.records
    finally:
        package.removeHandler(records)


class _PopenWithoutMain(popen_forkserver.Popen):
    """Starts a forkserver worker without the caller's __main__ in its preparation data."""

    def _launch(self, process_obj):
        # The fork server starts here (on the first worker), with the stop signals blocked: a
        # blocked mask passes to the server through exec and on to the workers it forks.
        previous_mask = signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS)
        try:
            self._launch_without_main(process_obj)
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, previous_mask)

    def _launch_without_main(self, process_obj):
        with _lock_start:
            get_preparation_data = spawn.get_preparation_data

            def without_main(name):
                data = get_preparation_data(name)
                data.pop("init_main_from_path", None)
                data.pop("init_main_from_name", None)
                return data

            spawn.get_preparation_data = without_main
            try:
                super()._launch(process_obj)
            finally:
                spawn.get_preparation_data = get_preparation_data


class _WorkerProcess(multiprocessing.context.ForkServerProcess):
    @staticmethod
    def _Popen(process_obj):
        return _PopenWithoutMain(process_obj)


class _WorkerContext(multiprocessing.context.ForkServerContext):
    Process = _WorkerProcess



def _get_pool(workers: int) -> ProcessPoolExecutor:
    global _pool, _pool_workers
    with _lock:
        if _pool is None or _pool_workers != workers:
            if _pool is not None:
                _pool.shutdown(wait=False, cancel_futures=True)
            context = _WorkerContext()
            context.set_forkserver_preload(PRELOAD_MODULES)
            _pool = ProcessPoolExecutor(workers, mp_context=context,
                                        initializer=_worker_start,
                                        initargs=(os.getpid(),))
            _pool_workers = workers
        return _pool


def stop_workers() -> None:
    """Stop the worker processes now (their running tasks are abandoned)."""
    global _pool
    with _lock:
        pool, _pool = _pool, None
    if pool is None:
        return
    processes = list((getattr(pool, "_processes", None) or {}).values())
    pool.shutdown(wait=False, cancel_futures=True)
    for process in processes:
        if process.is_alive():
            # SIGKILL, not SIGTERM: a worker has nothing to clean up, and glog's failure handler
            # (pycolmap installs it) answers a SIGTERM with a crash report and stack trace.
            process.kill()
    for process in processes:
        process.join(timeout=5)


def map_jobs(fn: Callable, arg_tuples: Sequence[tuple], jobs: int,
             on_done: Optional[Callable[[int], None]] = None,
             check: Optional[Callable[[], None]] = None) -> list:
    """[fn(*args) for args in arg_tuples], spread over job_count(jobs) worker processes when
    that is more than one and there is more than one task. fn and its arguments and results must
    pickle (fn a module-level function). What the tasks log under this package reaches this
    process's handlers, task by task in order; on_done(k) hears that the first k results are in.
    check() is called every STOP_CHECK_S while the workers run (between tasks where they run
    here): what it raises (a cancelled calibration) stops the workers and is raised."""
    import pycolmap

    global _no_workers
    workers = min(job_count(jobs), len(arg_tuples))
    if workers <= 1 or _no_workers:
        return _in_this_process(fn, arg_tuples, on_done, check)
    levels = (pycolmap.logging.minloglevel,
              logging.getLogger(PACKAGE_LOGGER).getEffectiveLevel())
    results: list = [None] * len(arg_tuples)
    pending = list(range(len(arg_tuples)))
    try:
        pool = _get_pool(workers)
        futures = {k: pool.submit(_run_task, *levels, fn, arg_tuples[k]) for k in pending}
    except (OSError, EOFError) as exc:  # no processes or semaphores (a locked-down container),
        if check is not None:            # or a fork server a stop's signal ended as it started
            check()
        log.warning("no worker processes here (%s): this process does all the work, on one "
                    "core", exc)
        _no_workers = True  # said once; not tried again
        stop_workers()
        return _in_this_process(fn, arg_tuples, on_done, check)
    try:
        for k in list(pending):
            results[k], records = _result(futures[k], check)
            for record in records:  # reported here, once, as if the task had run here
                logging.getLogger(record.name).handle(record)
            pending.remove(k)
            if on_done is not None:
                on_done(k + 1)
    except BrokenProcessPool as exc:
        if check is not None:
            check()  # stopped: the workers' end is no news
        log.warning("a worker process ended unexpectedly (%s); running the %d remaining "
                    "piece(s) of work in this process", exc, len(pending))
        stop_workers()
        for k in pending:
            if check is not None:
                check()
            results[k] = fn(*arg_tuples[k])
            if on_done is not None:
                on_done(k + 1)
    except Exception:  # a task's own error: the others' results are not needed
        for future in futures.values():
            future.cancel()
        raise
    except BaseException:  # Ctrl-C, SIGTERM: no worker outlives the call
        stop_workers()
        raise
    return results


def _result(future, check: Optional[Callable[[], None]]):
    """The future's result, check() called every STOP_CHECK_S while it is not in."""
    while True:
        if check is not None:
            check()
        try:
            return future.result(timeout=STOP_CHECK_S if check is not None else None)
        except FuturesTimeout:
            continue


def _in_this_process(fn: Callable, arg_tuples: Sequence[tuple],
                     on_done: Optional[Callable[[int], None]],
                     check: Optional[Callable[[], None]] = None) -> list:
    results = []
    for args in arg_tuples:
        if check is not None:
            check()
        results.append(fn(*args))
        if on_done is not None:
            on_done(len(results))
    return results
