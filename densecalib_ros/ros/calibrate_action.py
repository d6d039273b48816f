"""The node's ~/calibrate action (densecalib_interfaces/action/Calibrate): a calibration with the
options of its goal, its progress as feedback, a cancel that stops it, and its cameras in the
result (docs/ros.md).

One goal at a time: a goal arriving while another job (a calibration, a check, a reload) holds
the node's job slot is rejected, and why is said on ~/status and at WARN (the action protocol's
rejection carries no reason). A goal whose options the parameters' rules refuse is accepted and
ends ABORTED with the reason in its result. A cancel is accepted until the calibration writes its
files: the core stops at its next check, nothing is written and the goal ends CANCELED; the
published calibration stays current.
"""
from __future__ import annotations

import threading
import time
from typing import Optional

from densecalib_interfaces.action import Calibrate
from densecalib_interfaces.msg import CameraSummary
from rclpy.action import ActionServer, CancelResponse, GoalResponse
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.exceptions import InvalidHandle
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy

from ..core.errors import InputError
from ..core.progress import ProgressState
from ..core.types import RigCalibration
from .job_slot import Job, Outcome
from .parameters import parameter_values
from .settings import PARAMETERS, Settings, parse_settings

# Feedback is published this often while a goal runs (at least once a second, as asked).
FEEDBACK_PERIOD_S = 0.5
# The goal's options that take the node's parameter of that name when empty or zero.
GOAL_TEXT_OPTIONS = ("preset", "pipeline", "matcher", "second_matcher")
GOAL_COUNT_OPTIONS = ("consensus_runs", "max_frame_sets")
# A cancel arriving as its goal starts waits this long for the goal's calibration to start (its
# execution starts within milliseconds of its acceptance), and a calibration stopped by the
# goal's cancel this long for the cancel to be recorded on the goal.
CANCEL_HANDOVER_S = 1.0


def goal_settings(goal: Calibrate.Goal, values: dict) -> Optional[Settings]:
    """The settings a goal's calibration runs with: the node's parameter `values` with the
    goal's options over them, checked as the parameters are (InputError naming the option);
    None when the goal sets none (the node's settings as they are at the start)."""
    changes = {name: getattr(goal, name) for name in GOAL_TEXT_OPTIONS if getattr(goal, name)}
    for name in GOAL_COUNT_OPTIONS:
        value = int(getattr(goal, name))
        if value:
            (allowed,) = PARAMETERS[name][3]["integer_range"]
            if not allowed.from_value <= value <= allowed.to_value:
                raise InputError(f"{name} must be 0 (the node's parameter) or "
                                 f"{allowed.from_value}..{allowed.to_value}, got {value}.")
            changes[name] = value
    if not changes:
        return None
    return parse_settings({**values, **changes})


def feedback_msg(state: ProgressState) -> Calibrate.Feedback:
    """The action's feedback from the core's progress state (seconds left -1: not known yet)."""
    return Calibrate.Feedback(
        stage=state.stage, label=state.label, stage_done=max(int(state.stage_done), 0),
        stage_total=max(int(state.stage_total), 0), fraction_done=float(state.fraction),
        seconds_left=-1.0 if state.seconds_left is None else float(state.seconds_left),
        elapsed_s=float(state.elapsed_s))


def camera_summaries(rig: RigCalibration, settings: Settings) -> list[CameraSummary]:
    """Every camera of camera_names, in their order: its model, size, focal, fit; registered
    False for one the calibration could not place."""
    summaries = []
    for name, frame in zip(settings.camera_names, settings.frame_names):
        camera = rig.cameras.get(name)
        summary = CameraSummary(name=name, frame_id=frame, registered=camera is not None,
                                focal_std_px=-1.0, reprojection_rms_px=-1.0)
        if camera is not None:
            lens, quality = camera.intrinsics, camera.quality
            summary.model, summary.width, summary.height = lens.model, lens.width, lens.height
            summary.focal_px = float(lens.params[0])
            if quality is not None:
                summary.reprojection_rms_px = float(quality.reprojection_rms_px)
                summary.num_observations = int(quality.num_observations)
                if quality.focal_std_px is not None:
                    summary.focal_std_px = float(quality.focal_std_px)
        summaries.append(summary)
    return summaries


