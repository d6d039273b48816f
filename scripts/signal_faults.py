"""Ctrl-C and SIGTERM at random instants of `densecalib calibrate` (issue 85, item 2): the only exit
codes must be 130 and 143 (or 0 where the run ended first), with no traceback, abort or crash
report, and the output folder as it was unless the run said it wrote a new one.

    python scripts/signal_faults.py [--runs 100] [--seed 0]

Each run calibrates a generated 4-camera rig (two frame sets, 640x480) over an earlier output, and
its process group gets SIGINT or SIGTERM at a uniformly random instant within the time a whole run
takes here (measured first). Prints one line per run and a summary."""
from __future__ import annotations

import argparse
import hashlib
import os
import random
import signal
import subprocess
import sys
import tempfile
import time
from collections import Counter
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
CRASH_TEXT = ("Traceback", "terminate called", "Aborted", "*** ", "SystemError", "Fatal Python")
EXPECTED = {signal.SIGINT: 130, signal.SIGTERM: 143}


def _digest(folder: Path) -> str:
    h = hashlib.sha256()
    for path in sorted(p for p in folder.rglob("*") if p.is_file()):
        h.update(str(path.relative_to(folder)).encode())
        h.update(path.read_bytes())
    return h.hexdigest()


def _calibrate(images: Path, out: Path) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, "-m", "densecalib_ros.cli", "calibrate", "--images",
                             str(images), "--out", str(out)], cwd=REPO, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True, start_new_session=True)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--runs", type=int, default=100)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    sys.path.insert(0, str(REPO))
    from densecalib_ros.core import RigSpec, generate_rig
    from densecalib_ros.core.synthetic import write_rig

    rng = random.Random(args.seed)
    base = Path(tempfile.mkdtemp(prefix="signal_faults."))
    write_rig(generate_rig(RigSpec(lenses="ideal", num_cameras=4, width=640, height=480,
                                   num_time_steps=2, seed=1)), base / "images")
    out = base / "out"
    started = time.perf_counter()
    first = _calibrate(base / "images", out)
    assert first.wait() == 0, first.stderr.read()
    whole_s = time.perf_counter() - started
    print(f"a whole run takes {whole_s:.1f} s here; signals within it")
    codes, crashes, changed = Counter(), [], []
    for k in range(args.runs):
        sig = rng.choice([signal.SIGINT, signal.SIGTERM])
        delay = rng.uniform(0.0, whole_s)
        before = _digest(out)
        child = _calibrate(base / "images", out)
        time.sleep(delay)
        if child.poll() is None:
            os.killpg(child.pid, sig)
        code = child.wait(120)
        said = child.stderr.read()
        codes[(sig.name, code)] += 1
        crash = [c for c in CRASH_TEXT if c in said]
        wrote = code == 0 or "holds the new calibration" in said
        if crash or code not in (0, EXPECTED[sig]):
            crashes.append((k, sig.name, round(delay, 2), code, crash, said[-400:]))
        if not wrote and _digest(out) != before:
            changed.append((k, sig.name, round(delay, 2), code))
        leftovers = [p.name for p in base.iterdir() if p.name.startswith(".out.")]
        print(f"run {k + 1:3d}: {sig.name} at {delay:5.2f} s -> exit {code}"
              + (f"  CRASH {crash}" if crash else "") + (f"  leftovers {leftovers}"
                                                          if leftovers else ""), flush=True)
    print("exit codes:", dict(codes))
    print(f"runs with a wrong exit code or crash text: {len(crashes)}")
    for entry in crashes:
        print("  ", entry)
    print(f"runs that changed OUT without saying so: {len(changed)}", changed)
    return 1 if crashes or changed else 0


if __name__ == "__main__":
    sys.exit(main())
