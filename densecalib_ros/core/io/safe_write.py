"""Writes that never leave a half-written file or folder, and never replace what they must not.

A file is written to a temporary sibling and renamed into place (write_text_atomic); a set of
files (one per camera) is written whole to temporaries before any is renamed
(write_files_atomic), so that a failed write replaces none of them. A folder of
outputs is built beside its target and exchanged with it in one step (replace_directory_atomic:
renameat2 RENAME_EXCHANGE, else two renames whose gap the next run repairs). What a killed write
leaves (`.<name>.tmp.<pid>.*`, `.<name>.old.<pid>`) is removed, or put back, once its process is
gone (clean_leftovers). Output folders are checked to be safe to replace first
(check_output_folder).
"""
from __future__ import annotations

import contextlib
import functools
import logging
import os
import re
import shutil
import tempfile
from pathlib import Path
from typing import Callable, ContextManager, Optional, Sequence

from ..errors import InputError
from ..parallel import is_running

log = logging.getLogger(__name__)


def _umask() -> int:
    """The process umask, read without setting it (os.umask would, racing other threads)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    return 0o022


def _usual_mode(path: Path, directory: bool = False) -> int:
    """The mode an ordinary open()/mkdir would give `path` (its own when it exists): mkstemp and
    mkdtemp make owner-only files and folders, which drivers, camera_info_manager or colleagues
    running as another user could not read."""
    try:
        return path.stat().st_mode & 0o7777
    except OSError:
        return (0o777 if directory else 0o666) & ~_umask()


def write_text_atomic(path: str | os.PathLike, text: str | bytes) -> None:
    """Write `text` (or bytes) to a temporary sibling of path, then rename it into place: a
    reader never sees a half-written file."""
    path, tmp = Path(path), None
    try:
        tmp = _write_temporary(path, text)
        os.replace(tmp, path)
    except BaseException as exc:
        if tmp is not None:
            Path(tmp).unlink(missing_ok=True)
        if isinstance(exc, OSError):
            raise InputError(f"Cannot write {path}: {exc.strerror or exc}. "
                             + disk_hint(path.parent)) from exc
        raise


def write_files_atomic(files: dict) -> None:
    """Write several files ({path: text or bytes}) as one set: every file is written whole to
    a temporary sibling first, and only then are they renamed into place, so that a write that
    fails (a full disk) replaces none of them and a reader never finds old and new files mixed.
    A rename that fails after others were done (the folder's permissions changed under us)
    raises an InputError naming the files replaced and those left as they were."""
    written: list[tuple[Path, str]] = []
    try:
        for path, text in files.items():
            path = Path(path)
            written.append((path, _write_temporary(path, text)))
    except BaseException as exc:
        for _, tmp in written:
            Path(tmp).unlink(missing_ok=True)
        if isinstance(exc, OSError):
            raise InputError(f"Cannot write {path}: {exc.strerror or exc}. "
                             + disk_hint(path.parent) + " Nothing was replaced.") from exc
        raise
    replaced: list[Path] = []
    try:
        for path, tmp in written:
            os.replace(tmp, path)
            replaced.append(path)
    except BaseException as exc:
        for _, tmp in written[len(replaced):]:
            Path(tmp).unlink(missing_ok=True)
        kept = [str(p) for p, _ in written[len(replaced):]]
        said = (f"replaced: {', '.join(map(str, replaced)) or 'none'}; as they were: "
                f"{', '.join(kept)}")
        if isinstance(exc, OSError):
            raise InputError(f"Cannot replace {kept[0]}: {exc.strerror or exc}; {said}. "
                             "Write them again.") from exc
        if replaced:
            log.error("stopped while replacing files: %s", said)
        raise


def _write_temporary(path: Path, text: str | bytes) -> str:
    """Write `text` (or bytes) whole to a new temporary sibling of path, with the mode an
    ordinary write would give path; returns its name. Nothing is left behind on failure."""
    tmp = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        clean_leftovers(path.parent, lambda name: name == path.name)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.tmp.{os.getpid()}.", dir=path.parent)
        with os.fdopen(fd, "wb" if isinstance(text, bytes) else "w") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, _usual_mode(path))
        return tmp
    except BaseException:
        if tmp is not None:
            Path(tmp).unlink(missing_ok=True)
        raise


def disk_hint(path: Path) -> str:
    """What to check after a write failed: the disk's free space, if it can be told."""
    folder = next((p for p in [path, *path.parents] if p.exists()), None)
    try:
        free_mib = shutil.disk_usage(folder).free / 2**20
    except (OSError, TypeError):
        return "Check that the folder is writable and the disk has room."
    return (f"Check that the folder is writable and the disk has room ({free_mib:.0f} MiB free "
            f"on the disk holding {folder}).")


def check_output_folder(out_dir: str | os.PathLike, markers: Sequence[str],
                        inputs: Sequence[str | os.PathLike] = ()) -> Path:
    """The resolved out_dir, after making sure that replacing it as a whole loses nothing: raises
    InputError when it is empty, a file, the current folder or one holding it, holds one of
    `inputs` (or is one), or is a folder with contents but none of `markers` (the files by
    which a command knows its own earlier output: calibration.json, sync.json). A user's own
    folder is never emptied."""
    if not str(out_dir).strip():
        raise InputError("The output folder is empty (''): give a folder to write, e.g. "
                         "--out calib.")
    out = Path(out_dir).resolve()
    if out.exists() and not out.is_dir():
        raise InputError(f"{out_dir} is a file, not a folder: give a new folder to write.")
    for given in inputs:
        source = Path(given).resolve()
        if source == out or out in source.parents:
            what = "is" if source == out else "holds"
            raise InputError(f"The output folder {out_dir} {what} the input {given}: writing "
                             f"it would replace the input. Give another folder, e.g. "
                             f"{out}_out.")
    if out.is_dir() and any(out.iterdir()) and not any((out / m).exists() for m in markers):
        raise InputError(f"{out_dir} exists and is not an earlier output of this command (no "
                         f"{' or '.join(markers)} in it): writing there would replace all it "
                         "holds. Give a new or empty folder, or remove this one first.")
    here = Path.cwd().resolve()
    if here == out or out in here.parents:
        raise InputError(f"{out_dir} is the folder you are in (or holds it): it is replaced as a "
                         "whole, which would leave your shell in a folder that no longer "
                         f"exists. Run the command from outside it (cd {out.parent}).")
    parent = next(p for p in out.parents if p.exists())  # the folder written into (swap)
    if not parent.is_dir() or not os.access(parent, os.W_OK | os.X_OK):
        raise InputError(f"Cannot write {out_dir}: {parent} is not a writable folder. Give a "
                         "folder you can write to.")
    return out


def replace_directory_atomic(build, out_dir: str | os.PathLike,
                             markers: Optional[Sequence[str]] = None,
                             inputs: Sequence[str | os.PathLike] = (),
                             owned: Optional[Callable[[Path], set]] = None,
                             commit_guard: Callable[[], ContextManager] = contextlib.nullcontext
                             ) -> None:
    """Call build(tmp_dir) to fill a fresh temporary sibling of out_dir, then make it out_dir in
    one step: the two folders are exchanged atomically where the filesystem can (Linux
    renameat2), else renamed twice, and an old copy a kill left between the two renames is put
    back at the next run. If build raises, out_dir is untouched. With `markers`, out_dir is
    first checked to be safe to replace (check_output_folder; commands check before their work
    too, to fail early). With `owned(out_dir)`, the names in the old out_dir that the command
    writes: every other entry build did not write (an export, a user's notes) is copied into
    the new folder, and named once at WARNING. commit_guard(): a context held while the new
    folder is made out_dir and the old one removed (the command's: signals wait for it, so that
    what it says after a signal is what out_dir holds)."""
    if markers is not None:
        check_output_folder(out_dir, markers, inputs)
    out_dir = Path(out_dir).resolve()
    clean_leftovers(out_dir.parent, lambda name: name == out_dir.name)
    tmp, building, old = None, None, None
    try:
        out_dir.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.tmp.{os.getpid()}.",
                                    dir=out_dir.parent))
        building = str(tmp)
        os.chmod(tmp, _usual_mode(out_dir, directory=True))
        build(tmp)
        if owned is not None and out_dir.is_dir():
            _carry_over(out_dir, tmp, owned(out_dir))
        with commit_guard():
            if out_dir.exists() and exchange_paths(tmp, out_dir):
                old, tmp = tmp, None  # tmp now holds the previous folder
            else:
                if out_dir.exists():
                    old = out_dir.with_name(f".{out_dir.name}.old.{os.getpid()}")
                    os.replace(out_dir, old)
                os.replace(tmp, out_dir)
                tmp = None
            if old is not None:
                shutil.rmtree(old, ignore_errors=True)
                old = None
    except BaseException as exc:
        if old is not None and tmp is not None and not out_dir.exists():
            os.replace(old, out_dir)  # the second rename failed: the old folder goes back
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
        if isinstance(exc, OSError):
            raise InputError(f"Cannot write {out_dir}: {exc.strerror or exc}. "
                             + disk_hint(out_dir) + " Nothing was replaced.") from exc
        if isinstance(exc, InputError) and building and building in str(exc):
            # a file of the hidden temporary folder, named as the user knows it
            raise InputError(str(exc).replace(building, str(out_dir))
                             + " Nothing was replaced.") from exc
        raise


