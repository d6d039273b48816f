"""`densecalib_node`: calibrates a rigid camera rig from synchronised image topics (or a replayed
bag) on a service call and publishes CameraInfo per camera and the extrinsics on /tf_static.

Interface (names relative to the node, default name `densecalib_node`):
- subscribes: `image_topics` (sensor_msgs/Image or CompressedImage, sensor-data QoS);
- service `~/calibrate` (std_srvs/Trigger): calibrates on the buffered frame sets; answers with a
  one-line summary, or the reason of the failure; a call while one runs is refused ("busy");
- service `~/check` (std_srvs/Trigger): holds the buffered frame sets against the current
  calibration without recalibrating (core.monitor.consistency.check_latest: when the older sets fit
  and the newer do not, the newer are judged; and core.monitor.reference_views: each camera's latest
  images against its view at calibration time); success = it still fits, the message names a camera
  that moved and, after a change inside the buffer, when;
- the watch (timer): with check_interval_s > 0, the same check on the frame sets that arrived
  since the last one (and the one before them), its verdict on ~/status and /diagnostics; with
  recalibrate_on_change, a recalibration when the calibration no longer fits;
- service `~/sync` (std_srvs/Trigger): measures the cameras' stamp offsets from what moves in
  their latest `sync_window_s` seconds of images (core.io.motion_sync) and sets `stamp_offsets_s`;
- service `~/reload` (std_srvs/Trigger): publishes the calibration under `output_dir/latest`
  again, after `densecalib scale` / `floor` changed it or `latest` was pointed at another one;
  one that cannot be loaded leaves the current one published;
- service `~/clear` (std_srvs/Trigger): drops the buffered frame sets (after the rig was moved:
  the next calibration uses only images received since);
- publishes `~/status` (std_msgs/String: progress and state), `~/<camera>/camera_info`
  (sensor_msgs/CameraInfo, reliable, transient local, depth 1; the `stereo_pairs`' with their
  stereo rectification R, P, republished when that parameter changes), `/tf_static`
  (tf2_msgs/TFMessage, all cameras in one message, transient local, depth 1; with `floor` on,
  also floor_frame -> rig_frame), `~/points` (sensor_msgs/PointCloud2, transient local, depth
  1: the calibration's scene points in rig_frame, x y z rgb), `/diagnostics`
  (diagnostic_msgs/DiagnosticArray, 1 Hz; WARN when the last check found a camera moved);
- calls (optional) `<camera ns>/set_camera_info` (sensor_msgs/SetCameraInfo) with a timeout;
- files: `output_dir/<UTC timestamp>/` (calibration.json, <camera>.yaml, colmap/,
  reference_views/) written atomically, then the `output_dir/latest` symlink is swapped
  atomically (core.io.calibration_store); with keep_calibrations > 0 the oldest beyond that many
  are then removed. At start-up the calibration under `latest` is republished. A failed
  calibration publishes, writes and removes nothing.

Parameters: ros/settings.py (the table, their validation into Settings, the pipeline
configuration they select).

Threads: subscription callbacks (one callback group for all) only append messages to the
synchroniser (and, with sync_window_s > 0, add a small grey copy to the camera's motion signal);
a calibration runs in its own worker thread; the service callback (reentrant group,
multi-threaded executor) waits for its result while the executor keeps serving subscriptions,
timers and other service calls. A check (~/check, or the watch's timer in a group of its own)
runs in its caller's thread; it and a calibration hold the one job slot in turn.
"""
from __future__ import annotations

import functools
import math
import os
import signal
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Optional

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup
from rclpy.exceptions import (InvalidHandle, InvalidParameterTypeException,
                              InvalidParameterValueException)
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.parameter import Parameter
from sensor_msgs.msg import CompressedImage, Image
from std_msgs.msg import String
from std_srvs.srv import Trigger

from ..core.colmap_logging import show_colmap_log
from ..core.errors import CalibrationError, InputError
from ..core.io.calibration_store import (LATEST, prune_calibrations, stored_calibrations,
                                         write_new_calibration)
from ..core.io.camera_info import camera_info_yaml
from ..core.io.export import read_calibration, write_calibration_files, write_calibration_json
from ..core.io.safe_write import write_text_atomic
from ..core.io.sync import FrameSet, evenly_spaced
from ..core.method.known_intrinsics import with_previous_intrinsics
from ..core.products.report import info_strips_line
from ..core.types import RigCalibration
from .core_logs import forward_core_logs, stop_forwarding
from .checking import CheckOutcome, check_frame_sets
from .diagnostics import rig_diagnostic_status
from .frame_loss import LOSS_HINT
from .intake import ImageIntake
from .publishing import CalibrationPublisher, floor_parent
from .replay import BagReplayer
from .settings import PARAMETERS, Settings, is_list_parameter, parse_settings, pipeline_config
from .sync import MessageSynchronizer, malformed_note
from .transport import configure_intake_transport

