"""Reading a rig's images from a folder.

Two layouts:
- flat: DIR holds one image per camera; the file stem is the camera name (one frame set);
- per camera: DIR holds one subfolder per camera (folder name = camera name) with time-aligned
  images. How the images form frame sets (`align`):
  - "name": by file stem (the stems every camera has; others are named in a warning);
  - "order": by sorted position; cameras with more images than the others contribute evenly
    spaced ones (the k-th set is not the same moment in every camera: right for a static scene,
    where only the rig and the background matter);
  - "time": by EXIF capture time (camera traps, which each fire on their own): every image of the
    camera with the fewest images opens a set, with each other camera's image nearest in time,
    kept when all lie within max_time_gap_s; time_offsets_s[name] is how far that camera's clock
    runs ahead of the others' (s);
  - "auto" (default): "name" when at least half the stems are in every camera (dropped frames),
    else "order" when the counts agree, else an error that names the two other choices.
Hidden entries and files that are not images (by extension) are ignored.
"""
from __future__ import annotations

import logging
import os
import re
from pathlib import Path
from typing import Optional, Sequence

import cv2
import numpy as np

from ..errors import InputError, TooFewCamerasGivenError
from ..types import check_camera_names
from .file_kinds import IMAGE_EXTENSIONS, VIDEO_EXTENSIONS
from .image_encoding import to_pipeline_image
from .sync import evenly_spaced

log = logging.getLogger(__name__)

ALIGNMENTS = ("auto", "name", "order", "time")
DEFAULT_MAX_TIME_GAP_S = 2.0  # a burst of trail-camera shots spans about this


def jpeg_truncated(data: bytes) -> bool:
    """Whether a JPEG file's data lacks the end-of-image marker after its main image's scan data
    (OpenCV decodes the rest as grey with only a libjpeg warning). The segments before the first
    scan are skipped by their lengths: an EXIF thumbnail inside them has its own end marker.
    Data after the end marker (a phone's motion-photo video) is allowed."""
    pos = 2  # after SOI
    while pos + 4 <= len(data) and data[pos] == 0xFF:
        marker = data[pos + 1]
        if marker == 0xFF:  # fill byte
            pos += 1
            continue
        if marker == 0xDA:  # start of scan: the image data follows
            return data.find(b"\xff\xd9", pos) < 0
        if 0xD0 <= marker <= 0xD8 or marker == 0x01:  # markers without a length
            pos += 2
            continue
        pos += 2 + int.from_bytes(data[pos + 2:pos + 4], "big")
    return False  # not a layout this reads: leave it to the decoder


def read_file_bytes(path: str | os.PathLike, what: str) -> bytes:
    """A file's bytes, read by Python (cv2.imread crashes on a path of non-UTF-8 bytes);
    InputError naming the file when it cannot be read."""
    try:
        return Path(path).read_bytes()
    except OSError as exc:
        raise InputError(f"Cannot read {what} {path}: {exc.strerror}.") from exc


def decode_file_bytes(data: bytes, flags: int) -> Optional[np.ndarray]:
    """cv2.imdecode of an image file's bytes (EXIF orientation applied as imread does); None
    when they do not decode."""
    return cv2.imdecode(np.frombuffer(data, np.uint8), flags) if data else None


