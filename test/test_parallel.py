"""Work spread over worker processes (core.parallel, issue 42): the same rig on one core and on
several, a user's script without a main guard run once, no worker left behind by an interrupted
or killed calibration. Real processes and signals."""
import logging
import os
import signal
import subprocess
import sys
import textwrap
import time
from functools import partial

import numpy as np
import pytest

from densecalib_ros.core.config import make_config
from densecalib_ros.core.method.incremental import initial_intrinsics
from densecalib_ros.core.method.multistart import run_incremental
from densecalib_ros.core.parallel import is_running, descendant_pids, map_jobs
from densecalib_ros.core.progress import StageClock

import sfm_fixtures

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
gt_rig = partial(sfm_fixtures.gt_rig, pp_jitter_px=5.0, k1_range=(-0.1, 0.05), k2_max=0.02)


def test_the_multistart_gives_the_same_rig_and_log_on_one_core_and_on_several(caplog):
    names = ["cam_a", "cam_b", "cam_c", "cam_d"]
    cams, poses = gt_rig(4, seed=11)
    tracks = sfm_fixtures.gt_tracks(cams, poses, num_points=1500, outlier_frac=0.05, seed=11)
    focals = np.array([c.params[0] * 0.8 for c in cams])  # a start the multi-start must leave
    results = []
    for jobs in (1, 2):
        cfg = make_config("regular", sfm__num_threads=jobs).sfm
        init = initial_intrinsics([(c.width, c.height) for c in cams], focals, cfg.camera_model)
        messages = []
        caplog.clear()
        with caplog.at_level(logging.DEBUG, logger="densecalib_ros"):
            result = run_incremental(tracks, init, names, cfg, progress=messages.append)
        results.append((result, messages, [(r.name, r.levelno, r.getMessage())
                                           for r in caplog.records]))
    # (the lines saying the trials' time left come by the clock, not by the work: left out)
    (one, said_one, log_one), (two, said_two, log_two) = [
        (r, [m for m in said if "trials done" not in m],
         [x for x in log if "trials done" not in x[2]]) for r, said, log in results]
    assert said_one == said_two and any("focal multi-start" in m for m in said_one)
    # The trials' own debug lines (eq. 3 first-pair costs) reach this process's log from the
    # workers, in the same order.
    assert log_one == log_two and any("first pair" in m for _, _, m in log_one)
    assert one.failed == two.failed == []
    for c in range(len(names)):
        np.testing.assert_array_equal(one.state.camera(c).params, two.state.camera(c).params)
        np.testing.assert_array_equal(one.state.cam_from_world[c], two.state.cam_from_world[c])


def _script(tmp_path, body: str) -> list[str]:
    """Command line of a Python script file (a real __main__ with a path, as a user's script)."""
    path = tmp_path / "user_script.py"
    path.write_text(textwrap.dedent(body))
    return [sys.executable, str(path)]


def _env():
    return {**os.environ, "PYTHONPATH": REPO + os.pathsep + os.environ.get("PYTHONPATH", "")}


def test_a_script_without_a_main_guard_runs_once(tmp_path):
    """multiprocessing's own workers would import the script again, and its body run again in
    every worker."""
    command = _script(tmp_path, """
        import math
        from densecalib_ros.core.parallel import map_jobs
        print("script body ran", flush=True)
        print(map_jobs(math.factorial, [(5,), (6,), (7,)], 2), flush=True)
        """)
    done = subprocess.run(command, capture_output=True, text=True, env=_env(), timeout=120)
    assert done.returncode == 0, done.stderr
    assert done.stdout.splitlines() == ["script body ran", "[120, 720, 5040]"]


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGKILL])
def test_no_worker_outlives_an_interrupted_or_killed_run(tmp_path, sig):
    command = _script(tmp_path, """
        import time
        from densecalib_ros.core.parallel import map_jobs
        print("working", flush=True)
        map_jobs(time.sleep, [(4,)] * 6, 2)
        """)
    proc = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=_env())
    assert proc.stdout.readline().strip() == "working"
    deadline = time.monotonic() + 60
    while len(descendant_pids(proc.pid)) < 3 and time.monotonic() < deadline:  # server, 2 workers
        time.sleep(0.2)
    workers = set(descendant_pids(proc.pid))
    assert len(workers) >= 3, "the workers never started"
    os.kill(proc.pid, sig)
    proc.wait(timeout=30)
    # SIGINT: stopped by the run. SIGKILL: nothing runs in the parent; the fork server sees it
    # gone, and the workers their server (core.parallel.PARENT_CHECK_S), mid-task.
    deadline = time.monotonic() + 3
    while any(is_running(p) for p in workers) and time.monotonic() < deadline:
        time.sleep(0.2)
    left = [p for p in workers if is_running(p)]
    for p in left:
        os.kill(p, signal.SIGKILL)
    stderr = proc.stderr.read()
    assert not left, stderr
    # Stopped, not crashed: no crash report from a worker (glog's, which pycolmap installs,
    # prints a stack trace for a SIGTERM).
    assert "stack trace" not in stderr and "Aborted" not in stderr, stderr


