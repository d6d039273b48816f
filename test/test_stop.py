"""A calibration can be watched and stopped (issue 83): its stages report the fraction done and the
seconds left, a stop set from another thread ends it at its next check within a couple of
seconds, in any stage, and what was written before stays as it was (the library writes
nothing; `densecalib calibrate` interrupted by Ctrl-C or SIGTERM exits 130 or 143 with one line
and leaves its output folder as it was)."""
import hashlib
import os
import signal
import subprocess
import sys
import threading
import time

import pytest

from densecalib_ros.core import (CalibrationCancelled, Progress, RigSpec, StopToken,
                                 generate_rig, make_config, run_calibration)
from densecalib_ros.core.progress import STAGE_SHARES
from densecalib_ros.core.synthetic import write_rig

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
# A stop is answered within this many seconds (the action's cancel must end the goal within 2 s).
STOP_WITHIN_S = 2.0


@pytest.fixture(scope="module")
def rig():
    return generate_rig(RigSpec(lenses="ideal", num_cameras=4, camera_model="RADIAL", width=640,
                                height=480, num_time_steps=2, seed=1))


@pytest.mark.parametrize("stage", ["match", "calibrate", "refine"])
def test_a_stop_from_another_thread_ends_the_calibration_within_two_seconds(rig, stage):
    stopped_at = []
    token = StopToken()

    def on_stage(state):
        if state.stage == stage and not stopped_at:
            def stop():
                stopped_at.append(time.perf_counter())
                token.stop("cancelled by the test")
            threading.Timer(0.3, stop).start()
    states = []
    progress = Progress(on_stage=lambda s: (states.append(s), on_stage(s)), stop=token)
    with pytest.raises(CalibrationCancelled, match="cancelled by the test"):
        run_calibration(rig.images, rig.names, make_config("regular"), progress=progress)
    took = time.perf_counter() - stopped_at[0]
    assert took < STOP_WITHIN_S, f"{stage}: {took:.2f} s"
    assert [s.stage for s in states][0] == "match" and states[-1].stage == stage
    fractions = [s.fraction for s in states]
    assert fractions == sorted(fractions) and 0.0 <= fractions[-1] < 1.0
    assert all(s.seconds_left is not None and s.seconds_left >= 0 for s in states)


def test_the_fraction_done_and_the_seconds_left_follow_the_run(rig):
    """The stages in order, the fraction done rising to the end, the seconds left falling to
    about none, and the whole run's estimate within a factor of its length once a third is done."""
    states = []
    progress = Progress(on_stage=states.append)
    started = time.perf_counter()
    run_calibration(rig.images, rig.names, make_config("regular"), progress=progress)
    took = time.perf_counter() - started
    stages = [s.stage for s in states]
    assert stages[0] == "match" and "calibrate" in stages and stages[-1] == "done"
    assert stages.index("calibrate") < stages.index("refine")
    third = next(s for s in states if s.fraction >= 1 / 3)
    estimate = third.elapsed_s + third.seconds_left
    assert took / 3 < estimate < 3 * took, (estimate, took)
    assert progress.state().fraction == 1.0 and progress.state().seconds_left == 0.0


def test_a_stage_that_waits_for_work_run_ahead_counts_its_seconds_at_the_runs_pace():
    """Where the refinement begins with its dense correspondences still found ahead, the
    seconds it waits are added to its share at the pace the run has kept: the seconds left are
    those plus the stage's own planned share's, not the planned share's alone."""
    progress = Progress()
    progress.plan(["match", "calibrate", "refine"])
    progress.begin("match", "matching")
    time.sleep(0.2)
    progress.begin("calibrate", "calibrating")
    time.sleep(0.2)
    done_share = STAGE_SHARES["match"] + STAGE_SHARES["calibrate"]
    elapsed = progress.state().elapsed_s
    planned = elapsed * STAGE_SHARES["refine"] / done_share  # at the run's pace
    progress.begin("refine", "refining", 1, waits_s=2.0)
    state = progress.state()
    assert 0.1 < state.fraction < done_share / sum(STAGE_SHARES.values())
    assert abs(state.seconds_left - (2.0 + planned)) < 0.1, (state.seconds_left, planned)
    # half the wait over: half its share of the run done (the stage's one step not yet)
    wait_share = 2.0 * done_share / elapsed
    progress.waited(0.5)
    assert abs(progress.state().fraction - (done_share + 0.5 * wait_share) /
               (sum(STAGE_SHARES.values()) + wait_share)) < 0.01


def test_a_stage_that_times_its_steps_says_its_own_seconds_left():
    """The second matcher's matching takes several times its planned share: where a stage says
    its seconds left (advance's left_s, from its steps' pace), the run's seconds left are those
    plus the later stages' shares at the pace of the stages before; a share alone says far
    less. Its steps all done, the stage is done."""
    progress = Progress()
    progress.plan(["match", "calibrate", "refine"])
    progress.begin("match", "matching")
    time.sleep(0.3)
    pace = STAGE_SHARES["match"] / progress.state().elapsed_s  # share per second
    progress.begin("calibrate", "calibrating", 10)
    time.sleep(0.1)
    later_s = STAGE_SHARES["refine"] / pace
    progress.advance(1)  # by its share: one step of ten done
    by_share = progress.state().seconds_left
    progress.advance(1, left_s=6.0)
    state = progress.state()
    assert abs(state.seconds_left - (6.0 + later_s)) < 0.3, (state.seconds_left, later_s)
    assert by_share < 6.0 / 2
    progress.advance(10)
    assert progress.state().fraction > 0.8  # the stage done; refine's share left