def _carry_over(old_dir: Path, new_dir: Path, owned: set) -> None:
    kept = []
    for entry in sorted(old_dir.iterdir()):
        if entry.name in owned or (new_dir / entry.name).exists():
            continue
        if entry.is_dir() and not entry.is_symlink():
            shutil.copytree(entry, new_dir / entry.name, symlinks=True)
        else:
            shutil.copy2(entry, new_dir / entry.name, follow_symlinks=False)
        kept.append(entry.name)
    if kept:
        log.warning("kept in %s what this command does not write: %s (files exported from the "
                    "earlier calibration follow it, not this one: export them again)",
                    old_dir, ", ".join(kept))


_RENAME_EXCHANGE = 2  # linux/fs.h


@functools.lru_cache(maxsize=1)
def _renameat2():
    """libc's renameat2, or None (not Linux, an old C library)."""
    import ctypes

    try:
        return ctypes.CDLL(None, use_errno=True).renameat2
    except (OSError, AttributeError):
        return None


def exchange_paths(a: Path, b: Path) -> bool:
    """Swap two paths atomically (renameat2 RENAME_EXCHANGE); False where the system or the
    filesystem cannot, so that the caller renames instead."""
    renameat2, at_fdcwd = _renameat2(), -100
    return renameat2 is not None and renameat2(at_fdcwd, os.fsencode(a), at_fdcwd,
                                               os.fsencode(b), _RENAME_EXCHANGE) == 0


