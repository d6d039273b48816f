"""An export of one file per camera is all or nothing: under a file-size limit that lets some of
its files through (a disk filling up), `densecalib export --format opencv` over an earlier export
left cam0.yml new and the others old, exit 2, without saying so (issue 85 item 4). Now every file
is written whole before any is replaced: the earlier export stays as it was, and no temporary
file is left."""
import os
import subprocess
import sys

import pytest

from densecalib_ros.core.io.export import write_calibration_files
from densecalib_ros.core.synthetic import RigSpec, generate_rig

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _export(calibration, out, file_size=None):
    """(exit code, output) of `densecalib export CALIBRATION --format opencv --out OUT`, under
    `prlimit --fsize=file_size` when given."""
    env = {**os.environ, "PYTHONPATH": REPO + os.pathsep + os.environ.get("PYTHONPATH", "")}
    limit = ["prlimit", f"--fsize={file_size}"] if file_size else []
    done = subprocess.run([*limit, sys.executable, "-m", "densecalib_ros.cli", "export",
                           str(calibration), "--format", "opencv", "--out", str(out)],
                          capture_output=True, text=True, env=env, timeout=120)
    return done.returncode, done.stdout + done.stderr


def _files(folder):
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


@pytest.fixture(scope="module")
def calibrations(tmp_path_factory):
    root = tmp_path_factory.mktemp("cals")
    for seed in (1, 2):
        rig = generate_rig(RigSpec(lenses="real", num_cameras=4, camera_model="RADIAL",
                                   width=320, height=240, seed=seed))
        write_calibration_files(rig.ground_truth(), root / f"cal{seed}")
    return root / "cal1", root / "cal2"


def test_an_export_that_fails_part_way_replaces_none_of_the_earlier_files(calibrations,
                                                                          tmp_path):
    old, new = calibrations
    out = tmp_path / "opencv"
    assert _export(old, out)[0] == 0
    before = _files(out)
    assert _export(new, tmp_path / "sizes")[0] == 0
    sizes = sorted(len(text) for text in _files(tmp_path / "sizes").values())
    assert sizes[0] < sizes[-1], sizes  # a limit between them lets some files through
    rc, said = _export(new, out, file_size=sizes[0])
    assert rc == 2, said
    changed = sorted(name for name, text in _files(out).items() if before.get(name) != text)
    assert changed == [], changed  # every camera's file as the earlier export wrote it
    assert "Nothing was replaced." in said and "Traceback" not in said
    assert _export(new, out)[0] == 0
    after = _files(out)
    assert after == _files(tmp_path / "sizes") and all(after[n] != before[n] for n in after)


def test_an_export_into_another_calibration_is_refused(calibrations, tmp_path):
    """JARVIS writes <camera>.yaml per camera: into another calibration's folder they would replace
    its camera_info YAMLs. Refused, that calibration untouched; a single-file path ending in a
    separator (a folder meant) is refused too."""
    old, new = calibrations
    before = _files(new)
    env = {**os.environ, "PYTHONPATH": REPO + os.pathsep + os.environ.get("PYTHONPATH", "")}
    for fmt, out in (("jarvis", new), ("anipose", tmp_path / "folder_meant" / "")):
        done = subprocess.run([sys.executable, "-m", "densecalib_ros.cli", "export", str(old),
                               "--format", fmt, "--out", str(out) + ("/" if fmt == "anipose"
                                                                      else "")],
                              capture_output=True, text=True, env=env, timeout=120)
        said = done.stdout + done.stderr
        assert done.returncode == 2, said
        assert ("is a file of the calibration" if fmt == "jarvis" else "is a folder") in said
        assert "Traceback" not in said
    assert _files(new) == before and not (tmp_path / "folder_meant").exists()
