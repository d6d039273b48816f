"""Time offsets of a rig's cameras from what moves in their images (`--time-offset auto` with
--videos or --bag).

Cameras of an arena or a trap rig started by hand begin recording at different moments, and
cameras on different computers stamp their images by different clocks. Whatever moves in the
shared view (an animal, a person) changes every camera's image at the same instants, so each
camera's motion energy over time (mean absolute difference of consecutive frames, on small grey
images) is, up to gain, the same signal shifted by that camera's offset. The offset of each camera
from the reference camera (the first) is the lag that maximises the normalised cross-correlation
of the two signals, refined to a fraction of a frame by a parabola through the peak. The signals
are first averaged over the slowest camera's frame period (so all see motion at one time
resolution) and detrended over SMOOTHING_S: lighting drifts and auto-exposure move every pixel
slowly and would otherwise dominate.

A pair's offset is only used when its peak is both high (MIN_PEAK_CORRELATION) and unique (no
other lag more than UNIQUE_PEAK_SEPARATION_S away reaches MAX_SECOND_PEAK_RATIO of it); every pair
of cameras is compared and the offsets are fitted to the pairs used (offsets_from_motion). A
static scene or periodic motion gives no answer, and the error says to give the offsets by hand.

Convention as core.io.video_io: the frame of camera c at common time t is t + offset_c seconds into
its own time (a video's file time, a bag topic's header stamps); a camera that started recording
0.4 s before the reference, or whose clock runs 0.4 s ahead, has +0.4.
"""
from __future__ import annotations

import logging
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Optional, Sequence

import cv2
import numpy as np

from ..errors import InputError
from .video_io import VideoInfo, probe_video

log = logging.getLogger("densecalib.motion_sync")

DEFAULT_SYNC_WINDOW_S = 120.0  # the first this many seconds of every video are compared
SIGNAL_WIDTH_PX = 160  # frames are shrunk to this width: motion energy needs no detail
SMOOTHING_S = 1.0  # detrending window: slower changes (light, exposure) are not motion
MIN_OVERLAP_FRACTION = 0.5  # lags are searched while the signals overlap by this much
MIN_PEAK_CORRELATION = 0.3
MAX_SECOND_PEAK_RATIO = 0.8
UNIQUE_PEAK_SEPARATION_S = 0.5
BY_HAND = "give the offsets with --time-offset NAME=S"
MIN_SIGNAL_SAMPLES = 10


@dataclass(frozen=True)
class OffsetEstimate:
    offset_s: float  # relative to the reference camera (core.io.video_io convention)
    correlation: float  # normalised cross-correlation at the peak
    second_correlation: float  # best correlation at lags UNIQUE_PEAK_SEPARATION_S away


class MotionEnergy:
    """Accumulates a camera's motion signal from its frames in time order: energy between
    consecutive frames = mean |difference| of the frames shrunk to SIGNAL_WIDTH_PX wide in grey,
    placed midway between their times (cameras at different frame rates would otherwise be biased
    by half their frame periods). With max_span_s, only the latest max_span_s seconds are kept
    (a live stream)."""

    def __init__(self, max_span_s: Optional[float] = None):
        self.times_s: deque[float] = deque()
        self.energy: deque[float] = deque()
        self.max_span_s = max_span_s
        self._previous = None  # (time_s, shrunk grey frame)

    def add(self, time_s: float, image: np.ndarray) -> None:
        grey = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        h, w = grey.shape[:2]
        scale = min(1.0, SIGNAL_WIDTH_PX / max(w, 1))
        small = cv2.resize(grey, (max(1, round(w * scale)), max(1, round(h * scale))),
                           interpolation=cv2.INTER_AREA).astype(np.float32)
        if self._previous is not None and self._previous[1].shape == small.shape:
            self.times_s.append(0.5 * (self._previous[0] + time_s))
            self.energy.append(float(np.mean(np.abs(small - self._previous[1]))))
            while self.max_span_s is not None and \
                    self.times_s[-1] - self.times_s[0] > self.max_span_s:
                self.times_s.popleft()
                self.energy.popleft()
        self._previous = (float(time_s), small)

    def signal(self) -> tuple[np.ndarray, np.ndarray]:
        return np.asarray(self.times_s, dtype=np.float64), np.asarray(self.energy, np.float64)


def motion_signal(info: VideoInfo, window_s: float) -> tuple[np.ndarray, np.ndarray]:
    """(times_s, energy) of a video's first window_s seconds (MotionEnergy; frame k at k / fps
    in the video's own time). Frames are read in order (no seeking)."""
    cap = cv2.VideoCapture(str(info.path))
    if not cap.isOpened():
        raise InputError(f"Cannot open video {info.path} to find its time offset.")
    motion = MotionEnergy()
    try:
        for k in range(min(info.num_frames, int(np.ceil(window_s * info.fps)) + 1)):
            ok, frame = cap.read()
            if not ok or frame is None:
                break
            motion.add(k / info.fps, frame)
    finally:
        cap.release()
    return motion.signal()