@dataclass
class Outcome:
    success: bool
    message: str


CHECK_JOB = "check"  # the reasons of the job slot a ~/check and a ~/reload hold
RELOAD_JOB = "reload"
# How long a ~/calibrate caller waits, once the node stops, for a calibration that is writing its
# files (well under a second) to end: main() gives the callers 2 s to be answered.
_WRITE_GRACE_S = 1.5
# The watch recalibrates on a change seen in at least this many frame sets: a frame set alone can
# be odd (few matches, something that moved between the shots of unsynchronised cameras), and is
# not worth replacing a good calibration.
WATCH_CONFIRM_SETS = 2


@dataclass
class _Job:
    reason: str
    done: threading.Event = field(default_factory=threading.Event)
    outcome: Optional[Outcome] = None


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
        self._stopping = threading.Event()  # stop(): answer waiting callers, write nothing
        # set while a calibration's files are written and published: a stop then lets it end
        # (the files become current either way) and the caller is told what happened; the lock
        # orders that against stop(), so a calibration either writes or is abandoned
        self._writing = threading.Event()
        self._write_lock = threading.Lock()
        self._callers_waiting, self._num_callers_waiting = threading.Condition(), 0
        self._declare_parameters()
        try:
            self.settings = parse_settings(self._parameter_values())
            _check_output_dir(self.settings.output_dir)
        except InputError:
            self.destroy_node()
            raise
        self.add_on_set_parameters_callback(self._on_set_parameters)
        s = self.settings

        self._state_lock = threading.Lock()
        self._job: Optional[_Job] = None
        self._worker: Optional[threading.Thread] = None
        self.calibration: Optional[RigCalibration] = None
        self.calibration_dir: Optional[Path] = None
        self._calibrated_at: Optional[float] = None  # time.time() of the published calibration
        self._last_failure: Optional[str] = None
        self._status = "idle"
        self._last_check: Optional[CheckOutcome] = None
        # the newest frame set a watch check has seen (by identity: stamps may jump back when
        # a bag is replayed again or sim time restarts; the buffer only appends and drops)
        self._watched_last: Optional[FrameSet] = None
        self._last_watch = -math.inf  # time.monotonic() of the last watch check
        self._matcher = None  # ((name, max side), loaded core.method.matching.Matcher)

        self.sync = MessageSynchronizer(len(s.image_topics), s.slop_s, s.buffer_size,
                                        s.min_interval_s, s.sync_queue_size, s.stamp_offsets_s,
                                        s.sync_window_s)
        # the image subscriptions: on a single-threaded executor of their own (ros.intake)
        self._intake = ImageIntake(self)
        self._timer_group = MutuallyExclusiveCallbackGroup()
        self._service_group = ReentrantCallbackGroup()
        self._image_subs: list = [None] * len(s.image_topics)

        self._status_pub = self.create_publisher(String, "~/status", 20)
        self.publisher = CalibrationPublisher(self)
        self._diag_pub = self.create_publisher(DiagnosticArray, "/diagnostics", 10)
        for name, callback in (("~/calibrate", self._on_calibrate), ("~/check", self._on_check),
                               ("~/sync", self._on_sync), ("~/reload", self._on_reload),
                               ("~/clear", self._on_clear)):
            self.create_service(Trigger, name, callback, callback_group=self._service_group)

        self._subscribe_known_topics()
        if None in self._image_subs:
            self._discovery_timer = self.create_timer(
                0.5, _ends_with_the_node(self._subscribe_discovered_topics),
                callback_group=self._timer_group)
        self.create_timer(1.0, _ends_with_the_node(self._publish_diagnostics),
                          callback_group=self._timer_group)
        # the watch's checks take seconds: a group of their own keeps diagnostics flowing
        self.create_timer(1.0, _ends_with_the_node(self._watch),
                          callback_group=MutuallyExclusiveCallbackGroup())

        loaded, message = self._load_last_calibration(fall_back=True)
        (self.get_logger().info if loaded or "no calibration" in message else
         self.get_logger().error)(f"start-up: {message}")
        if s.replay_bag:
            self._replayer = BagReplayer(s.replay_bag, s.image_topics, self._on_replayed_message,
                                         rate=s.replay_rate, on_done=self._on_replay_done,
                                         logger=self.get_logger())
            self._replayer.start()
        self.get_logger().info(
            f"ready: {len(s.image_topics)} cameras ({', '.join(s.camera_names)}), preset "
            f"{s.preset}, pipeline {s.pipeline}, matcher {s.matcher}; call "
            f"{self.resolve_service_name('~/calibrate')} to calibrate")

    # ----------------------------------------------------------------- parameters
    def _declare_parameters(self) -> None:
        """Every parameter of ros.settings.PARAMETERS, with its description and range."""
        for name, (default, description, read_only, ranges) in PARAMETERS.items():
            if is_list_parameter(name):  # any array type, checked by parse_settings; [] if unset
                self.declare_parameter(name, [], ParameterDescriptor(
                    description=description, read_only=read_only, dynamic_typing=True))
                continue
            self.declare_parameter(name, default, ParameterDescriptor(
                description=description, read_only=read_only, **ranges))

    def _parameter_values(self, changes: Optional[list[Parameter]] = None) -> dict[str, Any]:
        values = {}
        for name in PARAMETERS:
            param = self.get_parameter_or(name, Parameter(name, Parameter.Type.NOT_SET, None))
            values[name] = param.value
        for p in changes or []:
            values[p.name] = p.value
        return values

    def _on_set_parameters(self, params: list[Parameter]) -> SetParametersResult:
        ours = [p for p in params if p.name in PARAMETERS]  # others: e.g. use_sim_time
        if not ours:
            return SetParametersResult(successful=True)
        try:
            new = parse_settings(self._parameter_values(ours))
        except InputError as exc:
            return SetParametersResult(successful=False, reason=str(exc))
        old, self.settings = self.settings, new
        if new.stamp_offsets_s != old.stamp_offsets_s:
            dropped = self.sync.set_offsets(new.stamp_offsets_s)
            self.get_logger().info(
                "stamp offsets [s]: " + ", ".join(f"{n} {o:+.4f}" for n, o in zip(
                    new.camera_names, new.stamp_offsets_s))
                + f"; {dropped} buffered frame sets dropped (paired by the old offsets)")
        if self.calibration is not None:
            t_ns = self.get_clock().now().nanoseconds
            if new.stereo_pairs != old.stereo_pairs:
                self.publisher.publish_camera_infos(self.calibration, t_ns)
            if floor_parent(new) != floor_parent(old):
                if new.floor and not self.calibration.quality.get("floor"):
                    self._find_floor_of_current_calibration(new.floor)
                self.publisher.publish_tf(self.calibration, t_ns)
        return SetParametersResult(successful=True)

    def _find_floor_of_current_calibration(self, view: str) -> None:
        """`floor` turned on for a calibration made without it: find the floor in its saved
        scene points (as `densecalib floor` does) and record it in its calibration.json, so that
        it is published now and after a restart. No floor found: the calibration stays as it is
        and the status says why."""
        from ..core.products.floor import find_floor_of_saved_calibration, set_floor

        try:
            floor = find_floor_of_saved_calibration(self.calibration_dir, self.calibration, view)
        except InputError as exc:
            self._set_status(f"floor: not found in {self.calibration_dir.name}: {exc}", "warning")
            return
        set_floor(self.calibration, floor)
        write_calibration_json(self.calibration, self.calibration_dir)
        self._set_status(f"floor: found in {self.calibration_dir.name} ({floor.num_points} "
                         f"points) and recorded in its calibration.json")

    # ----------------------------------------------------------------- intake
    def _subscribe(self, i: int, compressed: bool) -> None:
        s = self.settings
        msg_type = CompressedImage if compressed else Image
        topic = self.resolve_topic_name(s.image_topics[i])  # namespace and remappings applied
        self._image_subs[i] = self._intake.subscribe(
            msg_type, topic, lambda msg, i=i: self.sync.add(i, msg),
            on_lost=lambda total, i=i: self.sync.add_lost(i, total))
        given = "" if topic == s.image_topics[i] else f", image_topics: {s.image_topics[i]}"
        self.get_logger().info(f"camera {s.camera_names[i]}: subscribed to {topic} "
                               f"({msg_type.__name__}{given})")

    def _subscribe_known_topics(self) -> None:
        for i, (topic, transport) in enumerate(zip(self.settings.image_topics,
                                                   self.settings.transports)):
            if transport == "auto" and topic.rstrip("/").endswith("/compressed"):
                transport = "compressed"
            if transport != "auto":
                self._subscribe(i, transport == "compressed")

    def _subscribe_discovered_topics(self) -> None:
        """Timer: subscribe 'auto' topics once the graph tells their type."""
        types = dict(self.get_topic_names_and_types())
        for i, topic in enumerate(self.settings.image_topics):
            if self._image_subs[i] is not None:
                continue
            found = types.get(self.resolve_topic_name(topic), [])
            if "sensor_msgs/msg/CompressedImage" in found:
                self._subscribe(i, True)
            elif "sensor_msgs/msg/Image" in found:
                self._subscribe(i, False)
            elif found:
                self.get_logger().error(f"{topic} has type {found}, not an image: fix image_topics",
                                        throttle_duration_sec=30.0)
        if None not in self._image_subs:
            self._discovery_timer.cancel()

    def _on_replayed_message(self, stream: int, stamp_ns: int, msg) -> None:
        self.sync.add(stream, msg, stamp_ns)

    def _on_replay_done(self, num_messages: int, error: Optional[str]) -> None:
        if error:
            self._set_status(f"replay failed: {error}", "error")
            return
        self._set_status(f"replay done: {num_messages} messages, {len(self.sync)} frame sets "
                         "buffered")
        if self.settings.calibrate_after_replay:
            if self.start_calibration("after replay") is None:
                self.get_logger().warning("not calibrating after the replay: a calibration is "
                                          "already running")

    # ----------------------------------------------------------------- calibration
    def start_calibration(self, reason: str) -> Optional[_Job]:
        """Start a calibration in the worker thread; None when one is already running."""
        with self._state_lock:
            if self._job is not None:
                return None
            job = self._job = _Job(reason)
        self._worker = threading.Thread(target=self._run_job, args=(job,),
                                        name="densecalib-worker", daemon=True)
        self._worker.start()
        return job

    def _on_calibrate(self, request, response):
        job = self.start_calibration("service call")
        if job is None:
            response.success = False
            response.message = "busy: a calibration is already running; call again when it ends"
            return response
        with self._callers_waiting:
            self._num_callers_waiting += 1
        try:
            while not job.done.wait(0.2):
                if self._stopping.is_set():  # main() waits for this answer, not for the job
                    if self._writing.is_set() and job.done.wait(_WRITE_GRACE_S):
                        break  # it was writing its files: its own outcome says what happened
                    response.success = False
                    response.message = (
                        "the node is shutting down while the calibration's files are written: "
                        "if the write completes, `latest` points at them and the node publishes "
                        "them at its next start" if self._writing.is_set() else
                        "the node is shutting down: the calibration was abandoned; the last "
                        "calibration stays as it was")
                    return response
            response.success = job.outcome.success
            response.message = job.outcome.message
            return response
        finally:
            with self._callers_waiting:
                self._num_callers_waiting -= 1
                self._callers_waiting.notify_all()

    def answer_waiting_callers(self, timeout_s: float) -> None:
        """At shutdown, after stop(): wait (up to timeout_s) until every ~/calibrate caller
        waiting for the abandoned calibration has had its answer returned."""
        with self._callers_waiting:
            self._callers_waiting.wait_for(lambda: self._num_callers_waiting == 0, timeout_s)

    def _run_job(self, job: _Job) -> None:
        start = time.perf_counter()
        try:
            job.outcome = self._calibrate(start)
        except CalibrationError as exc:
            job.outcome = Outcome(False, f"calibration failed after "
                                         f"{time.perf_counter() - start:.1f} s: {exc}")
        except Exception as exc:  # a bug or an OS error must still answer the service call
            if isinstance(exc, (InvalidHandle, _rclpy.RCLError)) and self._stopping.is_set():
                job.outcome = Outcome(False, "the node shut down before the calibration was "
                                             "published (its files, if written, load at start-up)")
            else:
                self.get_logger().error(f"calibration crashed: {exc!r}")
                detail = str(exc) if isinstance(exc, OSError) else repr(exc)  # str names the file
                job.outcome = Outcome(False, f"calibration crashed after "
                                             f"{time.perf_counter() - start:.1f} s: {detail}")
        if not job.outcome.success:
            kept = (f"; still publishing the calibration of {self.calibration_dir.name}"
                    if self.calibration_dir is not None and not self._stopping.is_set() else "")
            job.outcome.message += kept
            self._last_failure = job.outcome.message
            self.get_logger().error(job.outcome.message)
        else:
            self._last_failure = None
            self.get_logger().info(job.outcome.message)
        self._set_status(("done: " if job.outcome.success else "failed: ") + job.outcome.message,
                         level=None)
        with self._state_lock:
            self._job = None
        job.done.set()

    def _on_check(self, request, response):
        """~/check: the buffer against the current calibration, in this service thread (matching
        only: seconds)."""
        outcome = self._run_check()
        response.success = bool(outcome and outcome.fits)
        response.message = (outcome.message if outcome else
                            "busy: a calibration or check is running")
        self._set_status(f"check: {response.message}",
                         "info" if response.success or outcome is None else "warning")
        return response

    def _run_check(self, sets: Optional[list] = None) -> Optional[CheckOutcome]:
        """A check of `sets` (default: the buffer, as ~/check does); None when a job is running.
        It holds the job slot, so that no calibration swaps the matcher meanwhile."""
        with self._state_lock:
            if self._job is not None:
                return None
            self._job = _Job(CHECK_JOB)
        try:
            outcome = self._check(sets)
        except CalibrationError as exc:  # InputError included
            outcome = CheckOutcome(None, f"check failed: {exc}")
        except Exception as exc:  # a bug must still answer the call
            self.get_logger().error(f"check crashed: {exc!r}")
            outcome = CheckOutcome(None, f"check crashed: {exc!r}")
        finally:
            with self._state_lock:
                self._job = None
        outcome.calibration_dir = self.calibration_dir
        self._last_check = outcome
        return outcome

    def _watch(self) -> None:
        """Timer: with check_interval_s > 0, check the calibration when frame sets arrived since
        the last check; with recalibrate_on_change, recalibrate when it no longer fits."""
        s = self.settings
        if (s.check_interval_s <= 0 or self.calibration is None
                or time.monotonic() - self._last_watch < s.check_interval_s):
            return
        buffered = self.sync.snapshot()
        first_new = next((i + 1 for i, fs in enumerate(buffered) if fs is self._watched_last), 0)
        if first_new >= len(buffered):
            return  # nothing new: the verdict would be the last one
        # the new frame sets only (matching is the cost), and the one before them: when it fits
        # and they do not, the check says the change came in between
        outcome = self._run_check(buffered[max(first_new - 1, 0):])
        if outcome is None:
            return  # busy: try again at the next tick
        self._last_watch, self._watched_last = time.monotonic(), buffered[-1]
        self._set_status(f"watch: {outcome.message}",
                         "warning" if outcome.fits is False else "info")
        if outcome.fits is False and s.recalibrate_on_change:
            if outcome.misfit_sets < WATCH_CONFIRM_SETS:
                self._set_status(f"watch: {outcome.misfit_sets} frame set does not fit; "
                                 "recalibrating when the next one confirms it")
            elif self.start_calibration("watch: the calibration no longer fits") is not None:
                self._set_status("watch: recalibrating, the calibration no longer fits")

    def _on_sync(self, request, response):
        """~/sync: measure the cameras' stamp offsets from the motion in their latest
        sync_window_s seconds (core.io.motion_sync) and set stamp_offsets_s to them; on failure
        the offsets stay as they were."""
        s = self.settings
        try:
            estimates = self.sync.measure_offsets(s.camera_names)
        except InputError as exc:
            response.success, response.message = False, f"sync failed: {exc}"
        except Exception as exc:  # a bug must still answer the call (and not end the spin)
            self.get_logger().error(f"sync crashed: {exc!r}")
            response.success, response.message = False, f"sync crashed: {exc!r}"
        else:
            offsets = [estimates[n].offset_s for n in s.camera_names]
            dropped = len(self.sync)
            result = self.set_parameters([Parameter("stamp_offsets_s", value=offsets)])[0]
            response.success = result.successful
            response.message = ("stamp offsets [s]: " + ", ".join(
                f"{n} {e.offset_s:+.4f}" + (f" (correlation {e.correlation:.2f})" if i else "")
                for i, (n, e) in enumerate((n, estimates[n]) for n in s.camera_names))
                + (f"; stamp_offsets_s set, {dropped} buffered frame sets dropped (paired by the "
                   "old offsets)" if result.successful else f"; not set: {result.reason}"))
        self._set_status(f"sync: {response.message}", "info" if response.success else "error")
        return response

    def _on_clear(self, request, response):
        """~/clear: drop the buffered frame sets, so that the next ~/calibrate or ~/check uses
        only images received from now on (after the rig was moved or a lens refocused). A
        running calibration keeps the frame sets it took."""
        dropped = self.sync.clear()
        response.success = True
        response.message = (f"dropped {dropped} buffered frame sets; "
                            f"{self.settings.min_frame_sets} needed to calibrate")
        self._set_status(f"clear: {response.message}")
        return response

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

    def _calibrate(self, start: float) -> Outcome:
        # heavy (pycolmap, matchers): import on use
        from ..core.job import CalibrationRequest, run_job
        from ..core.io.reference_view_files import read_reference_views

        s = self.settings
        sets = self.sync.snapshot()
        if len(sets) < s.min_frame_sets:
            raise InputError(f"{len(sets)} synchronised frame set(s) buffered, {s.min_frame_sets} "
                             f"needed: {self.sync.why_few_sets(s.camera_names, s.image_topics)}")
        sets = evenly_spaced(sets, s.max_frame_sets)
        self._set_status(f"calibrating {len(sets)} frame sets ({s.preset}, {s.pipeline}, "
                         f"{s.matcher})")
        sets, images = self._decoded(sets, s.min_frame_sets)
        config = pipeline_config(s)
        if s.keep_intrinsics and self.calibration is not None:
            config.known_intrinsics = with_previous_intrinsics(
                config.known_intrinsics, self.calibration, s.camera_names)
        previous_views = (read_reference_views(self.calibration_dir, s.camera_names)
                          if self.calibration is not None and self.calibration_dir is not None
                          else {})
        offsets = ({"stamp_offsets_s": dict(zip(s.camera_names, s.stamp_offsets_s))}
                   if any(s.stamp_offsets_s) else {})
        source = {"source": "topics", "topics": list(s.image_topics),
                  "camera_names": list(s.camera_names), **offsets,
                  "frame_set_stamps_ns": [  # as the headers had them
                      [int(t) + int(round(o * 1e9)) for t, o in zip(fs.stamps_ns,
                                                                    s.stamp_offsets_s)]
                      for fs in sets]}
        request = CalibrationRequest(
            images, list(s.camera_names), config, source,
            previous=self.calibration,  # start from it; a worse result is refused
            previous_views=previous_views,
            known_baseline=((*s.baseline_cameras, s.known_baseline_m)
                            if s.known_baseline_m > 0 else None),
            floor=s.floor or None, floor_hint="set the floor parameter (upright or top) to find it",
            matcher=self._matcher_for(s))
        # on ~/status only: the core logged the event, and core_logs forwards it to /rosout
        job = run_job(request, progress=lambda msg: self._set_status(f"calibrating: {msg}", None))
        rig, reconstruction = job.rig, job.calibration.reconstruction
        before_change = rig.quality.get("frame_sets_before_change", 0)
        if before_change:  # the provenance (core.io.export) names the frame sets calibrated
            rig.quality["input"]["frame_set_stamps_ns"] = \
                source["frame_set_stamps_ns"][before_change:]
        sets = sets[before_change:]
        elapsed = time.perf_counter() - start
        with self._write_lock:
            if self._stopping.is_set():  # the caller was told it was abandoned: keep to that
                raise CalibrationError("the node shut down during the calibration; nothing "
                                       "written")
            self._writing.set()
        try:
            out = self._write_files(rig, reconstruction, job.reference_views)
            self._publish(rig, out)
        finally:
            self._writing.clear()
        removed = prune_calibrations(s.output_dir, s.keep_calibrations, [out])
        set_info = (self.publisher.call_set_camera_info(rig) if s.call_set_camera_info
                    else None)
        message = _calibrated_message(s, rig, len(sets), elapsed, out, removed,
                                      self.publisher.stereo_problem, set_info)
        return Outcome(True, message)

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
    def _write_files(self, rig: RigCalibration, reconstruction=None,
                     reference_views: Optional[dict] = None) -> Path:
        """Write output_dir/<UTC time>/ atomically, then swap the `latest` symlink onto it. The
        stereo_pairs' camera YAML files carry their pair's rectification, as the CameraInfo
        the node publishes and sends to set_camera_info do."""
        rectified, _ = self.publisher.rectifications(rig)

        def write(folder: Path) -> None:
            write_calibration_files(rig, folder, reconstruction, reference_views=reference_views)
            for name, (rect_from_cam, projection) in rectified.items():
                write_text_atomic(folder / f"{name}.yaml", camera_info_yaml(
                    name, rig.cameras[name].intrinsics, rect_from_cam, projection))
        return write_new_calibration(self.settings.output_dir, write)

    def _load_last_calibration(self, fall_back: bool = False) -> tuple[bool, str]:
        """Publish the calibration under output_dir/latest; (published?, what happened). Anything
        wrong with it leaves the current calibration published. fall_back (start-up): where
        `latest` is missing its target or does not read, the newest kept calibration that reads
        cleanly is published instead, with a warning."""
        latest = self.settings.output_dir / LATEST
        if not latest.exists() and not latest.is_symlink():
            return False, f"no calibration under {latest}"
        try:
            rig = read_calibration(latest) if latest.exists() else None
            problem = None if rig is not None else f"{latest} points at nothing"
        except InputError as exc:
            rig, problem = None, str(exc)
        if rig is None:
            older = self._newest_readable_calibration() if fall_back else None
            if older is None:
                return False, f"not loaded: {problem}"
            self.get_logger().warning(
                f"start-up: {problem}; the newest kept calibration that reads cleanly, "
                f"{older[0]}, is published instead (calibrate again, or point {latest} at "
                "the one to use and call ~/reload)")
            latest, rig = older
        unknown = [c for c in rig.cameras if c not in self.settings.camera_names]
        if unknown:
            return False, (f"not loaded: the calibration in {latest.resolve()} has cameras "
                           f"{unknown}, which are not among camera_names "
                           f"{self.settings.camera_names}")
        self._publish(rig, latest.resolve(), (latest / "calibration.json").stat().st_mtime)
        rms = rig.quality.get("reprojection_rms_px", float("nan"))
        extras = [x for x, on in (("metric", rig.metric_scale),
                                  ("with its floor", bool(rig.quality.get("floor")) and
                                   floor_parent(self.settings) is not None)) if on]
        return True, (f"published {latest.resolve()}: {len(rig.cameras)} cameras "
                      f"({', '.join(rig.cameras)}), reprojection RMS {rms:.2f} px"
                      + (f", {' and '.join(extras)}" if extras else ""))

    def _newest_readable_calibration(self) -> Optional[tuple[Path, RigCalibration]]:
        """(folder, calibration) of the newest calibration under output_dir that reads cleanly
        and has only known cameras, or None."""
        for folder in reversed(stored_calibrations(self.settings.output_dir)):
            try:
                rig = read_calibration(folder)
            except InputError:
                continue
            if all(c in self.settings.camera_names for c in rig.cameras):
                return folder, rig
        return None

    def _on_reload(self, request, response):
        """~/reload: publish the calibration under output_dir/latest again, after it was changed
        on disk (`densecalib scale` or `floor` on output_dir) or pointed at another one (a
        calibration made offline). Holds the job slot: a calibration ending meanwhile would
        publish over it."""
        with self._state_lock:
            busy = self._job is not None
            if not busy:
                self._job = _Job(RELOAD_JOB)
        if busy:
            response.success = False
            response.message = ("busy: a calibration or check is running; call ~/reload when "
                                "it has ended")
            return response
        try:
            response.success, response.message = self._load_last_calibration()
        except Exception as exc:  # a bug or an OS error must still answer the call
            self.get_logger().error(f"reload crashed: {exc!r}")
            response.success, response.message = False, f"reload crashed: {exc!r}"
        finally:
            with self._state_lock:
                self._job = None
        if not response.success and self.calibration_dir is not None:
            response.message += f"; still publishing the calibration of {self.calibration_dir}"
        self._set_status(f"reload: {response.message}", "info" if response.success else "error")
        return response

    def _publish(self, rig: RigCalibration, directory: Path,
                 calibrated_at: Optional[float] = None) -> None:
        """Publish CameraInfo per calibrated camera and all extrinsics in one /tf_static message;
        calibrated_at: when the calibration was made (time.time(); default now), for its age."""
        self.publisher.publish(rig, directory)
        self.calibration, self.calibration_dir = rig, directory
        self._calibrated_at = time.time() if calibrated_at is None else calibrated_at
        self._publish_diagnostics()

    # ----------------------------------------------------------------- status
    def _set_status(self, text: str, level: Optional[str] = "info") -> None:
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
        with self._state_lock:
            return self._job is not None

    def _publish_diagnostics(self) -> None:
        with self._state_lock:
            job = self._job
        state = ("idle" if job is None else
                 {CHECK_JOB: "checking", RELOAD_JOB: "reloading"}.get(job.reason, "calibrating"))
        status, losing = rig_diagnostic_status(
            f"{self.get_name()}: rig calibration", self.settings, self.sync.stats(),
            self.sync.last_malformed, state, self._status, self.calibration,
            self.calibration_dir, self._calibrated_at, self._last_failure, self._last_check)
        if losing:
            self.get_logger().warning(
                f"{', '.join(losing)} of the recent frames missing (gaps in the header stamps): "
                + LOSS_HINT, throttle_duration_sec=60.0)
        msg = DiagnosticArray(status=[status])
        msg.header.stamp = self.get_clock().now().to_msg()
        self._diag_pub.publish(msg)

    def stop(self) -> None:
        """Shutdown begins: a caller waiting for a calibration is answered that it was abandoned,
        and the calibration writes and publishes nothing (one writing its files already ends
        that, and its caller is told so)."""
        with self._write_lock:
            self._stopping.set()

    @property
    def worker_running(self) -> bool:
        return self._worker is not None and self._worker.is_alive()

    def destroy_node(self):
        self.stop()
        stop_forwarding(self._core_logs)
        if self._replayer is not None:
            self._replayer.stop()
        if self._intake is not None:
            self._intake.destroy()
        return super().destroy_node()