def test_where_no_worker_can_start_the_work_runs_here_and_says_so_once(monkeypatch, caplog):
    """A container without process or semaphore rights: the calibration still runs."""
    import math

    import densecalib_ros.core.parallel as parallel

    def refuse(workers):
        raise PermissionError(1, "Operation not permitted", "/dev/shm")

    monkeypatch.setattr(parallel, "_get_pool", refuse)
    monkeypatch.setattr(parallel, "_no_workers", False)
    with caplog.at_level(logging.WARNING, logger="densecalib_ros"):
        assert parallel.map_jobs(math.factorial, [(4,), (5,)], 2) == [24, 120]
        assert parallel.map_jobs(math.factorial, [(3,), (6,)], 2) == [6, 720]
    (said,) = [r.getMessage() for r in caplog.records]
    assert "no worker processes here" in said and "/dev/shm" in said


@pytest.mark.parametrize("jobs", [1, 2])
def test_map_jobs_says_how_many_results_are_in_and_the_stage_clock_its_time_left(jobs):
    heard = []
    assert map_jobs(pow, [(2, k) for k in range(5)], jobs, on_done=heard.append) == \
        [1, 2, 4, 8, 16]
    assert heard == [1, 2, 3, 4, 5]
    clock = StageClock(4)
    assert clock.left(0) == "" and not clock.due(60.0)
    time.sleep(0.2)
    assert clock.due(0.1)
    left = clock.left(1)  # one step took >= 0.2 s: three more, >= 0.6 s
    assert left.startswith(", about ") and left.endswith(" s left")
    assert int(left.split()[2]) >= 1  # 0.6 s at least, said to the second
    assert not clock.due(60.0)  # just said
    assert clock.left(4) == ""  # the stage is over: nothing left to say


def test_a_stage_clock_whose_first_step_is_apart_counts_the_later_steps_pace():
    # a frame set matched whole, then later ones on what is new only: several times faster
    clock = StageClock(4, first_apart=True)
    time.sleep(1.5)
    assert clock.left(1) == ""  # nothing yet to say the later steps' pace by
    time.sleep(0.1)
    left = clock.left(2)  # two more steps at ~0.1 s: 0.2 s, not the 1.6 s the mean of all gives
    assert left.startswith(", about ") and int(left.split()[2]) <= 1
    assert clock.left(4) == ""


def test_work_run_ahead_takes_the_lowest_priority_and_stops_when_cancelled():
    """RunAhead's thread, and the threads its work starts, run at the lowest priority (Linux:
    a nice value per thread) while the caller's stays as it was; cancel() stops it and result()
    then gives None; work that fails gives None (the stage needing it does the work itself)."""
    import threading

    from densecalib_ros.core.parallel import AHEAD_NICE, RunAhead

    def priority():
        return os.getpriority(os.PRIO_PROCESS, threading.get_native_id())

    def work(cancelled, thread_start):
        while not cancelled.wait(0.01):
            pass
        return "never used"

    caller = priority()
    ahead = RunAhead(work)
    time.sleep(0.2)
    assert ahead._thread.is_alive()  # waits to be cancelled
    ahead.cancel()
    assert ahead.result() is None and not ahead._thread.is_alive()
    assert priority() == caller

    def quick(x, cancelled, thread_start):
        seen = {"own": priority(), "x": x}

        def inner():
            thread_start()
            seen["inner"] = priority()
        t = threading.Thread(target=inner)
        t.start()
        t.join()
        return seen
    lowest = max(caller, AHEAD_NICE)
    assert RunAhead(quick, 7).result() == {"own": lowest, "inner": lowest, "x": 7}

    def fails(cancelled, thread_start):
        raise ValueError("no")
    assert RunAhead(fails).result() is None