def read_image(path: str | os.PathLike) -> np.ndarray:
    """(H, W, 3) uint8 RGB of an image file (EXIF orientation applied); InputError naming the file
    if it cannot be read. 16-bit files (machine-vision cameras save 10-14-bit data in them) are
    shifted down by their used bit depth, as ROS mono16 images are: OpenCV's own 8-bit
    conversion divides by 256 and leaves a 12-bit image nearly black."""
    data = read_file_bytes(path, "image")
    if Path(path).suffix.lower() in (".jpg", ".jpeg") and jpeg_truncated(data):
        raise InputError(f"{path} is a truncated JPEG (a copy or transfer cut it short): its "
                         "lower part is missing and would be read as grey. Copy it again, or "
                         "remove it.")
    bgr = decode_file_bytes(data, cv2.IMREAD_COLOR | cv2.IMREAD_ANYDEPTH)
    if bgr is None or bgr.size == 0:
        raise InputError(f"Cannot read image {path}: it is missing, empty or not an image "
                         f"format OpenCV can decode. Replace or remove the file.")
    if bgr.dtype not in (np.uint8, np.uint16):  # float TIFF / EXR: its own range, to 0..255
        top = float(np.nanmax(bgr)) if np.isfinite(bgr).any() else 0.0
        bgr = np.clip(np.nan_to_num(bgr) * (255.0 / top if top > 0 else 0.0), 0, 255)
        bgr = bgr.astype(np.uint8)
    return to_pipeline_image(bgr, "bgr")


def _images_in(directory: Path) -> list[Path]:
    return sorted(p for p in directory.iterdir() if p.is_file() and not p.name.startswith(".")
                  and p.suffix.lower() in IMAGE_EXTENSIONS)


def camera_image_files(directory: str | os.PathLike, name: str) -> list[Path]:
    """Every image file of camera `name` in DIR, in either layout: DIR/<name>/* or DIR/<name>.*"""
    directory = Path(directory)
    if (directory / name).is_dir():
        return _images_in(directory / name)
    return [p for p in _images_in(directory) if p.stem == name] if directory.is_dir() else []


# Files a camera may well have written that are not read as images: skipped with a warning, so
# that a camera does not vanish from the rig unnoticed.
_UNREADABLE_KINDS = {**dict.fromkeys((".heic", ".heif", ".avif"), "convert it to JPEG or PNG"),
                     **dict.fromkeys((".dng", ".cr2", ".cr3", ".nef", ".arw", ".raw", ".orf",
                                      ".rw2"), "a raw photo: develop it to PNG or JPEG"),
                     **dict.fromkeys(VIDEO_EXTENSIONS, "a video: give video folders with --videos")}


def _warn_about_skipped(directory: Path, subdirs: list[Path]) -> None:
    """Warn of what in DIR looks meant as a camera but is not read: an image format OpenCV does
    not decode, a video, a broken link, a hidden image file, a camera subfolder without
    images."""
    skipped = []
    for p in sorted(directory.iterdir()):
        if p.name.startswith("."):
            # Hidden files are not read; one that is an image was meant as a camera (`...png`).
            if p.is_file() and p.suffix.lower() in IMAGE_EXTENSIONS:
                skipped.append(f"{p.name} (a hidden file: rename it without the leading '.')")
            continue
        if p.is_symlink() and not p.exists():
            skipped.append(f"{p.name} (a broken link)")
        elif p.is_file() and p.suffix.lower() in _UNREADABLE_KINDS:
            skipped.append(f"{p.name} ({_UNREADABLE_KINDS[p.suffix.lower()]})")
    skipped += [f"{d.name}/ (no images in it)" for d in subdirs if not _images_in(d)]
    if skipped:
        log.warning("skipped in %s: %s", directory, "; ".join(skipped))