def _moving_mean(x: np.ndarray, k: int) -> np.ndarray:
    """Centred moving mean over k samples, the edges normalised by the samples averaged."""
    if k <= 1:
        return x
    kernel = np.ones(k) / k
    return np.convolve(x, kernel, "same") / np.convolve(np.ones_like(x), kernel, "same")


def _detrended(times: np.ndarray, energy: np.ndarray, step_s: float,
               resolution_s: float) -> np.ndarray:
    """energy resampled every step_s from time 0, averaged over resolution_s (the slowest
    camera's frame period: a camera at 60 fps sees motion a 10 fps one cannot, which would only
    decorrelate them), minus its moving mean over SMOOTHING_S."""
    grid = np.arange(0.0, times[-1] + 1e-9, step_s)
    x = _moving_mean(np.interp(grid, times, energy), int(round(resolution_s / step_s)))
    return x - _moving_mean(x, max(1, int(round(SMOOTHING_S / step_s))))


def _correlations(ref: np.ndarray, other: np.ndarray, max_lag: int) -> np.ndarray:
    """Normalised cross-correlation ncc[L + max_lag] of ref[i] with other[i + L], L in
    [-max_lag, max_lag], over the overlap of the two; nan where the overlap is too short."""
    out = np.full(2 * max_lag + 1, np.nan)
    need = MIN_OVERLAP_FRACTION * min(len(ref), len(other))
    for j, lag in enumerate(range(-max_lag, max_lag + 1)):
        a = ref[max(0, -lag):]
        b = other[max(0, lag):]
        n = min(len(a), len(b))
        if n < max(need, 3):
            continue
        a, b = a[:n] - a[:n].mean(), b[:n] - b[:n].mean()
        denom = np.sqrt(np.dot(a, a) * np.dot(b, b))
        if denom > 0:
            out[j] = np.dot(a, b) / denom
    return out


def estimate_offset(ref: tuple[np.ndarray, np.ndarray], other: tuple[np.ndarray, np.ndarray],
                    step_s: float, resolution_s: float) -> OffsetEstimate:
    """Offset of `other` from `ref`, each a (times_s, energy) motion signal, compared every
    step_s at a time resolution of resolution_s."""
    a, b = (_detrended(*sig, step_s, resolution_s) for sig in (ref, other))
    max_lag = int(max(len(a), len(b)))
    ncc = _correlations(a, b, max_lag)
    if not np.isfinite(ncc).any():
        return OffsetEstimate(0.0, float("nan"), float("nan"))
    peak = int(np.nanargmax(ncc))
    shift = 0.0
    if 0 < peak < len(ncc) - 1 and np.isfinite(ncc[peak - 1:peak + 2]).all():
        y0, y1, y2 = ncc[peak - 1:peak + 2]
        curvature = y0 - 2 * y1 + y2
        if curvature < 0:
            shift = float(np.clip(0.5 * (y0 - y2) / curvature, -0.5, 0.5))
    lags_s = (np.arange(len(ncc)) - max_lag) * step_s
    far = np.abs(lags_s - lags_s[peak]) > UNIQUE_PEAK_SEPARATION_S
    second = float(np.nanmax(ncc[far])) if np.isfinite(ncc[far]).any() else float("-inf")
    return OffsetEstimate((peak - max_lag + shift) * step_s, float(ncc[peak]), second)


def _sure(est: OffsetEstimate) -> bool:
    """A peak high enough and unique enough to be an offset (module docstring)."""
    return bool(est.correlation >= MIN_PEAK_CORRELATION
                and est.second_correlation <= MAX_SECOND_PEAK_RATIO * est.correlation)


def _require_signals(signals: dict, by_hand: str) -> None:
    short = [n for n, (t, _) in signals.items() if len(t) < MIN_SIGNAL_SAMPLES]
    if short:
        raise InputError(f"The recordings of {', '.join(short)} are too short to find time "
                         f"offsets from their motion: {by_hand}.")


