"""Time offsets of a rig's videos from what moves in them (`--time-offset auto`).

Cameras of an arena or a trap rig started by hand begin recording at different moments. Whatever
moves in the shared view (an animal, a person) changes every camera's image at the same instants,
so each video's motion energy over time (mean absolute difference of consecutive frames, on
small grey images) is, up to gain, the same signal shifted by that video's offset. The offset of
each camera from the reference camera (the first by name) is the lag that maximises the
normalised cross-correlation of the two signals, refined to a fraction of a frame by a parabola
through the peak. The signals are first averaged over the slowest camera's frame period (so all
see motion at one time resolution) and detrended over SMOOTHING_S: lighting drifts and
auto-exposure move every pixel slowly and would otherwise dominate.

An offset is only reported when the peak is both high (MIN_PEAK_CORRELATION) and unique (no other
lag more than UNIQUE_PEAK_SEPARATION_S away reaches MAX_SECOND_PEAK_RATIO of it): a static scene
or periodic motion gives no answer, and the error says to give the offsets by hand.

Convention as core.video_io: the frame of camera c at common time t is t + offset_c seconds into
its file; a camera that started recording 0.4 s before the reference has +0.4.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import cv2
import numpy as np

from .errors import InputError
from .video_io import VideoInfo, probe_video

log = logging.getLogger("densecalib.video_sync")

DEFAULT_SYNC_WINDOW_S = 120.0  # the first this many seconds of every video are compared
SIGNAL_WIDTH_PX = 160  # frames are shrunk to this width: motion energy needs no detail
SMOOTHING_S = 1.0  # detrending window: slower changes (light, exposure) are not motion
MIN_OVERLAP_FRACTION = 0.5  # lags are searched while the signals overlap by this much
MIN_PEAK_CORRELATION = 0.3
MAX_SECOND_PEAK_RATIO = 0.8
UNIQUE_PEAK_SEPARATION_S = 0.5


@dataclass(frozen=True)
class OffsetEstimate:
    offset_s: float  # relative to the reference camera (core.video_io convention)
    correlation: float  # normalised cross-correlation at the peak
    second_correlation: float  # best correlation at lags UNIQUE_PEAK_SEPARATION_S away


def motion_signal(info: VideoInfo, window_s: float) -> tuple[np.ndarray, np.ndarray]:
    """(times_s, energy) of a video's first window_s seconds: energy[k] = mean |frame k+1 -
    frame k| (grey levels, frames shrunk to SIGNAL_WIDTH_PX wide), at the middle of the motion it
    measures, between frames k and k+1: (k + 0.5) / fps in the video's own time (cameras at
    different frame rates would otherwise be biased by half their frame periods). Frames are read
    in order (no seeking)."""
    cap = cv2.VideoCapture(str(info.path))
    if not cap.isOpened():
        raise InputError(f"Cannot open video {info.path} to find its time offset.")
    scale = min(1.0, SIGNAL_WIDTH_PX / max(info.width, 1))
    size = (max(1, round(info.width * scale)), max(1, round(info.height * scale)))
    energy, previous = [], None
    try:
        for _ in range(min(info.num_frames, int(np.ceil(window_s * info.fps)) + 1)):
            ok, frame = cap.read()
            if not ok or frame is None:
                break
            grey = frame if frame.ndim == 2 else cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
            small = cv2.resize(grey, size, interpolation=cv2.INTER_AREA).astype(np.float32)
            if previous is not None:
                energy.append(float(np.mean(np.abs(small - previous))))
            previous = small
    finally:
        cap.release()
    times = (np.arange(len(energy)) + 0.5) / info.fps
    return times, np.asarray(energy, dtype=np.float64)


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


def estimate_video_offsets(paths: Sequence[Path], names: Sequence[str],
                           window_s: float = DEFAULT_SYNC_WINDOW_S
                           ) -> dict[str, OffsetEstimate]:
    """Offset of every camera's video from the first one's (module docstring); InputError naming
    the cameras whose offset the motion does not determine."""
    infos = [probe_video(p) for p in paths]
    signals = [motion_signal(info, window_s) for info in infos]
    short = [n for n, (t, _) in zip(names, signals) if len(t) < 10]
    if short:
        raise InputError(f"The videos of {', '.join(short)} are too short to find time offsets "
                         "from their motion: give them with --time-offset NAME=S.")
    step_s = 1.0 / max(info.fps for info in infos)  # finer: the parabola through the peak
    resolution_s = 1.0 / min(info.fps for info in infos)
    out = {names[0]: OffsetEstimate(0.0, 1.0, float("nan"))}
    unsure = []
    for name, signal in zip(names[1:], signals[1:]):
        est = estimate_offset(signals[0], signal, step_s, resolution_s)
        out[name] = est
        log.info("time offset of %s from %s: %+.3f s (correlation %.2f, next best %.2f)", name,
                 names[0], est.offset_s, est.correlation, est.second_correlation)
        if not (est.correlation >= MIN_PEAK_CORRELATION
                and est.second_correlation <= MAX_SECOND_PEAK_RATIO * est.correlation):
            unsure.append(f"{name} (correlation {est.correlation:.2f}, another lag "
                          f"{est.second_correlation:.2f})")
    if unsure:
        raise InputError(
            f"The motion in the videos does not determine the time offset of "
            f"{', '.join(unsure)} from {names[0]}: the first {window_s:g} s show too little "
            "shared movement, or a repeating one. Give the offsets with --time-offset NAME=S "
            "(e.g. from a clap or a light switched on in view of every camera).")
    return out