def list_image_folder(directory: str | os.PathLike, align: str = "auto",
                      time_offsets_s: Optional[dict[str, float]] = None,
                      max_time_gap_s: float = DEFAULT_MAX_TIME_GAP_S,
                      without: Sequence[str] = ()) -> tuple[list[list[Path]], list[str]]:
    """The image files of DIR per frame set and camera (layouts and `align`: module docstring);
    the cameras named in `without` (subfolders or file stems) are left out.

    Returns (paths, camera_names) with paths[t][c] the file of camera c at time t. Raises
    InputError for a missing/ambiguous/misaligned folder, a camera subfolder without images
    (unless `without` names it: a rig that silently lost a camera is not what was asked for),
    the numbered frames of one camera given as the rig's folder, and TooFewCamerasGivenError (an
    InputError) for < 2 cameras.
    """
    if align not in ALIGNMENTS:
        raise InputError(f"Unknown image alignment {align!r}: use one of {', '.join(ALIGNMENTS)}.")
    directory = Path(directory)
    if not directory.is_dir():
        raise InputError(f"Image folder {directory} does not exist or is not a folder.")
    files = _images_in(directory)
    subdirs = sorted(p for p in directory.iterdir() if p.is_dir() and not p.name.startswith("."))
    files, subdirs = _leave_out(directory, files, subdirs, without)
    _refuse_empty_camera_folders(directory, files, subdirs)
    _warn_about_skipped(directory, subdirs)
    subdirs = [d for d in subdirs if _images_in(d)]
    if files and subdirs:
        raise InputError(
            f"{directory} mixes image files ({files[0].name}, ...) and camera subfolders "
            f"({subdirs[0].name}, ...): use one image per camera OR one subfolder per camera.")
    if files:
        _refuse_frames_of_one_camera(directory, files)
        _refuse_alignment_of_one_set(directory, align, time_offsets_s)
        names = [p.stem for p in files]
        duplicate = sorted({n for n in names if names.count(n) > 1})
        if duplicate:
            raise InputError(f"Several images in {directory} share the camera name(s) "
                             f"{', '.join(duplicate)} (file stem): keep one image per camera.")
        paths, names = [files], names
    elif subdirs:
        names = [d.name for d in subdirs]
        paths = _align(directory, names, [_images_in(d) for d in subdirs], align,
                       time_offsets_s or {}, max_time_gap_s)
    else:
        raise InputError(f"No images ({', '.join(IMAGE_EXTENSIONS)}) in {directory} or in its "
                         "subfolders: put one image per camera (file name = camera name) or one "
                         "subfolder per camera there.")
    check_camera_names(names)
    if len(names) < 2:
        raise TooFewCamerasGivenError(
            f"Found only one camera ({names[0]}) in {directory}: a rig calibration needs images "
            "of at least two cameras (one file per camera, or one subfolder per camera).")
    return paths, names


def _refuse_alignment_of_one_set(directory: Path, align: str,
                                 time_offsets_s: Optional[dict[str, float]]) -> None:
    """InputError where an alignment (or clock offsets) is asked of DIR's one image per camera:
    one frame set has nothing to pair, and the options would be ignored unsaid."""
    asked = ([f"--align {align}"] if align != "auto" else []) + \
        (["--time-offset"] if time_offsets_s else [])
    if asked:
        raise InputError(f"{directory} holds one image per camera (a single frame set), so "
                         f"there is nothing to pair: {' and '.join(asked)} belong(s) to camera "
                         "subfolders of images. Leave them out, or give one subfolder per camera.")


def _leave_out(directory: Path, files: list[Path], subdirs: list[Path], without: Sequence[str]
               ) -> tuple[list[Path], list[Path]]:
    """files and subdirs less the cameras named in `without`; InputError for a name that is
    no camera of DIR (a typo would otherwise leave out nothing)."""
    known = {d.name for d in subdirs} | {p.stem for p in files}
    unknown = [n for n in without if n not in known]
    if unknown:
        raise InputError(f"--without {' '.join(unknown)}: {directory} has no camera "
                         f"{', '.join(unknown)} (its cameras: {', '.join(sorted(known))}).")
    if without:
        log.info("left out as asked (--without): %s", ", ".join(without))
    return ([p for p in files if p.stem not in without],
            [d for d in subdirs if d.name not in without])