def _calibrated_message(s: Settings, rig: RigCalibration, num_sets: int, elapsed: float,
                        out: Path, removed: list, stereo_problem: Optional[str],
                        set_camera_info: Optional[str]) -> str:
    """The ~/calibrate reply for a calibration written to `out`: what was calibrated, from
    what, how well, its warnings and what became of the stored and the drivers' calibrations."""
    rms = rig.quality.get("reprojection_rms_px", float("nan"))
    failed = f", failed: {', '.join(rig.failed_cameras)}" if rig.failed_cameras else ""
    scale = (f", metric scale from {'-'.join(s.baseline_cameras)} = {s.known_baseline_m} m"
             if rig.metric_scale else "")
    message = (f"calibrated {len(rig.cameras)}/{len(s.camera_names)} cameras "
               f"({', '.join(rig.cameras)}{failed}) from {num_sets} frame sets, reprojection "
               f"RMS {rms:.2f} px, {elapsed:.1f} s{scale}; files in {out}")
    if "change_summary" in rig.quality:
        message += f"; {rig.quality['change_summary']} (started {rig.quality['init']})"
    if rig.quality.get("frame_sets_before_change"):
        message += (f"; the {rig.quality['frame_sets_before_change']} older frame sets "
                    "still fitted the previous calibration and were left out: the rig "
                    "changed after them")
    if rig.quality.get("info_strips"):  # found in the images (detect_info_strips)
        message += f"; {info_strips_line(rig.quality)}"
    for warning in rig.quality.get("warnings", []):
        message += f"; warning: {warning}"
    if stereo_problem:
        message += f"; warning: {stereo_problem}"
    if set_camera_info is not None:
        message += "; set_camera_info: " + set_camera_info
    if removed:
        message += (f"; removed the {len(removed)} oldest calibration(s) "
                    f"(keep_calibrations {s.keep_calibrations})")
    return message