def test_work_run_ahead_waits_while_paused_and_goes_on_when_resumed_or_asked_for():
    """pause() holds the work at its next look at `cancelled` (a calibration set aside while
    the second matcher runs: stages.attempt); resume() lets it go on; result() resumes it
    itself; a paused work that is cancelled ends."""
    import threading

    from densecalib_ros.core.parallel import RunAhead

    steps = []

    def work(cancelled, thread_start):
        while len(steps) < 40:
            if cancelled.is_set():
                return None
            steps.append(1)
            time.sleep(0.01)
        return len(steps)

    ahead = RunAhead(work)
    ahead.pause()
    time.sleep(0.1)
    held = len(steps)
    time.sleep(0.3)
    assert len(steps) <= held + 1 and ahead._thread.is_alive()  # one step may finish
    ahead.resume()
    time.sleep(0.1)
    assert len(steps) > held + 1
    ahead.pause()
    assert ahead.result() == 40  # asked for: taken up again

    stopped = RunAhead(lambda cancelled, thread_start: cancelled.is_set() or
                       cancelled.wait(5.0) or "not cancelled")
    stopped.pause()
    stopped.cancel()
    stopped._thread.join(2.0)
    assert not stopped._thread.is_alive() and stopped.result() is None


def test_a_process_ending_while_work_runs_ahead_in_opencv_keeps_its_exit_code(tmp_path):
    """A calibration that fails or is interrupted while the dense correspondences are found
    ahead exits with its own code: the work still inside OpenCV when the script ends is
    cancelled and waited for, not unwound through C++ by the interpreter's finalization
    (SIGABRT, 134). The script's work is one OpenCV call that outlasts the exit (0.4-0.7 s here)."""
    command = _script(tmp_path, """
        import sys, threading
        import cv2
        import numpy as np
        from densecalib_ros.core.parallel import RunAhead
        image = np.random.default_rng(0).random((5000, 5000), dtype=np.float32)
        started = threading.Event()

        def work(cancelled, thread_start):
            started.set()
            cv2.matchTemplate(image, image[:300, :300], cv2.TM_SQDIFF)

        ahead = RunAhead(work)
        started.wait()
        ahead.cancel()
        sys.exit(3)
        """)
    for _ in range(2):
        done = subprocess.run(command, capture_output=True, text=True, env=_env(), timeout=120)
        assert done.returncode == 3, done.stderr


def test_map_threads_gives_the_loops_results_in_its_order_with_seeded_ransacs():
    """map_threads: the pieces side by side give what the loop gives, bit for bit, in the loop's
    order: OpenCV's seeded RANSAC (the two-view geometry of the sampling) and pycolmap's (the
    placement repair's absolute poses) do not depend on the thread that ran them."""
    import pycolmap

    from densecalib_ros.core.method.incremental import absolute_pose
    from densecalib_ros.core.method.twoview import estimate_fundamental
    from densecalib_ros.core.parallel import map_threads

    rng = np.random.default_rng(3)
    camera = pycolmap.Camera(model="SIMPLE_RADIAL", width=800, height=600,
                             params=[700.0, 400.0, 300.0, 0.0])

    def views(k):
        X = rng.uniform(-2.0, 2.0, (600, 3)) + [0.0, 0.0, 6.0]
        shift = np.array([0.4 + 0.1 * k, 0.0, 0.1])
        xy_a = np.array(camera.img_from_cam(X)) + rng.normal(scale=0.5, size=(600, 2))
        xy_b = np.array(camera.img_from_cam(X + shift)) + rng.normal(scale=0.5, size=(600, 2))
        xy_b[:150] = rng.uniform(0.0, 600.0, (150, 2))  # outliers: the RANSAC has to draw
        return X, xy_a, xy_b
    pieces = [views(k) for k in range(8)]

    def geometry(p):
        return estimate_fundamental(p[1], p[2], 2.0, seed=0)

    def pose(p):
        start = pycolmap.Camera(model="SIMPLE_RADIAL", width=800, height=600,
                                params=[650.0, 400.0, 300.0, 0.0])
        return absolute_pose(p[2], p[0], start, refine_intrinsics=True), np.array(start.params)

    assert map_threads(geometry, []) == []
    for fn in (geometry, pose):
        loop = [fn(p) for p in pieces]
        for workers in (2, 4):
            side_by_side = map_threads(fn, pieces, workers)
            assert len(side_by_side) == len(loop)
            for a, b in zip(loop, side_by_side):
                if fn is geometry:
                    assert np.array_equal(a.F_ji, b.F_ji)
                    assert np.array_equal(a.inlier_mask, b.inlier_mask)
                else:
                    assert a[0] is not None
                    assert np.array_equal(a[0], b[0]) and np.array_equal(a[1], b[1])