def offsets_from_motion(signals: dict[str, tuple[np.ndarray, np.ndarray]],
                        frame_periods_s: Sequence[float], window_s: float,
                        by_hand: str = BY_HAND) -> dict[str, OffsetEstimate]:
    """Offset of every camera's motion signal (times_s, energy) from the first one's; the
    cameras' frame periods set the comparison step and resolution.

    Every pair of cameras is compared, not only each camera with the first: cameras on opposite
    sides of an arena see different halves of what moves, and may share too little motion with
    each other while both share enough with a third. The offsets are the weighted least-squares
    solution over the pairs with a sure peak (weight: the peak correlation); a pair that then
    disagrees by more than two of the slowest frames is dropped, the worst first. Each camera
    reports the estimate of its strongest pair. InputError naming the cameras that no chain of
    sure pairs ties to the first; its message ends with `by_hand` (how to give the offsets)."""
    names = list(signals)
    _require_signals(signals, by_hand)
    step_s = min(frame_periods_s)  # finer: the parabola through the peak
    resolution_s = max(frame_periods_s)
    pairs = {}
    for i in range(len(names)):
        for j in range(i + 1, len(names)):
            est = estimate_offset(signals[names[i]], signals[names[j]], step_s, resolution_s)
            pairs[(i, j)] = est
            log.info("time offset of %s from %s: %+.3f s (correlation %.2f, next best %.2f)",
                     names[j], names[i], est.offset_s, est.correlation, est.second_correlation)
    edges = {ij: est for ij, est in pairs.items() if _sure(est)}
    while True:
        reached, frontier = {0}, [0]
        while frontier:
            k = frontier.pop()
            for i, j in edges:
                for a, b in ((i, j), (j, i)):
                    if a == k and b not in reached:
                        reached.add(b)
                        frontier.append(b)
        if len(reached) < len(names):
            def best(k):  # the camera's strongest pair, for the message
                est = max((e for ij, e in pairs.items() if k in ij), key=lambda e: e.correlation)
                return (f"{names[k]} (correlation at most {est.correlation:.2f}, another lag "
                        f"{est.second_correlation:.2f})")
            raise InputError(
                "The motion in the images does not determine the time offset of "
                f"{', '.join(best(k) for k in range(len(names)) if k not in reached)} from "
                f"{names[0]}: the {window_s:g} s compared show too little shared movement, or "
                f"a repeating one. Let something move in view of every camera, or {by_hand} "
                "(e.g. from a clap or a light switched on in view of every camera).")
        keys = list(edges)
        rows = np.zeros((len(keys), len(names)))
        for r, (i, j) in enumerate(keys):
            rows[r, i], rows[r, j] = -1.0, 1.0
        w = np.sqrt([edges[k].correlation for k in keys])
        b = np.array([edges[k].offset_s for k in keys])
        x = np.zeros(len(names))  # the first camera's offset is 0
        x[1:] = np.linalg.lstsq(rows[:, 1:] * w[:, None], b * w, rcond=None)[0]
        residuals = np.abs(rows @ x - b)
        worst = int(np.argmax(residuals))
        if residuals[worst] <= 2.0 * resolution_s:
            break
        log.info("dropped the pair %s-%s: %.3f s off the other pairs", names[keys[worst][0]],
                 names[keys[worst][1]], residuals[worst])
        del edges[keys[worst]]
    out = {names[0]: OffsetEstimate(0.0, 1.0, float("nan"))}
    for k in range(1, len(names)):
        strongest = max((e for ij, e in edges.items() if k in ij), key=lambda e: e.correlation)
        out[names[k]] = OffsetEstimate(float(x[k]), strongest.correlation,
                                       strongest.second_correlation)
    return out


def estimate_video_offsets(paths: Sequence[Path], names: Sequence[str],
                           window_s: float = DEFAULT_SYNC_WINDOW_S
                           ) -> dict[str, OffsetEstimate]:
    """Offset of every camera's video from the first one's (module docstring)."""
    infos = [probe_video(p) for p in paths]
    signals = {name: motion_signal(info, window_s) for name, info in zip(names, infos)}
    return offsets_from_motion(signals, [1.0 / info.fps for info in infos], window_s)


def bag_offsets(bag_path, topics: Sequence[str], names: Sequence[str],
                window_s: float = DEFAULT_SYNC_WINDOW_S) -> dict[str, OffsetEstimate]:
    """Offset of every image topic's header-stamp clock from the first topic's (module
    docstring), from the first window_s seconds of each topic, read in one pass."""
    from .bag import decode_image_message, iter_image_messages

    motions = [MotionEnergy() for _ in topics]
    first_ns: list[Optional[int]] = [None] * len(topics)
    done = [False] * len(topics)
    t0 = None
    for index, stamp, _, msgtype, msg in iter_image_messages(bag_path, list(topics)):
        t0 = stamp if t0 is None else t0
        first_ns[index] = stamp if first_ns[index] is None else first_ns[index]
        if stamp - first_ns[index] > window_s * 1e9:
            done[index] = True
            if all(done):
                break  # every topic's window is read
            continue
        motions[index].add((stamp - t0) * 1e-9, decode_image_message(msgtype, msg))
    return stream_offsets({name: m.signal() for name, m in zip(names, motions)}, window_s)


def stream_offsets(signals: dict[str, tuple[np.ndarray, np.ndarray]], window_s: float,
                   by_hand: str = BY_HAND) -> dict[str, OffsetEstimate]:
    """Offset of every stream's stamping clock from the first stream's, from their motion
    signals (MotionEnergy.signal of a bag's topics, or of the images a node receives), each
    stream's frame period its median frame interval."""
    _require_signals(signals, by_hand)
    periods = [float(np.median(np.diff(t))) for t, _ in signals.values()]
    if not all(np.isfinite(p) and p > 0 for p in periods):
        raise InputError("Every camera needs a stream of images with increasing header stamps "
                         f"to find time offsets from their motion: {by_hand}.")
    start = min(t[0] for t, _ in signals.values())
    signals = {n: (t - start, e) for n, (t, e) in signals.items()}  # the grid starts at 0
    return offsets_from_motion(signals, periods, window_s, by_hand)