# what a write killed part-way leaves beside its target: `.<name>.tmp.<pid>.<any>` (a folder or
# file being written) and `.<name>.old.<pid>` (a folder being replaced)
_LEFTOVER = re.compile(r"^\.(?P<name>.+)\.(?P<kind>tmp|old)\.(?P<pid>\d+)(\..*)?$")


def clean_leftovers(parent: Path, targets: Callable[[str], bool]) -> None:
    """Remove from `parent` what writes of the targets it names left when their process was
    killed (one no longer running); an old copy whose folder is missing (killed between two
    renames) is put back first. Said once at WARNING."""
    try:
        entries = list(parent.iterdir())
    except OSError:
        return
    done = []
    for entry in sorted(entries, key=lambda e: e.name):
        m = _LEFTOVER.match(entry.name)
        if not m or not targets(m["name"]) or is_running(int(m["pid"])):
            continue
        target = parent / m["name"]
        try:
            if m["kind"] == "old" and not target.exists() and not target.is_symlink():
                os.replace(entry, target)
                done.append(f"put back {target} (a run was killed while replacing it)")
                continue
            if entry.is_dir() and not entry.is_symlink():
                shutil.rmtree(entry)
            else:
                entry.unlink()
            done.append(f"removed {entry.name}")
        except OSError:
            continue
    if done:
        log.warning("left by runs killed while writing in %s: %s", parent, "; ".join(done))
