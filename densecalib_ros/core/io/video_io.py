"""Reading a rig's frame sets from one video per camera (arenas and camera traps record video).

DIR holds one video file per camera; the file stem is the camera name. The videos share one
timeline: the frame of camera c at common time t is at t + offset_c seconds into its file
(offset 0 for cameras started together; a camera that started recording 0.4 s before the others
has +0.4). Frame sets are taken at evenly spaced common times inside the span every video covers
(and inside an optional [start, end] window), one frame per camera: the one showing at that time
(frame k shows from k / fps to (k + 1) / fps). Each time is moved to the middle of the frame the
slowest camera shows then (mid_frame_times_s): a time near a frame boundary would turn an
offset's error of a fraction of a frame into a whole frame between the cameras.

The rig is rigid, so time errors only matter for what moves in the scene (animals, people): their
matches then disagree between cameras, and the cycle-consistent sampling and the epipolar filter
drop most of them, but a static background is what calibrates. Give offsets when the recordings
did not start together.
"""
from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Optional

import cv2
import numpy as np

from ..errors import InputError, TooFewCamerasGivenError
from .file_kinds import IMAGE_EXTENSIONS, VIDEO_EXTENSIONS

log = logging.getLogger(__name__)

DEFAULT_VIDEO_FRAME_SETS = 8
# fourcc -> container (OpenCV's FFmpeg writes them): mp4v and MJPG lossy, FFV1 lossless (every
# frame decodes to the pixels written; large files, and not every player reads it)
VIDEO_CODECS = {"mp4v": ".mp4", "MJPG": ".avi", "FFV1": ".mkv"}
# A frame count read from a container can be an estimate (duration x fps); the last frames may
# not decode, so a failed read steps back this many frames before giving up.
_READ_BACKOFF_FRAMES = 5
# Moments tried across one frame of the slowest camera for synchronising_trims' common start: a
# twenty-fourth of a frame is finer than motion sync's offsets are known to.
START_CANDIDATES = 24


@dataclass(frozen=True)
class VideoInfo:
    path: Path
    fps: float
    num_frames: int
    width: int
    height: int

    @property
    def duration_s(self) -> float:
        return self.num_frames / self.fps


def list_video_folder(directory: str | os.PathLike) -> tuple[list[Path], list[str]]:
    """(video files, camera names = file stems) of DIR; InputError when there are none or two share
    a name, TooFewCamerasGivenError (an InputError) for fewer than two."""
    directory = Path(directory)
    if not directory.is_dir():
        raise InputError(f"Video folder {directory} does not exist or is not a folder.")
    files = sorted(p for p in directory.iterdir() if p.is_file() and not p.name.startswith(".")
                   and p.suffix.lower() in VIDEO_EXTENSIONS)
    if not files:
        raise InputError(f"No videos ({', '.join(VIDEO_EXTENSIONS)}) in {directory}: put one video "
                         "per camera there, named after the camera (e.g. cam0.mp4).")
    _warn_about_images(directory)
    names = [p.stem for p in files]
    duplicate = sorted({n for n in names if names.count(n) > 1})
    if duplicate:
        raise InputError(f"Several videos in {directory} share the camera name(s) "
                         f"{', '.join(duplicate)} (file stem): keep one video per camera.")
    if len(files) < 2:
        raise TooFewCamerasGivenError(
            f"Found only one video ({files[0].name}) in {directory}: a rig calibration needs "
            "videos of at least two cameras.")
    return files, names


def _warn_about_images(directory: Path) -> None:
    """Warn of images in a folder of videos: a camera given as a still among videos is not read,
    and would leave the rig unnoticed."""
    images = sorted(p.name for p in directory.iterdir() if p.is_file()
                    and not p.name.startswith(".") and p.suffix.lower() in IMAGE_EXTENSIONS)
    if images:
        log.warning("skipped in %s: %s (images: only the videos are read; give a camera's "
                    "images with --images, or its video here)", directory, ", ".join(images))


def _open(path: Path) -> cv2.VideoCapture:
    cap = cv2.VideoCapture(str(path))
    if not cap.isOpened():
        raise InputError(f"Cannot open video {path}: it is missing, damaged or in a format this "
                         "OpenCV build cannot decode. Convert it (e.g. ffmpeg -i IN -c:v libx264 "
                         "OUT.mp4) or extract frames and use --images.")
    return cap


