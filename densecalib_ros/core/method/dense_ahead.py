"""The dense correspondences found while the rig is still searched (DenseAhead): the image
refinement's alignments need only the images and the keypoint matches until their last checks,
so they run on cores the search leaves idle instead of after it."""
from __future__ import annotations

import threading
from functools import partial
from typing import Callable, Optional, Sequence

import numpy as np

from ..parallel import STOP_CHECK_S, RunAhead, available_cores
from ..types import Tracks
from .dense_frame_sets import densified_times, later_frame_sets
from .dense_matches import AlignmentCount, dense_tracks, first_pass, points_per_image
from .reconstruction import SfMState

# Core-seconds one reference point's alignment onto another image, or back, takes (both passes
# of a 15x15 patch on the development machine's cores): what the dense work a calibration waits
# for will take (DenseAhead.seconds_left), since its pace ahead, behind the SfM, says nothing.
ALIGN_CORE_S_PER_POINT = 3e-5


def alignment_steps(num_cameras: int, num_frame_sets: float) -> float:
    """_aligned_both_ways' steps over these frame sets among this many cameras (one pass); a
    frame set densified on part of its images counts as that share of one (AlignmentCount)."""
    return 2 * num_frame_sets * num_cameras * (num_cameras - 1)


class DenseAhead:
    """dense_tracks' work on a calibration's frame sets, keypoint-match tracks and masks, done on
    cores the calibration leaves idle before the tracks are asked for (parallel.RunAhead): the
    first pass among all cameras as soon as the matches are known, and the rest for a rig
    expected to be the final one (expect) as soon as it is found. tracks(state) gives what
    dense_tracks would, from the work done ahead where it fits that state."""

    def __init__(self, frame_sets: Sequence[Sequence[np.ndarray]], num_cameras: int,
                 keypoint_tracks: Tracks, masks: Optional[Sequence] = None,
                 px_scale: Optional[np.ndarray] = None,
                 first_of: Optional["DenseAhead"] = None) -> None:
        """first_of: a DenseAhead on the same frame sets, keypoint tracks, masks and px_scale
        (another calibration of the same matches) whose first pass, which depends on nothing
        else, this one takes over instead of running it again."""
        self._inputs = (frame_sets, keypoint_tracks, masks)
        self.px_scale = px_scale
        self._num_cameras = num_cameras
        if first_of is not None:
            self._num_frame_sets = first_of._num_frame_sets
            self._first_done, self._first = first_of._first_done, first_of._first
        else:
            later = later_frame_sets(frame_sets, keypoint_tracks)
            self._num_frame_sets = len(densified_times(keypoint_tracks)) + sum(later.values())
            self._first_done = AlignmentCount()
            self._first = RunAhead(partial(first_pass, px_scale=px_scale,
                                           counted=self._first_done, later=later), frame_sets,
                                   range(num_cameras), keypoint_tracks, masks,
                                   name="densecalib-dense-ahead")
        # (_rig_key, RunAhead of dense_tracks, the alignments it did)
        self._expected: Optional[tuple] = None

    def expect(self, state: SfMState) -> None:
        """Start the rest of dense_tracks for this rig (replacing an earlier expectation)."""
        if self._expected is not None:
            self._expected[1].cancel()
        state, counted = state.copy(), AlignmentCount()
        self._expected = (_rig_key(state), RunAhead(self._rest, state, counted,
                                                    name="densecalib-dense-ahead"), counted)

    def _rest(self, state: SfMState, counted: AlignmentCount, cancelled: threading.Event,
              thread_start: Callable[[], None]) -> Tracks:
        frame_sets, keypoint_tracks, masks = self._inputs
        return dense_tracks(frame_sets, state, keypoint_tracks, masks, self._first.result(),
                            cancelled, thread_start, self.px_scale, counted)

    def seconds_left(self, state: SfMState) -> float:
        """About the seconds tracks(state) will still spend on alignments not yet done ahead
        (ALIGN_CORE_S_PER_POINT on every core)."""
        registered = len(state.registered())
        first_left = alignment_steps(self._num_cameras, self._num_frame_sets) - \
            self._first_done.done
        rest = alignment_steps(registered, self._num_frame_sets) * (
            1 if registered == self._num_cameras else 2)  # the first pass again, among fewer
        expected = self._expected_for(state)
        rest_done = expected[2].done if expected is not None else 0
        points = max(first_left, 0) * points_per_image(self._num_cameras) + \
            max(rest - rest_done, 0) * points_per_image(registered)
        return points * ALIGN_CORE_S_PER_POINT / available_cores()

    def wait(self, state: SfMState, report: Callable[[float], None]) -> None:
        """Wait for the work run ahead that tracks(state) takes up, telling `report` every
        STOP_CHECK_S the fraction done of what was left when the wait began (seconds_left)."""
        expected = self._expected_for(state)
        ahead = expected[1] if expected is not None else self._first
        left_s = self.seconds_left(state)
        while not ahead.returned_within(STOP_CHECK_S):
            if left_s > 0:
                report(1.0 - self.seconds_left(state) / left_s)

    def tracks(self, state: SfMState) -> Tracks:
        expected = self._expected_for(state)
        if expected is not None:
            tracks = expected[1].result()
            if tracks is not None:
                return tracks
        frame_sets, keypoint_tracks, masks = self._inputs
        return dense_tracks(frame_sets, state, keypoint_tracks, masks, self._first.result(),
                            px_scale=self.px_scale)

    def _expected_for(self, state: SfMState) -> Optional[tuple]:
        """The expectation run ahead for this state's rig, or None."""
        if self._expected is not None and self._expected[0] == _rig_key(state):
            return self._expected
        return None

    def cancel(self) -> None:
        """Stop what still runs (a calibration that ends without the tracks)."""
        self._first.cancel()
        if self._expected is not None:
            self._expected[1].cancel()

    def pause(self, paused: bool = True) -> None:
        """Hold what still runs between image pairs (paused), or let it go on (not paused)."""
        for ahead in [self._first] + ([self._expected[1]] if self._expected else []):
            ahead.pause() if paused else ahead.resume()


def _rig_key(state: SfMState) -> tuple:
    """What of a state dense_tracks depends on: the registered cameras' poses and intrinsics."""
    return tuple((c, state.cam_from_world[c].tobytes(), state.camera(c).model,
                  np.asarray(state.camera(c).params, np.float64).tobytes())
                 for c in state.registered())
