"""`densecalib_node`: calibrates a rigid camera rig from synchronised image topics (or a replayed
bag) on a service call and publishes CameraInfo per camera and the extrinsics on /tf_static.

Its interface (the ~/calibrate action, the services ~/calibrate ~/cancel ~/check ~/sync ~/reload
~/clear, the watch, the topics, the files under output_dir) is docs/ros.md's; its parameters are
ros/settings.py's table. The parts: intake (ros.intake, ros.sync), the action (ros.calibrate_action)
and the Trigger services (ros.services), the job slot, its cancel and its shutdown hand-over
(ros.job_slot), the calibration as a core.job request (ros.calibrating), the check (ros.checking),
the files (ros.calibration_files), what is published (ros.publishing, ros.diagnostics).

Threads: image callbacks (the intake's executor) only append to the synchroniser; a calibration
runs in the job slot's worker thread while its caller (service or action goal) waits
(multi-threaded executor), and stops at the core's next check when cancelled; a check (~/check,
or the watch's own timer) runs in its caller's thread; a calibration, a check and a reload hold
the slot in turn.
"""
from __future__ import annotations

import functools
import time
from pathlib import Path
from typing import Callable, Optional

from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import SetParametersResult
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.exceptions import InvalidHandle
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.parameter import Parameter
from std_msgs.msg import String

from ..core.errors import CalibrationCancelled, CalibrationError, InputError
from ..core.io.calibration_store import prune_calibrations
from ..core.io.sync import evenly_spaced
from ..core.progress import Progress, StopToken
from ..core.types import RigCalibration
from .calibrate_action import CalibrateAction
from .calibrating import UNSCALED, calibrated_message, calibration_request
from .calibration_files import (check_output_dir, latest_calibration, save_found_floor,
                                write_calibration)
from .checking import CheckOutcome, check_frame_sets
from .core_logs import forward_core_logs, stop_forwarding
from .diagnostics import rig_diagnostic_status
from .frame_loss import LOSS_HINT
from .intake import CameraSubscriptions, ImageIntake
from .job_slot import ABANDONED, CHECK_JOB, RELOAD_JOB, Job, JobSlot, Outcome
from .parameters import declare_parameters, parameter_values
from .publishing import LATCHED_QOS, CalibrationPublisher, floor_parent
from .replay import BagReplayer
from .services import TriggerServices
from .settings import PARAMETERS, Settings, parse_settings
from .sync import MessageSynchronizer, malformed_note, offsets_line
from .watch import WATCH_CONFIRM_SETS, Watch


def _ends_with_the_node(callback: Callable[[], None]) -> Callable[[], None]:
    """A timer callback that ends quietly when destroy_node ran while it was due or running (its
    publishers gone): an exception from a callback ends the executor's spin() for every node it
    serves, so one node shut down beside others would silence them all."""
    @functools.wraps(callback)
    def run() -> None:
        try:
            callback()
        except InvalidHandle:
            pass
    return run