def probe_video(path: str | os.PathLike) -> VideoInfo:
    """Frame rate, frame count and size of a video, from its container."""
    path = Path(path)
    cap = _open(path)
    try:
        fps = float(cap.get(cv2.CAP_PROP_FPS))
        count = int(round(cap.get(cv2.CAP_PROP_FRAME_COUNT)))
        width = int(cap.get(cv2.CAP_PROP_FRAME_WIDTH))
        height = int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT))
    finally:
        cap.release()
    if not np.isfinite(fps) or fps <= 0 or count <= 0:
        raise InputError(f"Video {path} reports no frame rate or frame count (fps {fps}, "
                         f"{count} frames), so its frames cannot be placed in time: re-mux it "
                         "(e.g. ffmpeg -i IN -c copy OUT.mp4) or extract frames and use --images.")
    return VideoInfo(path, fps, count, width, height)


def common_span_s(infos: list[VideoInfo], offsets_s: list[float],
                  start_s: Optional[float] = None, end_s: Optional[float] = None
                  ) -> tuple[float, float]:
    """[first, last) common time that every video covers, cut to [start_s, end_s]."""
    first = max(-off for off in offsets_s)
    last = min(info.duration_s - off for info, off in zip(infos, offsets_s))
    if start_s is not None:
        first = max(first, float(start_s))
    if end_s is not None:
        last = min(last, float(end_s))
    if last <= first:
        spans = ", ".join(f"{i.path.name} {-o:.2f}..{i.duration_s - o:.2f} s"
                          for i, o in zip(infos, offsets_s))
        asked = ", ".join(f"{what} {t:g} s" for what, t in (("--start", start_s),
                                                            ("--end", end_s)) if t is not None)
        raise InputError(f"The videos share no time span (each video on the common timeline: "
                         f"{spans}{'; ' + asked if asked else ''}): check the time offsets"
                         f"{' and ' + asked if asked else ''}.")
    return first, last


def frame_set_times_s(first_s: float, last_s: float, num_sets: int) -> np.ndarray:
    """num_sets common times, the midpoints of equal slices of [first_s, last_s): away from the
    ends, where recordings often start dark or blurred."""
    return first_s + (np.arange(num_sets) + 0.5) * (last_s - first_s) / num_sets


def mid_frame_times_s(times_s: np.ndarray, infos: list[VideoInfo], offsets_s: list[float]
                      ) -> np.ndarray:
    """Each common time moved to the middle of the frame that the slowest camera (the lowest
    fps; the first of equals) shows then. A camera of the same frame rate whose offset is off by
    less than half a frame then still shows the frame it shows with the right offset, where at
    a time near a boundary a small error (motion sync's estimate: docs/cli.md) would pick the
    next frame, a whole frame period apart in time."""
    slowest = min(range(len(infos)), key=lambda c: infos[c].fps)
    fps, offset = infos[slowest].fps, offsets_s[slowest]
    return (np.floor((np.asarray(times_s, float) + offset) * fps) + 0.5) / fps - offset


def _read_frame(cap: cv2.VideoCapture, info: VideoInfo, index: int) -> np.ndarray:
    for i in range(index, max(-1, index - _READ_BACKOFF_FRAMES - 1), -1):
        cap.set(cv2.CAP_PROP_POS_FRAMES, i)
        ok, bgr = cap.read()
        if ok and bgr is not None and bgr.size:
            if bgr.shape[:2] != (info.height, info.width):
                raise InputError(f"Video {info.path} changes size mid-stream "
                                 f"({info.width}x{info.height} -> {bgr.shape[1]}x{bgr.shape[0]}).")
            return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB) if bgr.ndim == 3 else bgr
    raise InputError(f"Cannot decode frame {index} of video {info.path} ({info.num_frames} frames "
                     f"at {info.fps:g} fps by its header): the file may be truncated; re-encode it "
                     "or pass --end before the damage.")


def read_video_frame_sets(directory: str | os.PathLike,
                          num_sets: int = DEFAULT_VIDEO_FRAME_SETS,
                          offsets_s: Optional[dict[str, float]] = None,
                          start_s: Optional[float] = None, end_s: Optional[float] = None
                          ) -> tuple[list[list[np.ndarray]], list[str], list[float]]:
    """Frame sets of a video folder (module docstring): (frame_sets, camera_names, times_s) with
    frame_sets[t][c] (H, W, 3) uint8 RGB and times_s[t] the common time of set t. offsets_s: per
    camera name, seconds (missing cameras: 0; unknown names are an error)."""
    if int(num_sets) < 1:
        raise InputError(f"The number of frame sets must be at least 1, got {num_sets}.")
    paths, names = list_video_folder(directory)
    offsets_s = dict(offsets_s or {})
    unknown = sorted(set(offsets_s) - set(names))
    if unknown:
        raise InputError(f"Offsets for unknown camera(s) {', '.join(unknown)}: the cameras of "
                         f"{directory} are {', '.join(names)}.")
    offsets = [float(offsets_s.get(n, 0.0)) for n in names]
    infos = [probe_video(p) for p in paths]
    first, last = common_span_s(infos, offsets, start_s, end_s)
    # Never two sets on the same frame of the slowest camera: at most one set per frame period
    # (set times at least a period apart fall in different frames of it).
    shortest = min(int((last - first) * info.fps) for info in infos)
    times = mid_frame_times_s(frame_set_times_s(first, last, max(1, min(int(num_sets), shortest))),
                              infos, offsets)
    frame_sets: list[list[np.ndarray]] = [[] for _ in times]
    for info, offset in zip(infos, offsets):
        cap = _open(info.path)
        try:
            for t, time_s in enumerate(times):
                index = int(np.clip(np.floor((time_s + offset) * info.fps), 0,
                                    info.num_frames - 1))
                frame_sets[t].append(_read_frame(cap, info, index))
        finally:
            cap.release()
    return frame_sets, names, [float(t) for t in times]


