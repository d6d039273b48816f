"""A folder of calibrations over time: the node's output_dir.

Each calibration goes to `<root>/<UTC time>Z/` (`_1`, `_2`... when several are made within a
second), written whole before it appears (safe_write.replace_directory_atomic), and the `latest`
symlink is then swapped onto it atomically: a reader never sees a half-written calibration, and a
failed calibration leaves `latest` where it was. A field rig that recalibrates on its own (the
node's watch) would fill its disk one calibration at a time (1.2 MB for the demo's 5 cameras,
mostly the reference views and the COLMAP model): prune_calibrations keeps the newest few.
Folders are ordered by their names, the UTC time they were made; on a computer without a
real-time clock that restarts at 1970 after a power cut the order is wrong, but the one `latest`
points to is never removed. Nothing else in the root (a folder a user put there, files) is
touched.
"""
from __future__ import annotations

import os
import re
import shutil
import threading
import time
from pathlib import Path
from typing import Callable, Iterable

from .safe_write import clean_leftovers, replace_directory_atomic

LATEST = "latest"
_CALIBRATION_NAME = re.compile(r"^\d{8}T\d{6}Z(_\d+)?$")  # what write_new_calibration names


def write_new_calibration(root: Path, write: Callable[[Path], None]) -> Path:
    """Make `<root>/<UTC time>Z/` with write(folder) and point `<root>/latest` at it; returns it."""
    root.mkdir(parents=True, exist_ok=True)
    stamp = time.strftime("%Y%m%dT%H%M%S", time.gmtime())
    out, k = root / f"{stamp}Z", 1
    while out.exists():
        out, k = root / f"{stamp}Z_{k}", k + 1
    clean_leftovers(root, lambda name: name == LATEST or bool(_CALIBRATION_NAME.match(name)))
    replace_directory_atomic(lambda tmp: write(Path(tmp)), out)
    out.chmod(0o755)  # created private as a temporary directory
    tmp_link = root / f".{LATEST}.tmp.{os.getpid()}.{threading.get_ident()}"
    tmp_link.unlink(missing_ok=True)
    os.symlink(out.name, tmp_link)
    os.replace(tmp_link, root / LATEST)
    return out


def stored_calibrations(root: Path) -> list[Path]:
    """The calibration folders write_new_calibration made under `root`, oldest first."""
    if not root.is_dir():
        return []
    return sorted((p for p in root.iterdir()
                   if _CALIBRATION_NAME.match(p.name) and p.is_dir() and not p.is_symlink()),
                  key=lambda p: _order(p.name))


def _order(name: str) -> tuple[str, int]:
    stamp, _, k = name.partition("_")
    return stamp, int(k or 0)


def prune_calibrations(root: Path, keep: int, protected: Iterable[Path] = ()) -> list[Path]:
    """Remove all but the newest `keep` calibration folders under `root` (keep <= 0: remove
    nothing); never the one `latest` points to nor those in `protected`. Returns those removed;
    a folder that cannot be removed is left (and not returned)."""
    if keep <= 0:
        return []
    folders = stored_calibrations(root)
    spared = {p.resolve() for p in protected if p is not None}
    if (root / LATEST).exists():
        spared.add((root / LATEST).resolve())
    removed = []
    for folder in folders[:max(len(folders) - keep, 0)]:
        if folder.resolve() in spared:
            continue
        try:
            shutil.rmtree(folder)
        except OSError:
            continue
        removed.append(folder)
    return removed