class DenseCalibNode(Node):
    """The calibration node (module docstring: interface and threading)."""

    def __init__(self, node_name: str = "densecalib_node", **node_kwargs):
        super().__init__(node_name, **node_kwargs)
        self._core_logs = forward_core_logs(self.get_logger().get_child("core"))
        self._replayer: Optional[BagReplayer] = None
        self._intake: Optional[ImageIntake] = None
        self._calibrate_action: Optional[CalibrateAction] = None
        self.jobs = JobSlot()
        declare_parameters(self)
        try:
            self.settings = parse_settings(parameter_values(self))
            check_output_dir(self.settings.output_dir)
        except InputError:
            self.destroy_node()
            raise
        self.add_on_set_parameters_callback(self._on_set_parameters)
        s = self.settings

        self.calibration: Optional[RigCalibration] = None
        self.calibration_dir: Optional[Path] = None
        self._calibrated_at: Optional[float] = None  # time.time() of the published calibration
        self.last_failure: Optional[str] = None
        self._status = "idle"
        self._last_check: Optional[CheckOutcome] = None
        self._watch_sets = Watch()
        self._matcher = None  # ((name, max side), loaded core.method.matching.Matcher)

        self.sync = MessageSynchronizer(len(s.image_topics), s.slop_s, s.buffer_size,
                                        s.min_interval_s, s.sync_queue_size, s.stamp_offsets_s,
                                        s.sync_window_s)
        # the image subscriptions: on a single-threaded executor of their own (ros.intake)
        self._intake = ImageIntake(self)
        self._timer_group = MutuallyExclusiveCallbackGroup()

        # latched: a subscriber arriving late (a dashboard, ros2 topic echo) sees the state now
        self._status_pub = self.create_publisher(String, "~/status", LATCHED_QOS)
        self.publisher = CalibrationPublisher(self)
        self._diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self._trigger_services = TriggerServices(self)
        self._calibrate_action = CalibrateAction(self)

        self.camera_subscriptions = CameraSubscriptions(self, self._intake, s, self.sync)
        if not self.camera_subscriptions.complete:
            self._discovery_timer = self.create_timer(
                0.5, _ends_with_the_node(self._subscribe_discovered_topics),
                callback_group=self._timer_group)
        self.create_timer(1.0, _ends_with_the_node(self.publish_diagnostics),
                          callback_group=self._timer_group)
        # the watch's checks take seconds: a group of their own keeps diagnostics flowing
        self.create_timer(1.0, _ends_with_the_node(self._watch),
                          callback_group=MutuallyExclusiveCallbackGroup())

        loaded, message = self.load_last_calibration(fall_back=True)
        (self.get_logger().info if loaded or "no calibration" in message else
         self.get_logger().error)(f"start-up: {message}")
        if s.replay_bag:
            self._replayer = BagReplayer(
                s.replay_bag, s.image_topics, lambda i, t_ns, msg: self.sync.add(i, msg, t_ns),
                rate=s.replay_rate, on_done=self._on_replay_done, logger=self.get_logger())
            self._replayer.start()
        self.get_logger().info(
            f"ready: {len(s.image_topics)} cameras ({', '.join(s.camera_names)}), preset "
            f"{s.preset}, pipeline {s.pipeline}, matcher {s.matcher}; send a goal to the action "
            f"(or call the service) {self.resolve_service_name('~/calibrate')} to calibrate")

    # ----------------------------------------------------------------- parameters
    def _on_set_parameters(self, params: list[Parameter]) -> SetParametersResult:
        ours = [p for p in params if p.name in PARAMETERS]  # others: e.g. use_sim_time
        if not ours:
            return SetParametersResult(successful=True)
        try:
            new = parse_settings(parameter_values(self, ours))
        except InputError as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        old, self.settings = self.settings, new
        if new.stamp_offsets_s != old.stamp_offsets_s:
            dropped = self.sync.set_offsets(new.stamp_offsets_s)
            self.get_logger().info(
                offsets_line(new.camera_names, new.stamp_offsets_s)
                + f"; {dropped} buffered frame sets dropped (paired by the old offsets)")
        if self.calibration is not None:
            t_ns = self.get_clock().now().nanoseconds
            if new.stereo_pairs != old.stereo_pairs:
                self.publisher.publish_camera_infos(self.calibration, t_ns)
            if floor_parent(new) != floor_parent(old):
                if new.floor and not self.calibration.quality.floor:
                    self._find_floor_of_current_calibration(new.floor)
                self.publisher.publish_tf(self.calibration, t_ns)
        return SetParametersResult(successful=True)

    def _find_floor_of_current_calibration(self, view: str) -> None:
        """`floor` turned on for a calibration made without it: found in its saved scene points
        (as `densecalib floor` does) and recorded (ros.calibration_files.save_found_floor); not
        found, the calibration stays as it is and the status says why."""
        from ..core.products.floor import find_floor_of_saved_calibration

        try:
            floor = find_floor_of_saved_calibration(self.calibration_dir, self.calibration, view)
        except InputError as exc:
            self.set_status(f"floor: not found in {self.calibration_dir.name}: {exc}", "warning")
            return
        self.set_status(save_found_floor(self.calibration_dir, self.calibration, floor))

    # ----------------------------------------------------------------- intake
    def _subscribe_discovered_topics(self) -> None:
        """Timer: subscribe 'auto' topics once the graph tells their type."""
        self.camera_subscriptions.subscribe_discovered()
        if self.camera_subscriptions.complete:
            self._discovery_timer.cancel()

    def _on_replay_done(self, num_messages: int, error: Optional[str]) -> None:
        if error:
            self.set_status(f"replay failed: {error}", "error")
            return
        self.set_status(f"replay done: {num_messages} messages, {len(self.sync)} frame sets "
                         "buffered")
        if self.settings.calibrate_after_replay:
            if self.start_calibration("after replay") is None:
                self.get_logger().warning("not calibrating after the replay: a calibration is "
                                          "already running")

    # ----------------------------------------------------------------- calibration
    def start_calibration(self, reason: str, settings: Optional[Settings] = None,
                          from_scratch: bool = False) -> Optional[Job]:
        """Start a calibration in the worker thread, with `settings` (default: the node's at its
        start), from the published calibration unless from_scratch; None when a job is
        running. The job's Progress says where it is and stops it (jobs.cancel)."""
        progress = Progress(on_message=lambda msg: self.set_status(f"calibrating: {msg}", None),
                            stop=StopToken())
        return self.jobs.start_worker(reason, self._run_job, settings=settings,
                                      from_scratch=from_scratch, progress=progress)

    def busy_line(self) -> str:
        """What holds the job slot, in words."""
        reason = self.jobs.reason
        return ("a check is running" if reason == CHECK_JOB else
                "a reload is running" if reason == RELOAD_JOB else
                f"a calibration is already running ({reason})" if reason else
                "the node is shutting down" if self.jobs.stopping.is_set() else "idle")

    def _run_job(self, job: Job) -> None:
        start = time.perf_counter()
        try:
            job.outcome = self._calibrate(job, start)
        except CalibrationCancelled as exc:  # jobs.cancel() or shutdown: nothing written
            job.outcome = Outcome(False, ABANDONED if self.jobs.stopping.is_set() else
                                  f"cancelled after {time.perf_counter() - start:.1f} s "
                                  f"({exc}): nothing written", cancelled=True)
        except CalibrationError as exc:
            job.outcome = Outcome(False, f"calibration failed after "
                                         f"{time.perf_counter() - start:.1f} s: {exc}")
        except Exception as exc:  # a bug or an OS error must still answer the service call
            if isinstance(exc, (InvalidHandle, _rclpy.RCLError)) and self.jobs.stopping.is_set():
                job.outcome = Outcome(False, "the node shut down before the calibration was "
                                             "published (its files, if written, load at start-up)")
            else:
                self.get_logger().error(f"calibration crashed: {exc!r}")
                detail = str(exc) if isinstance(exc, OSError) else repr(exc)  # str names the file
                job.outcome = Outcome(False, f"calibration crashed after "
                                             f"{time.perf_counter() - start:.1f} s: {detail}")
        job.outcome.elapsed_s = time.perf_counter() - start
        self._said_outcome(job.outcome)

    def _said_outcome(self, outcome: Outcome) -> None:
        """A calibration's outcome on ~/status and in the log (a failure at ERROR, and on
        /diagnostics until the next success; a cancel is no failure)."""
        if not outcome.success and self.calibration_dir is not None \
                and not self.jobs.stopping.is_set():
            outcome.message += f"; still publishing the calibration of {self.calibration_dir.name}"
        if outcome.success:
            self.last_failure = None
            self.get_logger().info(outcome.message)
        elif outcome.cancelled:
            self.get_logger().warning(outcome.message)
        else:
            self.last_failure = outcome.message
            self.get_logger().error(outcome.message)
        self.set_status(("done: " if outcome.success else "cancelled: " if outcome.cancelled
                         else "failed: ") + outcome.message, level=None)

    def run_check(self, sets: Optional[list] = None) -> Optional[CheckOutcome]:
        """A check of `sets` (default: the buffer, as ~/check does); None when a job is running.
        It holds the job slot, so that no calibration swaps the matcher meanwhile."""
        with self.jobs.held(CHECK_JOB) as held:
            if not held:
                return None
            try:
                outcome = self._check(sets)
            except CalibrationError as exc:  # InputError included
                outcome = CheckOutcome(None, f"check failed: {exc}")
            except Exception as exc:  # a bug must still answer the call
                self.get_logger().error(f"check crashed: {exc!r}")
                outcome = CheckOutcome(None, f"check crashed: {exc!r}")
        outcome.calibration_dir = self.calibration_dir
        self._last_check = outcome
        return outcome

    def _watch(self) -> None:
        """Timer: with check_interval_s > 0, check the calibration when frame sets arrived since
        the last check (ros.watch); with recalibrate_on_change, recalibrate when it no longer
        fits."""
        sets = (self._watch_sets.sets_to_check(self.settings, self.sync.snapshot())
                if self.calibration is not None else None)
        if sets is None:
            return
        outcome = self.run_check(sets)
        if outcome is None:
            return  # busy: try again at the next tick
        self._watch_sets.checked(sets)
        self.set_status(f"watch: {outcome.message}",
                         "warning" if outcome.fits is False else "info")
        if outcome.fits is False and self.settings.recalibrate_on_change:
            if outcome.misfit_sets < WATCH_CONFIRM_SETS:
                self.set_status(f"watch: {outcome.misfit_sets} frame set does not fit; "
                                 "recalibrating when the next one confirms it")
            elif self.start_calibration("watch: the calibration no longer fits") is not None:
                self.set_status("watch: recalibrating, the calibration no longer fits")

    def _check(self, sets: Optional[list] = None) -> CheckOutcome:
        s, rig = self.settings, self.calibration
        if rig is None:
            return CheckOutcome(None, "no calibration to check yet: call ~/calibrate first")
        sets = evenly_spaced(self.sync.snapshot() if sets is None else sets, s.max_frame_sets)
        if not sets:
            return CheckOutcome(None, "no synchronised frame sets buffered to check the "
                                      "calibration with: "
                                + self.sync.why_few_sets(s.camera_names, s.image_topics))
        sets, images = self._decoded(sets, 1)
        return check_frame_sets(rig, self.calibration_dir, s, sets, images, self._matcher_for(s))

    def _decoded(self, sets: list, needed: int) -> tuple[list, list]:
        """The sets whose images decode and their images; a camera whose frames do not decode
        is named at WARN (and on /diagnostics), and InputError when fewer than `needed` sets
        are left."""
        sets, images, dropped = self.sync.decode(sets)
        note = malformed_note(self.settings.camera_names, dropped, self.sync.last_malformed)
        if note:
            self.get_logger().warning(note)
        if len(sets) < needed:
            raise InputError(f"{len(sets)} frame set(s) whose images all decode, {needed} needed; "
                             f"{note or 'none buffered'}.")
        return sets, images

    def _calibrate(self, job: Job, start: float) -> Outcome:
        from ..core.job import run_job  # heavy (pycolmap, matchers): import on use

        s = job.settings or self.settings
        sets = self.sync.snapshot()
        if len(sets) < s.min_frame_sets:
            raise InputError(f"{len(sets)} synchronised frame set(s) buffered, {s.min_frame_sets} "
                             f"needed: {self.sync.why_few_sets(s.camera_names, s.image_topics)}")
        sets = evenly_spaced(sets, s.max_frame_sets)
        previous = None if job.from_scratch else self.calibration
        self.set_status(f"calibrating {len(sets)} frame sets ({s.preset}, {s.pipeline}, "
                        f"{s.matcher}{', from scratch' if job.from_scratch else ''})")
        sets, images = self._decoded(sets, s.min_frame_sets)
        request = calibration_request(s, sets, images, previous, self.calibration_dir,
                                      self._matcher_for(s))
        # the core's events on ~/status only: it logged them, and core_logs forwards to /rosout
        result = run_job(request, progress=job.progress)
        rig, reconstruction = result.rig, result.calibration.reconstruction
        before_change = rig.quality.frame_sets_before_change or 0
        if before_change:  # the provenance (core.io.export) names the frame sets calibrated
            rig.quality.input["frame_set_stamps_ns"] = \
                request.source["frame_set_stamps_ns"][before_change:]
        sets = sets[before_change:]
        elapsed = time.perf_counter() - start
        with self.jobs.writing_files(job):
            out = self.write_files(rig, reconstruction, result.reference_views)
            self._publish(rig, out)
        removed = prune_calibrations(s.output_dir, s.keep_calibrations, [out])
        set_info = (self.publisher.call_set_camera_info(rig) if s.call_set_camera_info
                    else None)
        return Outcome(True, calibrated_message(s, rig, len(sets), elapsed, out, removed,
                                                self.publisher.stereo_problem, set_info),
                       folder=out, rig=rig, frame_sets=len(sets))

    def _matcher_for(self, s: Settings):
        """The loaded matcher of the current settings, kept across calibrations (loading learned
        weights takes seconds)."""
        from ..core.method.matching import create_matcher

        key = (s.matcher, s.max_image_side_px)
        if self._matcher is None or self._matcher[0] != key:
            matcher = create_matcher(s.matcher, max_image_side_px=s.max_image_side_px)
            matcher.load()
            self._matcher = (key, matcher)
        return self._matcher[1]

    # ----------------------------------------------------------------- outputs
    def write_files(self, rig: RigCalibration, reconstruction=None,
                     reference_views: Optional[dict] = None) -> Path:
        """The calibration's new folder under output_dir, `latest` swapped onto it; the
        stereo_pairs' YAML files with their rectification, as published."""
        rectified, _ = self.publisher.rectifications(rig)
        return write_calibration(self.settings.output_dir, rig, rectified, reconstruction,
                                 reference_views)

    def load_last_calibration(self, fall_back: bool = False) -> tuple[bool, str]:
        """Publish the calibration under output_dir/latest (ros.calibration_files); (published?,
        what happened). Anything wrong with it leaves the current calibration published."""
        s = self.settings
        try:
            stored = latest_calibration(s.output_dir, s.camera_names, fall_back)
        except InputError as exc:
            return False, str(exc)
        if stored.instead:
            self.get_logger().warning(f"start-up: {stored.instead}")
        self._publish(stored.rig, stored.folder, stored.made_at)
        return True, stored.published_line(floor_on=floor_parent(s) is not None)

    def _publish(self, rig: RigCalibration, directory: Path,
                 calibrated_at: Optional[float] = None) -> None:
        """Publish CameraInfo per calibrated camera and all extrinsics in one /tf_static message;
        calibrated_at: when the calibration was made (time.time(); default now), for its age."""
        self.publisher.publish(rig, directory)
        if not rig.metric_scale:
            self.get_logger().warning(f"{directory.name}: {UNSCALED}")
        self.calibration, self.calibration_dir = rig, directory
        self._calibrated_at = time.time() if calibrated_at is None else calibrated_at
        self.publish_diagnostics()

    # ----------------------------------------------------------------- status
    def set_status(self, text: str, level: Optional[str] = "info") -> None:
        """Publish the status and log it at `level` ("info", "warning", "error"; None: not at
        all, the caller logged it): a failure must be found among /rosout's errors."""
        self._status = text
        try:
            self._status_pub.publish(String(data=text))
        except (InvalidHandle, _rclpy.RCLError):  # shutdown while a calibration runs or ends
            pass
        # one call site per severity: rclpy refuses a site whose severity changes
        if level == "info":
            self.get_logger().info(text)
        elif level == "warning":
            self.get_logger().warning(text)
        elif level == "error":
            self.get_logger().error(text)

    @property
    def busy(self) -> bool:
        return self.jobs.reason is not None

    def publish_diagnostics(self) -> None:
        reason = self.jobs.reason
        state = ("idle" if reason is None else
                 {CHECK_JOB: "checking", RELOAD_JOB: "reloading"}.get(reason, "calibrating"))
        status, losing = rig_diagnostic_status(
            f"{self.get_name()}: rig calibration", self.settings, self.sync.stats(),
            self.sync.last_malformed, state, self._status, self.calibration,
            self.calibration_dir, self._calibrated_at, self.last_failure, self._last_check)
        if losing:
            self.get_logger().warning(
                f"{', '.join(losing)} of the recent frames missing (gaps in the header stamps): "
                + LOSS_HINT, throttle_duration_sec=60.0)
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = self.get_clock().now().to_msg()
        self._diag_pub.publish(msg)

    def stop(self) -> None:
        """Shutdown begins: the job slot's hand-over (ros.job_slot: answer, write nothing)."""
        self.jobs.stop()

    def destroy_node(self):
        self.stop()
        stop_forwarding(self._core_logs)
        if self._replayer is not None:
            self._replayer.stop()
        if self._intake is not None:
            self._intake.destroy()
        if self._calibrate_action is not None:
            self._calibrate_action.destroy()
        return super().destroy_node()

