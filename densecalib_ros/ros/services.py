"""The node's std_srvs/Trigger services, for scripts: ~/calibrate, ~/cancel, ~/check, ~/sync,
~/reload and ~/clear (docs/ros.md). Each turns what the node did, or the typed error it met,
into a Trigger response and a ~/status line; the work itself is the node's."""
from __future__ import annotations

import time

from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.parameter import Parameter
from std_srvs.srv import Trigger

from ..core.errors import InputError
from .job_slot import RELOAD_JOB
from .sync import offsets_line

# How long ~/cancel waits for the calibration to stop before it answers.
CANCEL_WAIT_S = 2.0


class TriggerServices:
    """The Trigger services of `node` (a DenseCalibNode), in a reentrant group of their own: a
    ~/calibrate caller waits for the calibration while ~/cancel stops it."""

    def __init__(self, node):
        self._node = node
        group = ReentrantCallbackGroup()
        for name, callback in (("~/calibrate", self._on_calibrate), ("~/cancel", self._on_cancel),
                               ("~/check", self._on_check), ("~/sync", self._on_sync),
                               ("~/reload", self._on_reload), ("~/clear", self._on_clear)):
            node.create_service(Trigger, name, callback, callback_group=group)

    def _on_calibrate(self, request, response):
        """~/calibrate: a calibration with the node's parameters, answered when it ends."""
        node = self._node
        job = node.start_calibration("service call")
        if job is None:
            response.success = False
            response.message = (f"busy: {node.busy_line()}; call again when it ends (or stop a "
                                "calibration with ~/cancel)")
            return response
        outcome = node.jobs.wait_for(job)
        response.success, response.message = outcome.success, outcome.message
        return response

    def _on_cancel(self, request, response):
        """~/cancel: stop the running calibration (the ~/calibrate service's or the action's);
        it writes nothing and the published calibration stays current. Answers once it stopped
        or after CANCEL_WAIT_S."""
        node = self._node
        job = node.jobs.running
        why_not = node.jobs.cancel("cancelled by ~/cancel")
        if why_not is not None:
            response.success, response.message = False, f"nothing cancelled: {why_not}"
            node.set_status(f"cancel: {response.message}")
            return response
        start = time.monotonic()
        stopped = job.done.wait(CANCEL_WAIT_S)
        kept = (f"; still publishing the calibration of {node.calibration_dir.name}"
                if node.calibration_dir is not None else "")
        response.success = True
        response.message = (
            f"the calibration ({job.reason}) stopped after {time.monotonic() - start:.1f} s, "
            f"nothing written{kept}" if stopped and job.outcome and job.outcome.cancelled else
            f"the calibration ({job.reason}) ended before the cancel took effect: "
            f"{job.outcome.message}" if stopped else
            f"the calibration ({job.reason}) was told to stop; it stops at its next check and "
            f"writes nothing{kept}")
        node.set_status(f"cancel: {response.message}")
        return response

    def _on_check(self, request, response):
        """~/check: the buffer against the current calibration, in this service thread (matching
        only: seconds)."""
        outcome = self._node.run_check()
        response.success = bool(outcome and outcome.fits)
        response.message = (outcome.message if outcome else
                            "busy: a calibration or check is running")
        self._node.set_status(f"check: {response.message}",
                              "info" if response.success or outcome is None else "warning")
        return response

    def _on_sync(self, request, response):
        """~/sync: measure the cameras' stamp offsets from the motion in their latest
        sync_window_s seconds (core.io.motion_sync) and set stamp_offsets_s to them; on failure
        the offsets stay as they were."""
        node = self._node
        s = node.settings
        changed = False
        try:
            estimates = node.sync.measure_offsets(s.camera_names)
        except InputError as exc:
            response.success, response.message = False, f"sync failed: {exc}"
        except Exception as exc:  # a bug must still answer the call (and not end the spin)
            node.get_logger().error(f"sync crashed: {exc!r}")
            response.success, response.message = False, f"sync crashed: {exc!r}"
        else:
            offsets = [estimates[n].offset_s for n in s.camera_names]
            changed, dropped = offsets != list(s.stamp_offsets_s), len(node.sync)
            result = node.set_parameters([Parameter("stamp_offsets_s", value=offsets)])[0]
            response.success = result.successful
            response.message = offsets_line(
                s.camera_names, offsets, [None] + [estimates[n].correlation
                                                   for n in s.camera_names[1:]]) + (
                f"; not set: {result.reason}" if not result.successful else
                f"; stamp_offsets_s set, {dropped} buffered frame sets dropped (paired by the "
                "old offsets)" if changed else "; the offsets already set")
        # new offsets were logged as the parameter changed: then ~/status only
        node.set_status(f"sync: {response.message}",
                        "error" if not response.success else None if changed else "info")
        return response

    def _on_reload(self, request, response):
        """~/reload: publish the calibration under output_dir/latest again, after it was changed
        on disk (`densecalib scale` or `floor` on output_dir) or pointed at another one (a
        calibration made offline). Holds the job slot: a calibration ending meanwhile would
        publish over it."""
        node = self._node
        with node.jobs.held(RELOAD_JOB) as held:
            if not held:
                response.success = False
                response.message = ("busy: a calibration or check is running; call ~/reload "
                                    "when it has ended")
                return response
            try:
                response.success, response.message = node.load_last_calibration()
            except Exception as exc:  # a bug or an OS error must still answer the call
                node.get_logger().error(f"reload crashed: {exc!r}")
                response.success, response.message = False, f"reload crashed: {exc!r}"
        if not response.success and node.calibration_dir is not None:
            response.message += f"; still publishing the calibration of {node.calibration_dir}"
        node.set_status(f"reload: {response.message}", "info" if response.success else "error")
        return response

    def _on_clear(self, request, response):
        """~/clear: drop the buffered frame sets, so that the next ~/calibrate or ~/check uses
        only images received from now on (after the rig was moved or a lens refocused). A
        running calibration keeps the frame sets it took."""
        node = self._node
        dropped = node.sync.clear()
        response.success = True
        response.message = (f"dropped {dropped} buffered frame sets; "
                            f"{node.settings.min_frame_sets} needed to calibrate")
        node.set_status(f"clear: {response.message}")
        return response