def transcode_video(info: VideoInfo, dest: str | os.PathLike, codec: str = "mp4v",
                    first_frame: int = 0, num_frames: Optional[int] = None,
                    transform: Optional[Callable[[np.ndarray], np.ndarray]] = None,
                    size: Optional[tuple[int, int]] = None) -> int:
    """Write frames first_frame .. first_frame + num_frames - 1 (default: to the end) of a video
    to dest at its frame rate, each BGR frame passed through `transform` (of output size
    (width, height) `size`, default the input's); returns the number written. Frames are read
    in order (decoders seek to key frames only)."""
    size = size or (info.width, info.height)
    cap = _open(info.path)
    writer = cv2.VideoWriter(str(dest), cv2.VideoWriter_fourcc(*codec), info.fps, size)
    if not writer.isOpened():
        cap.release()
        raise InputError(f"Cannot write {dest} with codec {codec}: try another codec "
                         f"({', '.join(VIDEO_CODECS)}), and check the disk.")
    count = index = 0
    try:
        while num_frames is None or count < num_frames:
            ok, frame = cap.read()
            if not ok or frame is None:
                break
            if index >= first_frame:
                writer.write(frame if transform is None else transform(frame))
                count += 1
            index += 1
    finally:
        cap.release()
        writer.release()
    if count == 0:
        raise InputError(f"No frame of {info.path} from frame {first_frame} on could be decoded.")
    return count


def _nearest_frames(infos: list[VideoInfo], offsets_s: list[float], moment_s: float
                    ) -> list[int]:
    """Per video, the frame starting nearest to the common time moment_s."""
    return [int(round((moment_s + off) * info.fps)) for info, off in zip(infos, offsets_s)]


def _frame_starts_spread_s(infos: list[VideoInfo], offsets_s: list[float], moment_s: float
                           ) -> float:
    """How far apart (s, common time) the frames of the videos starting nearest to moment_s
    start."""
    starts = [k / info.fps - off for info, off, k in
              zip(infos, offsets_s, _nearest_frames(infos, offsets_s, moment_s))]
    return max(starts) - min(starts)


@dataclass(frozen=True)
class Trim:
    first_frame: int  # the first frame kept
    num_frames: int
    start_s: float  # common time of the first frame kept


def synchronising_trims(infos: list[VideoInfo], offsets_s: list[float]) -> list[Trim]:
    """Per video, the frames to keep so that all start at the same moment, as nearly as their
    frame rates and offsets allow, and, at equal frame rates, have as many frames: frame index k
    then shows the same instant in every video, what tools that take synchronised videos
    (anipose) assume. The moment is the one, from the latest camera's start on over one frame
    of the slowest camera (START_CANDIDATES steps), at which the frames starting nearest to it
    start closest together (the earliest such): at the latest camera's start itself another
    camera can sit half a frame from its nearest frame, where an offset's error of a fraction of
    a frame (motion sync's estimate) picks the frame after."""
    first, last = common_span_s(infos, offsets_s)
    period_s = 1.0 / min(info.fps for info in infos)
    moments = first + np.arange(START_CANDIDATES) * period_s / START_CANDIDATES
    moments = moments[moments < last]  # first < last: common_span_s
    # spreads compared to the nanosecond: equal ones up to rounding keep the earliest moment
    start = min(moments, key=lambda t: round(_frame_starts_spread_s(infos, offsets_s, t), 9))
    starts = _nearest_frames(infos, offsets_s, start)
    counts = [min(info.num_frames - k, int(np.floor((last - start) * info.fps)))
              for info, k in zip(infos, starts)]
    if len({info.fps for info in infos}) == 1:
        counts = [min(counts)] * len(infos)
    return [Trim(k, max(0, n), k / info.fps - off)
            for info, off, k, n in zip(infos, offsets_s, starts, counts)]