def result_msg(outcome: Outcome, settings: Settings) -> Calibrate.Result:
    result = Calibrate.Result(success=outcome.success, message=outcome.message,
                              reprojection_rms_px=-1.0, frame_sets=outcome.frame_sets,
                              elapsed_s=float(outcome.elapsed_s))
    if outcome.folder is not None:
        result.output_dir = str(outcome.folder)
    if outcome.rig is not None:
        result.reprojection_rms_px = float(outcome.rig.quality.fit_rms_px())
        result.cameras = camera_summaries(outcome.rig, settings)
    return result


class CalibrateAction:
    """The ~/calibrate action server of `node` (a DenseCalibNode)."""

    def __init__(self, node):
        self._node = node
        self._lock = threading.Lock()
        self._jobs: dict[bytes, Job] = {}  # goal id -> its calibration, while it runs
        self._cancelled: set[bytes] = set()  # goals whose own cancel stopped their calibration
        self._server = ActionServer(
            node, Calibrate, "~/calibrate", execute_callback=self._execute,
            goal_callback=self._on_goal, cancel_callback=self._on_cancel,
            callback_group=ReentrantCallbackGroup())

    def destroy(self) -> None:
        self._server.destroy()

    def _on_goal(self, goal: Calibrate.Goal) -> GoalResponse:
        if not self._node.jobs.stopping.is_set() and self._node.jobs.reason is None:
            return GoalResponse.ACCEPT
        self._node.set_status(f"calibrate goal rejected: {self._node.busy_line()}", "warning")
        return GoalResponse.REJECT

    def _on_cancel(self, goal_handle) -> CancelResponse:
        """A cancel of a running goal: its calibration is told to stop (it writes nothing);
        refused once the calibration is written (the goal then succeeds)."""
        key = bytes(goal_handle.goal_id.uuid)
        deadline = time.monotonic() + CANCEL_HANDOVER_S
        while (job := self._job_of(key)) is None and time.monotonic() < deadline:
            time.sleep(0.01)
        with self._lock:
            self._cancelled.add(key)
        why_not = (self._node.jobs.cancel("goal cancelled", job) if job is not None else
                   "the goal's calibration did not start")
        if why_not is not None:
            with self._lock:
                self._cancelled.discard(key)
            self._node.set_status(f"cancel of the calibrate goal refused: {why_not}", "warning")
            return CancelResponse.REJECT
        self._node.set_status("calibrate goal cancelled: stopping the calibration")
        return CancelResponse.ACCEPT

    def _job_of(self, key: bytes) -> Optional[Job]:
        with self._lock:
            return self._jobs.get(key)

    def _execute(self, goal_handle) -> Calibrate.Result:
        node, goal = self._node, goal_handle.request
        key = bytes(goal_handle.goal_id.uuid)
        try:
            settings = goal_settings(goal, parameter_values(node))
        except InputError as exc:
            goal_handle.abort()
            node.set_status(f"calibrate goal refused: {exc}", "error")
            return result_msg(Outcome(False, f"invalid goal: {exc}"), node.settings)
        job = node.start_calibration("action goal", settings, goal.from_scratch)
        if job is None:  # another job took the slot since the goal was accepted
            goal_handle.abort()
            return result_msg(Outcome(False, f"busy: {node.busy_line()}"), node.settings)
        with self._lock:
            self._jobs[key] = job
        self._feedback(goal_handle, job)
        try:
            outcome = node.jobs.wait_for(job, on_wait=lambda: self._feedback(goal_handle, job),
                                         period_s=FEEDBACK_PERIOD_S)
        finally:
            with self._lock:
                self._jobs.pop(key, None)
                cancelled_by_goal = key in self._cancelled
                self._cancelled.discard(key)
        if outcome.cancelled and cancelled_by_goal:
            deadline = time.monotonic() + CANCEL_HANDOVER_S  # ACCEPT may not be recorded yet
            while not goal_handle.is_cancel_requested and time.monotonic() < deadline:
                time.sleep(0.01)
        if outcome.cancelled and goal_handle.is_cancel_requested:
            goal_handle.canceled()
        elif outcome.success:
            goal_handle.succeed()
        else:  # failed, or stopped by ~/cancel or the shutdown
            goal_handle.abort()
        return result_msg(outcome, settings or node.settings)

    def _feedback(self, goal_handle, job: Job) -> None:
        try:
            goal_handle.publish_feedback(feedback_msg(job.progress.state()))
        except (InvalidHandle, _rclpy.RCLError):  # the node shutting down: answered anyway
            pass