def _refuse_empty_camera_folders(directory: Path, files: list[Path], subdirs: list[Path]) -> None:
    """InputError naming the camera subfolders without images among others with images: that
    camera would be left out of the rig, and a calibration written over an earlier one would
    drop its files (a copy that failed, a card not yet read)."""
    empty = [d for d in subdirs if not _images_in(d)]
    if not empty or files or len(empty) == len(subdirs):
        return
    held = [f"{d}/ ({_what_it_holds(d)})" for d in empty]
    raise InputError(
        f"Camera folder{'s' if len(empty) > 1 else ''} {'; '.join(held)} without images: the rig "
        f"would be calibrated without {', '.join(d.name for d in empty)}. Put the camera's "
        f"images there, or say to calibrate without it: --without "
        f"{' '.join(d.name for d in empty)}.")


def _what_it_holds(folder: Path) -> str:
    others = sorted(p.name for p in folder.iterdir() if not p.name.startswith("."))
    if not others:
        return "empty"
    return (f"no image files ({', '.join(IMAGE_EXTENSIONS)}); it holds {len(others)} other "
            f"entr{'y' if len(others) == 1 else 'ies'}, e.g. {others[0]}")


# A run of this many digits at the end of a file stem is a frame counter or a time stamp (0000,
# IMG_1234, frame_000123), not a camera's name (cam0 .. cam12).
_FRAME_NUMBER_DIGITS = 3
_NUMBERED = re.compile(
    rf"^(?P<head>.*?)(?P<number>\d{{{_FRAME_NUMBER_DIGITS},}})(?P<tail>\D*)$")


def _refuse_frames_of_one_camera(directory: Path, files: list[Path]) -> None:
    """InputError when DIR's images are numbered alike (the same name around a run of at least
    _FRAME_NUMBER_DIGITS digits) and a folder beside DIR holds images with the same numbers: DIR
    is one camera's folder of a rig whose cameras are DIR's parent's subfolders (`--images
    rig/cam0` calibrated its frames as cameras, for minutes)."""
    numbers = _frame_numbers(files)
    if numbers is None or directory.resolve().parent == directory.resolve():
        return
    parent = directory.resolve().parent
    siblings = [d for d in sorted(parent.iterdir()) if d.is_dir() and not d.name.startswith(".")
                and d.resolve() != directory.resolve()]
    alike = [d for d in siblings
             if len(numbers & (_frame_numbers(_images_in(d)) or set())) >= len(numbers) / 2]
    if alike:
        raise InputError(
            f"{directory} holds numbered images ({files[0].name}, {files[1].name}, ...) and "
            f"{', '.join(d.name for d in alike[:3])} beside it hold the same numbers: these are "
            f"the frames of one camera, not one image per camera. Give the folder that holds "
            f"the camera folders: --images {parent}")


def _frame_numbers(files: list[Path]) -> Optional[set[int]]:
    """The frame numbers of files named alike around a run of digits (0000.png, 0001.png), or
    None when they are not (fewer than two files, names that differ otherwise)."""
    matches = [_NUMBERED.match(p.stem) for p in files]
    if len(files) < 2 or not all(matches) or \
            len({(m["head"], m["tail"]) for m in matches}) > 1:
        return None
    return {int(m["number"]) for m in matches}


