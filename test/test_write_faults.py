"""Faults while writing, injected for real: processes killed with SIGKILL and SIGTERM part-way
through replacing a folder, a file-size limit standing in for a full disk. After each, the last
good output is current and the next run cleans what the killed one left (issue 40)."""
import json
import logging
import os
import signal
import subprocess
import sys
import textwrap

import pytest

from densecalib_ros.core.errors import InputError
from densecalib_ros.core.io.export import (CALIBRATION_MARKERS, calibration_entries,
                                           write_calibration_files)
from densecalib_ros.core.io.safe_write import exchange_paths, replace_directory_atomic
from densecalib_ros.core.synthetic import RigSpec, generate_rig, write_rig

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _child(script: str, *args) -> subprocess.Popen:
    """A Python process running `script` (argv[1:] = args) with this checkout importable."""
    env = {**os.environ, "PYTHONPATH": REPO + os.pathsep + os.environ.get("PYTHONPATH", "")}
    return subprocess.Popen([sys.executable, "-c", textwrap.dedent(script), *map(str, args)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)


def _wait_for(proc: subprocess.Popen, line: str, timeout_s: float = 60.0) -> None:
    """Until the child prints `line` (it is then where the test wants to kill it)."""
    import selectors

    with selectors.DefaultSelector() as sel:
        sel.register(proc.stdout, selectors.EVENT_READ)
        while sel.select(timeout_s):
            got = proc.stdout.readline()
            if got.strip() == line:
                return
            if not got:
                break
    proc.kill()
    raise AssertionError(f"the child never said {line!r}: {proc.stderr.read()}")


@pytest.fixture(scope="module")
def images(tmp_path_factory):
    """A rig the default command calibrates in a few seconds."""
    folder = tmp_path_factory.mktemp("rig") / "images"
    write_rig(generate_rig(RigSpec(lenses="ideal", num_cameras=4, camera_model="RADIAL",
                                   width=640, height=480, num_time_steps=2, seed=1)), folder)
    return folder


def _write(out, text):
    replace_directory_atomic(lambda tmp: (tmp / "calibration.json").write_text(text), out,
                             CALIBRATION_MARKERS)


def _hidden(folder):
    return sorted(p.name for p in folder.iterdir() if p.name.startswith("."))


def test_the_swap_is_one_atomic_exchange(tmp_path):
    """Where the filesystem can, old and new folders are exchanged in one step: there is no
    moment at which the output folder is missing."""
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    (tmp_path / "a" / "x").write_text("a")
    if not exchange_paths(tmp_path / "a", tmp_path / "b"):
        pytest.skip(f"renameat2(RENAME_EXCHANGE) is not available on {tmp_path}'s filesystem")
    assert (tmp_path / "b" / "x").read_text() == "a" and not any((tmp_path / "a").iterdir())


def test_a_kill_between_the_two_renames_is_undone_at_the_next_run(tmp_path, caplog):
    """Without the exchange (a filesystem that lacks it) the old folder is renamed aside before
    the new one takes its place; SIGKILL there left OUT missing and its copy hidden for ever.
    The next run puts it back, and a run that fails leaves it current."""
    out = tmp_path / "out"
    _write(out, "good")
    child = _child("""
        import os, sys, time
        from pathlib import Path
        from densecalib_ros.core.io import safe_write
        safe_write.exchange_paths = lambda a, b: False  # a filesystem without RENAME_EXCHANGE
        rename = os.replace
        def replace(src, dst):
            rename(src, dst)
            if ".old." in Path(dst).name:  # the first of the two renames is done
                print("between", flush=True)
                time.sleep(60)
        os.replace = replace
        safe_write.replace_directory_atomic(
            lambda tmp: (tmp / "calibration.json").write_text("new"), Path(sys.argv[1]))
    """, out)
    _wait_for(child, "between")
    child.send_signal(signal.SIGKILL)
    child.wait(10)
    left = _hidden(tmp_path)  # the old folder aside and the new one not yet in place
    assert not out.exists() and left[0] == f".out.old.{child.pid}", left
    assert len(left) == 2 and left[1].startswith(f".out.tmp.{child.pid}."), left

    def failing(tmp):
        raise RuntimeError("a calibration that failed")
    with caplog.at_level(logging.WARNING), pytest.raises(RuntimeError):
        replace_directory_atomic(failing, out, CALIBRATION_MARKERS)
    assert (out / "calibration.json").read_text() == "good" and _hidden(tmp_path) == []
    assert f"put back {out} (a run was killed while replacing it)" in caplog.text


@pytest.mark.parametrize("sig", [signal.SIGKILL, signal.SIGTERM])
def test_a_run_killed_while_writing_leaves_the_last_output_and_its_leftovers_go(images, tmp_path,
                                                                               sig, caplog):
    """`densecalib calibrate` killed while it writes its folder (SIGKILL: nothing can clean up;
    SIGTERM: timeout's or systemd's stop) leaves the last output as it was; SIGTERM ends with
    exit 143 and no temporary folder, SIGKILL's is removed by the next run."""
    out = tmp_path / "out"
    _write(out, "good")
    child = _child("""
        import sys, time
        from densecalib_ros import cli
        from densecalib_ros.core.io import export
        write = export.write_calibration_files
        def slow(rig, folder, *args, **kwargs):
            write(rig, folder, *args, **kwargs)
            print("writing", flush=True)
            time.sleep(60)
        export.write_calibration_files = slow
        sys.exit(cli.main(["calibrate", "--images", sys.argv[1], "--out", sys.argv[2],
                           "--consensus-runs", "1", "--threads", "1"]))
    """, images, out)
    _wait_for(child, "writing", 240.0)
    leftover = [f for f in _hidden(tmp_path) if f.startswith(f".out.tmp.{child.pid}.")]
    assert len(leftover) == 1, _hidden(tmp_path)
    child.send_signal(sig)
    code = child.wait(60)
    assert (out / "calibration.json").read_text() == "good"
    if sig == signal.SIGTERM:
        assert code == 143 and "terminated (SIGTERM)" in child.stderr.read()
        assert _hidden(tmp_path) == []
        return
    assert _hidden(tmp_path) == leftover
    with caplog.at_level(logging.WARNING):
        _write(out, "next")
    assert (out / "calibration.json").read_text() == "next" and _hidden(tmp_path) == []
    assert f"removed {leftover[0]}" in caplog.text


def test_a_signal_as_the_new_folder_is_made_current_is_said_as_it_ended(images, tmp_path):
    """SIGTERM while the written folder is exchanged with OUT (issue 85, item 3: it used to say
    "what was written before stays as it was" with OUT replaced, and leave a temporary folder):
    the exchange and the old folder's removal end first, and the command says that OUT holds
    the new calibration; exit 143, nothing left beside OUT."""
    out = tmp_path / "out"
    _write(out, "good")
    child = _child("""
        import sys, time
        from densecalib_ros import cli
        from densecalib_ros.core.io import safe_write
        exchange = safe_write.exchange_paths
        def slow(a, b):
            done = exchange(a, b)
            print("exchanged", flush=True)
            time.sleep(2)
            return done
        safe_write.exchange_paths = slow
        sys.exit(cli.main(["calibrate", "--images", sys.argv[1], "--out", sys.argv[2],
                           "--consensus-runs", "1", "--threads", "1"]))
    """, images, out)
    _wait_for(child, "exchanged", 240.0)
    child.send_signal(signal.SIGTERM)
    code = child.wait(60)
    said = child.stderr.read()
    assert code == 143, said
    assert "after the calibration was written: the output holds the new calibration" in said
    assert "stays as it was" not in said
    assert json.loads((out / "calibration.json").read_text())["cameras"]
    assert _hidden(tmp_path) == []


def test_a_recalibration_keeps_what_it_did_not_write(tmp_path, caplog):
    """A new calibration written over an earlier one replaces that calibration's files
    (calibration.json, the camera YAML files, colmap/) and keeps, with a warning, what an
    export or the user put there; a camera no longer in the rig loses its YAML file."""
    out = tmp_path / "out"
    three = generate_rig(RigSpec(lenses="ideal", num_cameras=3, camera_model="RADIAL",
                                 width=320, height=240, num_time_steps=1, seed=2)).ground_truth()
    write_calibration_files(three, out)
    (out / "anipose.toml").write_text("[cam_0]\n")
    (out / "notes").mkdir()
    (out / "notes" / "site.txt").write_text("north fence")
    two = type(three)(three.reference_camera,
                      {n: c for n, c in three.cameras.items() if n != "cam2"})
    with caplog.at_level(logging.WARNING):
        replace_directory_atomic(lambda tmp: write_calibration_files(two, tmp), out,
                                 CALIBRATION_MARKERS, owned=calibration_entries)
    assert sorted(p.name for p in out.iterdir()) == [
        "anipose.toml", "calibration.json", "cam0.yaml", "cam1.yaml", "notes"]
    assert list(json.loads((out / "calibration.json").read_text())["cameras"]) == ["cam0", "cam1"]
    assert (out / "notes" / "site.txt").read_text() == "north fence"
    assert "anipose.toml, notes (files exported from the earlier calibration" in caplog.text


def test_a_model_cut_short_by_a_full_disk_is_not_made_current(images, tmp_path):
    """pycolmap's writer returns normally when a write fails (ENOSPC, or here EFBIG under a
    file-size limit, which truncates the files as a full disk does): the model is read back,
    so `densecalib scale` keeps the good model and says why instead of replacing it with a
    truncated one."""
    import pycolmap

    from densecalib_ros.cli import main

    out = tmp_path / "out"
    assert main(["calibrate", "--images", str(images), "--out", str(out),
                 "--consensus-runs", "1", "--threads", "1"]) == 0
    model = pycolmap.Reconstruction(str(out / "colmap"))
    size = (out / "colmap" / "points3D.bin").stat().st_size
    assert size > 20000, size  # a model the limit below cuts short
    child = _child("""
        import resource, signal, sys
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a failed write, not a killed process
        resource.setrlimit(resource.RLIMIT_FSIZE, (10000, 10000))
        from densecalib_ros import cli
        sys.exit(cli.main(["scale", sys.argv[1], "--baseline", "cam0", "cam1", "0.5"]))
    """, out)
    code = child.wait(120)
    said = child.stderr.read()
    assert code == 0, said  # calibration.json (small) is scaled
    assert "Cannot write the COLMAP model" in said and "keeps its earlier unit" in said
    back = pycolmap.Reconstruction(str(out / "colmap"))
    assert back.num_points3D() == model.num_points3D()
    assert (out / "colmap" / "points3D.bin").stat().st_size == size
    assert _hidden(out) == []


def test_a_write_that_fails_names_the_output_not_its_hidden_temporary_folder(tmp_path):
    """A file that cannot be written while the new folder is built (here EFBIG under a file-size
    limit, as ENOSPC on a full disk) is reported under the output folder's name, with the free
    space, and the last output stays."""
    out = tmp_path / "out"
    _write(out, "good")
    child = _child("""
        import resource, signal, sys
        from pathlib import Path
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (10000, 10000))
        from densecalib_ros.core.errors import InputError
        from densecalib_ros.core.io.safe_write import replace_directory_atomic, write_text_atomic
        try:
            replace_directory_atomic(
                lambda tmp: write_text_atomic(tmp / "calibration.json", "x" * 20000),
                Path(sys.argv[1]), ("calibration.json",))
        except InputError as exc:
            print(exc)
    """, out)
    said, _ = child.communicate(timeout=60)
    assert said.startswith(f"Cannot write {out / 'calibration.json'}: File too large."), said
    assert "MiB free on the disk holding" in said and "Nothing was replaced." in said
    assert ".tmp." not in said
    assert (out / "calibration.json").read_text() == "good" and _hidden(tmp_path) == []


def test_a_second_rename_that_fails_puts_the_old_folder_back(tmp_path, monkeypatch):
    """Without the exchange, the old folder is renamed aside first; when the new one then cannot
    take its place (here EXDEV, as from a folder on another filesystem), the old one goes back at
    once and the error says nothing was replaced."""
    from densecalib_ros.core.io import safe_write

    out = tmp_path / "out"
    _write(out, "good")
    monkeypatch.setattr(safe_write, "exchange_paths", lambda a, b: False)
    rename = os.replace

    def replace(src, dst):
        if ".tmp." in os.path.basename(str(src)):
            raise OSError(18, "Invalid cross-device link")
        rename(src, dst)
    monkeypatch.setattr(os, "replace", replace)
    with pytest.raises(InputError, match="Cannot write .*out: Invalid cross-device link.*"
                                         "Nothing was replaced"):
        _write(out, "new")
    monkeypatch.setattr(os, "replace", rename)
    assert (out / "calibration.json").read_text() == "good" and _hidden(tmp_path) == []