def _digest(folder) -> str:
    h = hashlib.sha256()
    for root, _, files in sorted(os.walk(folder)):
        for name in sorted(files):
            path = os.path.join(root, name)
            h.update(path.encode())
            with open(path, "rb") as f:
                h.update(f.read())
    return h.hexdigest()


@pytest.fixture(scope="module")
def calibrated(rig, tmp_path_factory):
    """(image folder, an output folder holding an earlier calibration of it)."""
    base = tmp_path_factory.mktemp("stop")
    write_rig(rig, base / "images")
    out = base / "out"
    done = subprocess.run([sys.executable, "-m", "densecalib_ros.cli", "calibrate", "--images",
                           str(base / "images"), "--out", str(out), "--consensus-runs", "1"],
                          capture_output=True, text=True, cwd=REPO, timeout=600)
    assert done.returncode == 0, done.stderr
    return base / "images", out


@pytest.mark.parametrize("sig, said", [(signal.SIGINT, "matched frame set 1/2"),
                                       (signal.SIGTERM, "consensus run 1 of up to 5"),
                                       (signal.SIGINT, "refined on all")])
def test_a_signal_during_the_calibration_stops_the_command_and_keeps_its_output(calibrated, sig,
                                                                               said):
    """Ctrl-C or SIGTERM sent to the command's process group (as a terminal and `timeout` send
    them) while it calibrates: the calibration stops at its next check; exit 130 or 143, one
    line, no traceback or crash report from it or its worker processes; the output folder as it
    was, nothing left beside it."""
    images, out = calibrated
    before = _digest(out)
    child = subprocess.Popen([sys.executable, "-m", "densecalib_ros.cli", "calibrate",
                              "--images", str(images), "--out", str(out)], cwd=REPO,
                             stderr=subprocess.PIPE, text=True, start_new_session=True)
    lines = []
    for line in child.stderr:
        lines.append(line)
        if said in line:
            break
    sent = time.perf_counter()
    os.killpg(child.pid, sig)
    rest = child.stderr.read()
    code = child.wait(60)
    took = time.perf_counter() - sent
    assert code == {signal.SIGINT: 130, signal.SIGTERM: 143}[sig], rest
    after = rest.strip().splitlines()
    assert "what was written before stays as it was" in after[-1], rest
    assert sum(" ERROR " in line for line in after) == 1, rest
    for crash in ("Traceback", "terminate called", "Aborted", "*** ", "SystemError"):
        assert crash not in rest
    assert took < 10.0
    assert _digest(out) == before
    assert not [p for p in os.listdir(out.parent) if p.startswith(".out.")]


def test_on_a_terminal_the_command_shows_a_line_per_stage_and_the_log_with_v(calibrated,
                                                                            tmp_path):
    """On a terminal: one updating line per stage with the time left, and none of the log's
    INFO lines; with -v the full log."""
    import pty

    images, _ = calibrated
    shown = {}
    for flags in ((), ("-v",)):
        main, tty = pty.openpty()
        child = subprocess.Popen([sys.executable, "-m", "densecalib_ros.cli", *flags,
                                  "calibrate", "--images", str(images), "--out",
                                  str(tmp_path / f"out{len(flags)}"), "--consensus-runs", "1"],
                                 cwd=REPO, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL,
                                 stderr=tty)
        os.close(tty)
        text = b""
        while True:
            try:
                chunk = os.read(main, 65536)
            except OSError:  # the terminal closed: the child is done
                break
            if not chunk:
                break
            text += chunk
        assert child.wait(600) == 0
        os.close(main)
        shown[flags] = text.decode(errors="replace")
    line = shown[()]
    assert "matching (sift)" in line and "calibrating" in line
    assert "refining on the images" in line and " left" in line and "\r" in line
    assert " INFO " not in line
    assert " INFO " in shown[("-v",)] and "matched frame set 1/2" in shown[("-v",)]


def test_a_ctrl_c_while_the_command_imports_ends_in_one_line(monkeypatch, caplog, tmp_path):
    """Ctrl-C while the subcommand's modules load (pycolmap's C++ part among them) ended in a
    traceback that told the user to reinstall pycolmap, exit 1. The signal now waits for the
    command's own handler: exit 130 and one line. The user's Ctrl-C is raised, for real, from
    inside the import."""
    import importlib
    import logging

    from densecalib_ros.cli import main

    real_import = importlib.import_module

    def import_with_ctrl_c(name, *args, **kwargs):
        if name.startswith("densecalib_ros.commands."):
            signal.raise_signal(signal.SIGINT)
        return real_import(name, *args, **kwargs)

    monkeypatch.setattr(importlib, "import_module", import_with_ctrl_c)
    with caplog.at_level(logging.ERROR):
        assert main(["report", str(tmp_path / "none")]) == 130
    assert "interrupted" in caplog.text