def _align(directory: Path, names: list[str], per_cam: list[list[Path]], align: str,
           time_offsets_s: dict[str, float], max_time_gap_s: float) -> list[list[Path]]:
    """paths[t][c] of camera subfolders (module docstring)."""
    unknown = sorted(set(time_offsets_s) - set(names))
    if unknown:
        raise InputError(f"Time offsets for unknown camera(s) {', '.join(unknown)}: the cameras "
                         f"of {directory} are {', '.join(names)}.")
    per_cam, stems = _numbered_frames(per_cam)
    counts = {n: len(ps) for n, ps in zip(names, per_cam)}
    shared = set(stems[0]).intersection(*stems[1:])
    if align == "auto":
        # Mostly the same names: frames dropped by some camera (a recorder's hiccup, a deleted
        # blurry shot); pairing by position would shift every later set.
        if all(s == stems[0] for s in stems) or len(shared) >= 0.5 * max(counts.values()):
            align = "name"
        elif len(set(counts.values())) == 1:
            align = "order"
        else:
            raise InputError(
                f"Camera subfolders of {directory} hold different numbers of images ({counts}) "
                "and different file names, so they cannot be aligned by name or position. Give "
                "each time step the same file name in every camera folder, or choose: "
                "--align time (pair images by their EXIF capture time, e.g. camera traps) or "
                "--align order (evenly spaced images of each camera; fine for a static scene).")
    if align == "name":
        if not shared:
            raise InputError(f"--align name: no file name is in every camera folder of "
                             f"{directory} (e.g. {names[0]}/{per_cam[0][0].name} and "
                             f"{names[1]}/{per_cam[1][0].name}); name each time step alike in "
                             "every folder, or use --align order or --align time.")
        _warn_about_unshared_frames(names, per_cam, stems, shared)
        by_stem = [dict(zip(s, ps)) for s, ps in zip(stems, per_cam)]
        return [[files[stem] for files in by_stem] for stem in stems[0] if stem in shared]
    if align == "order":
        n = min(counts.values())
        if len(set(counts.values())) > 1:
            log.info("Pairing images by position: %d frame set(s) from %s image(s) per camera "
                     "(not the same moments in every camera; fine for a static scene).", n,
                     counts)
        picks = [np.round(np.linspace(0, len(ps) - 1, n)).astype(int) for ps in per_cam]
        return [[per_cam[c][picks[c][t]] for c in range(len(names))] for t in range(n)]
    return _align_by_capture_time(names, per_cam, time_offsets_s, max_time_gap_s)


# A frame counter: a run of digits at the end of a file stem, however padded (1, 0001).
_FRAME_COUNTER = re.compile(r"^(?P<head>.*?)(?P<number>\d+)(?P<tail>\D*)$")


def _numbered_frames(per_cam: list[list[Path]]) -> tuple[list[list[Path]], list[list[str]]]:
    """(each camera's images, their frame names): a camera whose files are named alike around
    a frame counter (_FRAME_COUNTER) in the counter's order (1, 2, 10, not 1, 10, 2); and where
    every camera names its files alike, the counter as the name, so that 0002 and 2 are one
    frame. Otherwise the files' sorted order and stems."""
    parts = []
    for files in per_cam:
        matches = [_FRAME_COUNTER.match(p.stem) for p in files]
        numbered = all(matches) and len({(m["head"], m["tail"]) for m in matches}) == 1 and \
            len({int(m["number"]) for m in matches}) == len(files)
        parts.append([(int(m["number"]), m["head"], m["tail"]) for m in matches]
                     if numbered else None)
    ordered = [[f for _, f in sorted(zip(part, files), key=lambda x: x[0][0])]
               if part else files for part, files in zip(parts, per_cam)]
    patterns = {(head, tail) for part in parts if part for _, head, tail in part}
    if all(parts) and len(patterns) == 1:
        return ordered, [[str(n) for n, _, _ in sorted(part)] for part in parts]
    return ordered, [[p.stem for p in files] for files in ordered]


def _warn_about_unshared_frames(names: list[str], per_cam: list[list[Path]],
                                frames: list[list[str]], shared: set) -> None:
    """Warn of the images left out (by file stem) whose frame name is not in `shared`."""
    def listed(xs: list[str]) -> str:
        return ", ".join(xs[:5]) + (f" and {len(xs) - 5} more" if len(xs) > 5 else "")

    left_out = {n: [p.stem for p, x in zip(ps, fs) if x not in shared]
                for n, ps, fs in zip(names, per_cam, frames)}
    if any(left_out.values()):
        log.warning("Frame sets by file name: %d with every camera; left out, as not every "
                    "camera has them: %s", len(shared),
                    "; ".join(f"{n}: {listed(xs)}" for n, xs in left_out.items() if xs))