def _check_output_dir(output_dir: Path) -> None:
    """InputError at start-up when the calibrations could not be written (found only after the
    first calibration's minutes otherwise)."""
    try:
        output_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"output_dir {output_dir} cannot be created: {exc.strerror or exc}; "
                         "give a folder the node may write.") from None
    if not os.access(output_dir, os.W_OK | os.X_OK):
        raise InputError(f"output_dir {output_dir} is not writable by this user; give a folder "
                         "the node may write.")


def main(args=None) -> int:
    # Importing pycolmap installs glog's failure signal handlers, SIGTERM's among them: a stack
    # dump and exit 143 instead of a clean shutdown (systemd, docker stop, ros2 launch send
    # SIGTERM). So import it first and give SIGTERM back to rclpy, which chains to what it finds.
    # Ceres's recovered solver failures are no operator's concern: errors only.
    show_colmap_log(verbose=False)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    transport = configure_intake_transport()  # before the participant exists
    rclpy.init(args=args)
    node, executor, rc = None, None, 0
    try:
        node = DenseCalibNode()
        if transport is not None:
            said, capped = transport
            (node.get_logger().warning if capped else node.get_logger().info)(said)
        executor = MultiThreadedExecutor(num_threads=4)
        executor.add_node(node)
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except InputError as exc:
        rclpy.logging.get_logger("densecalib_node").fatal(f"invalid parameters: {exc}")
        rc = 1
    except (InvalidParameterTypeException, InvalidParameterValueException) as exc:
        # rclpy's own checks of the declared types and ranges, before parse_settings
        rclpy.logging.get_logger("densecalib_node").fatal(
            f"invalid parameters: {exc} (a double takes a decimal point, slop_s:=1.0; a list "
            "takes brackets, image_topics:=\"['/cam0/image_raw', '/cam1/image_raw']\"; the "
            "ranges are in docs/ros.md's parameter table)")
        rc = 1
    except Exception:
        if rclpy.ok():
            raise
        # a signal shut the context down while the node was starting: as after spin
    finally:
        if node is not None:
            node.stop()  # a waiting ~/calibrate caller is answered, the worker writes nothing
            node.answer_waiting_callers(timeout_s=2.0)
            time.sleep(0.1)  # the executor thread sends the returned answer
            if executor is not None:
                executor.shutdown(timeout_sec=0)
            node.destroy_node()
        rclpy.try_shutdown()
    if node is not None and node.worker_running:
        # The abandoned calibration is inside OpenCV or COLMAP: at interpreter exit Python ends
        # such a daemon thread by unwinding it through their C++ frames, which aborts (SIGABRT,
        # exit 134, a stack dump). Nothing of it is kept, so end the process here instead.
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(rc)
    return rc
