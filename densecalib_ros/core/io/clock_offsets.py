"""Clock offsets of camera traps from their capture times alone (`--align time --time-offset
auto`).

Trail cameras fire on their own when an animal passes; cameras watching the same spot fire within
a second or two of each other. So camera c's capture times, shifted back by its clock's offset
from the reference camera's, fall next to the reference camera's capture times, while any wrong
shift pairs only chance coincidences. Every difference t_c - t_ref is a candidate; candidates
pile up at the true offset (one per co-observed shot pair). The densest windows of width
2 max_time_gap_s are scored by how many reference shots they pair (a burst of shots counts once
per shot, not per pair), and the best one's median difference is the offset. Any offset is
found: a clock set an hour off (daylight saving), a day off, or reset to its factory date.

The answer must be clear: at least MIN_PAIRED_SHOTS reference shots paired, and no offset outside
that window pairing more than MAX_SECOND_PAIRED_RATIO as many (a time-lapse schedule with the same
interval in every camera pairs as well at every multiple of it). Otherwise the error asks for the
offset by hand.

Convention as core.io.image_io: time_offsets_s[name] is how far that camera's clock runs ahead of
the reference camera's (s).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from ..errors import InputError

MIN_PAIRED_SHOTS = 3
MAX_SECOND_PAIRED_RATIO = 0.5
CANDIDATE_WINDOWS = 50  # the densest windows whose shots are counted
MAX_DIFFERENCES = 20_000_000  # candidate pairs held at once (memory: 160 MB)


@dataclass(frozen=True)
class ClockOffset:
    offset_s: float  # how far the camera's clock runs ahead of the reference camera's
    paired_shots: int  # reference shots with a shot of this camera within the time gap
    second_paired_shots: int  # the most any offset outside the chosen window pairs


def _paired(ref_s: np.ndarray, other_sorted_s: np.ndarray, offset_s: float,
            gap_s: float) -> int:
    """Reference shots with a shot of the other camera within gap_s once it is shifted back by
    offset_s."""
    shifted = other_sorted_s - offset_s
    i = np.searchsorted(shifted, ref_s)
    before = shifted[np.clip(i - 1, 0, len(shifted) - 1)]
    after = shifted[np.clip(i, 0, len(shifted) - 1)]
    nearest = np.minimum(np.abs(before - ref_s), np.abs(after - ref_s))
    return int(np.count_nonzero(nearest <= gap_s))


def estimate_clock_offset(ref_s: Sequence[float], other_s: Sequence[float],
                          gap_s: float) -> ClockOffset:
    """Offset of the other camera's clock from the reference camera's (module docstring)."""
    ref = np.sort(np.asarray(ref_s, dtype=np.float64))
    other = np.sort(np.asarray(other_s, dtype=np.float64))
    if len(ref) * len(other) > MAX_DIFFERENCES:
        raise InputError(f"Too many capture times to compare ({len(ref)} x {len(other)}) for "
                         "--time-offset auto: give the offsets with --time-offset NAME=S, or "
                         "fewer images.")
    diffs = np.sort((other[:, None] - ref[None, :]).ravel())
    window = 2.0 * gap_s
    density = np.searchsorted(diffs, diffs + window, side="right") - np.arange(len(diffs))
    order = np.argsort(-density, kind="stable")
    candidates, taken = [], []
    for i in order:  # the densest windows, not overlapping one another
        if len(candidates) == CANDIDATE_WINDOWS:
            break
        if any(abs(diffs[i] - t) < window for t in taken):
            continue
        taken.append(diffs[i])
        inside = diffs[i:i + density[i]]
        offset = float(np.median(inside))
        candidates.append((_paired(ref, other, offset, gap_s), -density[i], offset))
    candidates.sort(reverse=True)
    best_paired, _, best = candidates[0]
    second = max((p for p, _, o in candidates[1:] if abs(o - best) > window), default=0)
    return ClockOffset(best, best_paired, second)


def estimate_clock_offsets(times_s: dict[str, Sequence[float]], gap_s: float
                           ) -> dict[str, ClockOffset]:
    """Every camera's clock offset from the first camera's; InputError naming the cameras whose
    offset the capture times do not settle."""
    names = list(times_s)
    reference = names[0]
    out = {reference: ClockOffset(0.0, len(times_s[reference]), 0)}
    unsure = []
    for name in names[1:]:
        est = estimate_clock_offset(times_s[reference], times_s[name], gap_s)
        out[name] = est
        if est.paired_shots < MIN_PAIRED_SHOTS or \
                est.second_paired_shots > MAX_SECOND_PAIRED_RATIO * est.paired_shots:
            unsure.append(f"{name} (best {est.offset_s:+.1f} s pairs {est.paired_shots} shots, "
                          f"another offset {est.second_paired_shots})")
    if unsure:
        raise InputError(
            f"The capture times do not settle the clock offset of {', '.join(unsure)} from "
            f"{reference}: too few shots taken together within {gap_s:g} s, or a regular "
            "schedule (time-lapse) that pairs as well at other offsets. Give the offsets with "
            "--time-offset NAME=SECONDS (how far that camera's clock runs ahead).")
    return out