def _capture_times_s(files: list[Path]) -> np.ndarray:
    from .exif import exif_capture_time_s

    times = []
    for path in files:
        t = exif_capture_time_s(path)
        if t is None:
            raise InputError(f"{path} has no EXIF capture time (DateTimeOriginal), which "
                             "pairing by capture time needs in every image: name each moment's "
                             "images alike in every camera folder (or calibrate with --align "
                             "order, for a static scene).")
        times.append(t)
    return np.asarray(times, dtype=np.float64)


def capture_times_by_camera(directory: str | os.PathLike) -> dict[str, np.ndarray]:
    """{camera: EXIF capture times [s] of its images} of a folder of camera subfolders."""
    directory = Path(directory)
    subdirs = sorted(p for p in directory.iterdir() if p.is_dir() and not p.name.startswith(".")
                     and _images_in(p)) if directory.is_dir() else []
    if len(subdirs) < 2:
        raise InputError(f"--align time needs one subfolder of images per camera in {directory}.")
    return {d.name: _capture_times_s(_images_in(d)) for d in subdirs}


def _align_by_capture_time(names: list[str], per_cam: list[list[Path]],
                           time_offsets_s: dict[str, float], max_time_gap_s: float
                           ) -> list[list[Path]]:
    times = [_capture_times_s(files) - float(time_offsets_s.get(name, 0.0))
             for name, files in zip(names, per_cam)]
    anchor = int(np.argmin([len(ps) for ps in per_cam]))
    sets, nearest_miss = [], np.inf
    for t_anchor in np.sort(times[anchor]):
        picks = [int(np.argmin(np.abs(ts - t_anchor))) for ts in times]
        gap = max(abs(times[c][i] - t_anchor) for c, i in enumerate(picks))
        if gap <= max_time_gap_s:
            sets.append([per_cam[c][i] for c, i in enumerate(picks)])
        else:
            nearest_miss = min(nearest_miss, gap)
    if not sets:
        raise InputError(
            f"--align time: no image of {names[anchor]} has images of every other camera within "
            f"{max_time_gap_s:g} s (nearest: {nearest_miss:.1f} s). If a camera's clock is off, "
            "give --time-offset NAME=SECONDS (how far it runs ahead); else raise --max-time-gap, "
            "or use --align order for a static scene.")
    log.info("Paired %d frame set(s) by EXIF capture time (%d image(s) of %s had no partner "
             "within %g s).", len(sets), len(times[anchor]) - len(sets), names[anchor],
             max_time_gap_s)
    return sets


def read_image_folder(directory: str | os.PathLike, max_frame_sets: Optional[int] = None,
                      **alignment) -> tuple[list[list[np.ndarray]], list[str]]:
    """Frame sets of an image folder: (frame_sets, camera_names), frame_sets[t][c] (H, W, 3)
    uint8 RGB. At most max_frame_sets evenly spaced time steps are read. Every image of a camera
    must have the same size (the cameras are calibrated at one resolution). alignment:
    list_image_folder's align, time_offsets_s, max_time_gap_s."""
    paths, names = list_image_folder(directory, **alignment)
    return read_image_files(evenly_spaced(paths, max_frame_sets), names), names


def read_image_files(paths: list[list[Path]], names: list[str]) -> list[list[np.ndarray]]:
    """frame_sets[t][c] (H, W, 3) uint8 RGB of the files paths[t][c]; InputError when a camera's
    images differ in size (the cameras are calibrated at one resolution)."""
    frame_sets = [[read_image(p) for p in row] for row in paths]
    for c, name in enumerate(names):
        first = frame_sets[0][c].shape[:2]
        for t in range(1, len(frame_sets)):
            if frame_sets[t][c].shape[:2] != first:
                h, w = frame_sets[t][c].shape[:2]
                raise InputError(
                    f"Images of camera {name} differ in size: {paths[t][c]} is {w}x{h}, "
                    f"{paths[0][c]} {first[1]}x{first[0]}. A camera is calibrated at one "
                    "resolution: remove or resize the images of the other size.")
    return frame_sets
