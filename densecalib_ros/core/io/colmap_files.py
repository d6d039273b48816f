"""A COLMAP binary model checked record by record before pycolmap reads it.

pycolmap's reader takes every count in the files at its word: it reserves memory for a track
length or a number of 2D points before reading them, and past the end of a file cut short it
reads garbage counts. A points3D.bin cut short by a full disk took 17 GB before std::bad_alloc
(issue 85). model_problem walks each file's records, checks every count against the bytes left
in the file before stepping over what it counts, and names the first record that does not fit;
it touches the file through a read-only memory map and allocates nothing per record, so a
damaged model costs no more memory than its size. The layouts are COLMAP's
(src/colmap/scene/reconstruction_io_binary.cc), little-endian.
"""
from __future__ import annotations

import mmap
import struct
from pathlib import Path
from typing import Callable, Optional

_U32 = struct.Struct("<I")
_U64 = struct.Struct("<Q")
_POSE_BYTES = 7 * 8  # quaternion (w, x, y, z) and translation, doubles


class _Damage(Exception):
    """Where a file stops matching its layout (a message for model_problem)."""


class _Cursor:
    """Reading position in one file's bytes; every step checks that the bytes are there."""

    def __init__(self, data, name: str):
        self.data, self.name, self.pos = data, name, 0

    def left(self) -> int:
        return len(self.data) - self.pos

    def skip(self, size: int, what: str) -> None:
        if size > self.left():
            raise _Damage(f"{self.name}: {what} needs {size} bytes at byte {self.pos}, "
                          f"{self.left()} are left")
        self.pos += size

    def u32(self, what: str) -> int:
        start = self.pos
        self.skip(4, what)
        return _U32.unpack_from(self.data, start)[0]

    def u64(self, what: str) -> int:
        start = self.pos
        self.skip(8, what)
        return _U64.unpack_from(self.data, start)[0]

    def count(self, what: str, least_bytes_each: int, wide: bool = True) -> int:
        """A count (uint64, or uint32 where not wide) of `what`, records of at least
        least_bytes_each bytes: refused when the bytes left cannot hold that many (the check
        pycolmap does not make)."""
        n = self.u64(f"the number of {what}") if wide else self.u32(f"the number of {what}")
        if n * least_bytes_each > self.left():
            raise _Damage(f"{self.name} claims {n} {what} at byte {self.pos}; the "
                          f"{self.left()} bytes left hold at most "
                          f"{self.left() // least_bytes_each}")
        return n

    def string(self, what: str) -> None:
        end = self.data.find(b"\0", self.pos)
        if end < 0:
            raise _Damage(f"{self.name}: {what} at byte {self.pos} has no end")
        self.pos = end + 1


def _camera_params(model_id: int) -> Optional[int]:
    """How many parameters COLMAP's camera model `model_id` has (None: no such model)."""
    import pycolmap

    known = {int(m.value): m for name, m in pycolmap.CameraModelId.__members__.items()
             if name != "INVALID"}
    if model_id not in known:
        return None
    return len(pycolmap.Camera.create_from_model_id(1, known[model_id], 1.0, 1, 1).params)


def _cameras(c: _Cursor) -> None:
    for _ in range(c.count("cameras", 24)):
        c.skip(4, "a camera id")
        model_id = c.u32("a camera model")
        num_params = _camera_params(model_id)
        if num_params is None:
            raise _Damage(f"{c.name}: camera model id {model_id} at byte {c.pos - 4} is not "
                          "one COLMAP has")
        c.skip(16 + 8 * num_params, "a camera's size and parameters")


def _images(c: _Cursor) -> None:
    for _ in range(c.count("images", 64 + 1 + 8)):
        c.skip(64, "an image's id, pose and camera")
        c.string("an image name")
        c.skip(24 * c.count("2D points", 24), "an image's 2D points")


def _points3d(c: _Cursor) -> None:
    for _ in range(c.count("points", 51)):
        c.skip(43, "a point's id, position, colour and error")
        c.skip(8 * c.count("track elements", 8), "a point's track")


def _rigs(c: _Cursor) -> None:
    for _ in range(c.count("rigs", 8)):
        c.skip(4, "a rig id")
        num_sensors = c.count("sensors", 8, wide=False)
        if num_sensors:
            c.skip(8, "a rig's reference sensor")
        for _ in range(max(num_sensors - 1, 0)):
            c.skip(8, "a sensor id")
            has_pose = c.data[c.pos] if c.left() else None
            c.skip(1, "a sensor's pose flag")
            if has_pose:
                c.skip(_POSE_BYTES, "a sensor's pose")


def _frames(c: _Cursor) -> None:
    for _ in range(c.count("frames", 68)):
        c.skip(8 + _POSE_BYTES, "a frame's ids and pose")
        c.skip(16 * c.count("data ids", 16, wide=False), "a frame's data ids")


_LAYOUTS: dict[str, Callable[[_Cursor], None]] = {
    "rigs.bin": _rigs, "cameras.bin": _cameras, "frames.bin": _frames, "images.bin": _images,
    "points3D.bin": _points3d}


def file_problem(path: Path) -> Optional[str]:
    """What makes one COLMAP binary file unreadable as its layout (named by the file name):
    a count its bytes cannot hold, a record cut short, bytes after its last record; None when
    it reads whole."""
    walk = _LAYOUTS[path.name]
    try:
        with open(path, "rb") as f:
            size = path.stat().st_size
            if size == 0:
                return f"{path.name} is empty"
            with mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as data:
                cursor = _Cursor(data, path.name)
                walk(cursor)
                if cursor.left():
                    return (f"{path.name} holds {cursor.left()} bytes after its last record "
                            f"(of {size})")
    except _Damage as exc:
        return str(exc)
    except (OSError, ValueError) as exc:
        return f"{path.name} cannot be read ({exc})"
    return None


def model_problem(model: str | Path) -> Optional[str]:
    """The first problem of the COLMAP binary model in folder `model` (file_problem of each of
    its .bin files that is there), or None: pycolmap.Reconstruction may read it."""
    model = Path(model)
    for name in _LAYOUTS:
        if (model / name).is_file():
            problem = file_problem(model / name)
            if problem:
                return problem
    return None
