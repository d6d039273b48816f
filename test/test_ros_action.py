"""The node's ~/calibrate action driven by a real rclpy ActionClient on loopback (own
ROS_DOMAIN_ID, localhost discovery), with frame sets from real camera driver nodes: feedback at
least once a second with the seconds left, the result's cameras against the generated rig's
truth, one goal at a time, a cancel mid-run that ends the goal CANCELED within 2 s and leaves the
previous calibration published and current, ~/cancel for the Trigger's calibrations, and the
latched ~/status that a late subscriber still receives."""
import time

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy", reason="node tests need rclpy (ROS 2 Jazzy)")
pytest.importorskip("tf2_msgs.msg", reason="tf2_msgs missing: run scripts/setup_env.sh")
pytest.importorskip("densecalib_interfaces.action",
                    reason="densecalib_interfaces missing: run scripts/setup_env.sh")

from action_msgs.msg import GoalStatus  # noqa: E402
from densecalib_interfaces.action import Calibrate  # noqa: E402

from densecalib_ros.core.io.export import read_calibration  # noqa: E402
from densecalib_ros.core.synthetic import RigSpec, generate_rig  # noqa: E402
from densecalib_ros.ros.rig_nodes import wait_until  # noqa: E402
from ros_fixtures import (CALIBRATION_TIMEOUT_S, CAMERAS, Ros,  # noqa: E402
                          camera_info_values, publish_frame_sets, stored_rig_with_floor)

pytestmark = [pytest.mark.ros, pytest.mark.slow]

# What the issue asks of the action: feedback at least this often, a cancel ended within this.
FEEDBACK_EVERY_S = 1.0
CANCEL_WITHIN_S = 2.0
# A calibration of the test rig from scratch takes well over this (tens of seconds on 2 cores):
# cancelled this long after it started, it is mid-run.
MID_RUN_S = 3.0


@pytest.fixture(scope="module")
def ros():
    r = Ros()
    yield r
    r.close()


@pytest.fixture(scope="module")
def rig():
    return generate_rig(RigSpec(lenses="ideal", num_cameras=4, camera_model="RADIAL", width=320,
                                height=240, num_time_steps=2, seed=1))


def feedback_gaps(client, start: float, end: float) -> list[float]:
    """Seconds between the goal's acceptance, each feedback's arrival and the goal's end."""
    times = [start] + [t for t, _ in client.feedback() if start <= t <= end] + [end]
    return list(np.diff(times))


def wait_mid_run(client, node) -> None:
    """Until the feedback says the calibration has run MID_RUN_S; it must still be running."""
    assert wait_until(lambda: any(f.elapsed_s >= MID_RUN_S for _, f in client.feedback()),
                      MID_RUN_S + 10.0), client.feedback()[-1:]
    assert node.busy, "the calibration ended before it could be cancelled mid-run"


def stored_state(listener, folder):
    """What a subscriber and the disk say is current: CameraInfo, /tf_static, `latest`."""
    assert wait_until(lambda: len(listener.snapshot()["camera_info"]) == len(CAMERAS)
                      and listener.rig_from_optical(), 10.0)
    return (camera_info_values(listener),
            {k: np.round(v, 9).tolist() for k, v in listener.rig_from_optical().items()},
            (folder / "latest").resolve(), sorted(p.name for p in folder.iterdir()))


def test_a_goal_reports_feedback_and_its_cameras_and_one_runs_at_a_time(ros, rig, tmp_path):
    node = ros.densecalib(tmp_path / "calib")
    client, other, caller = ros.goal_client(), ros.goal_client(), ros.caller()
    listener = ros.listener(node)
    try:
        publish_frame_sets(ros, node, rig.images)
        goal = Calibrate.Goal(consensus_runs=2, max_frame_sets=2)
        handle = client.send(goal)
        start = time.monotonic()
        assert handle.accepted
        assert wait_until(lambda: node.busy, 5.0)
        # one goal at a time: a second goal is rejected (why: on ~/status), the Trigger says busy
        assert not other.send(Calibrate.Goal()).accepted
        assert wait_until(lambda: "calibrate goal rejected: a calibration is already running "
                          "(action goal)" in listener.snapshot()["status"], 5.0)
        busy = caller.call(10.0)
        assert not busy.success and busy.message.startswith(
            "busy: a calibration is already running (action goal)"), busy.message
        status, result = client.result(handle, CALIBRATION_TIMEOUT_S)
        end = time.monotonic()
        assert status == GoalStatus.STATUS_SUCCEEDED, result.message
        assert result.success and result.message.startswith("calibrated 4/4 cameras"), \
            result.message
        # feedback at least once a second, with the seconds left of the whole run
        gaps = feedback_gaps(client, start, end)
        assert max(gaps) <= FEEDBACK_EVERY_S, (max(gaps), len(gaps))
        feedback = [f for _, f in client.feedback()]
        assert all(b.elapsed_s >= a.elapsed_s for a, b in zip(feedback, feedback[1:]))
        assert all(0.0 <= f.fraction_done <= 1.0 for f in feedback)
        known = [f for f in feedback if f.seconds_left >= 0.0]
        assert known, [(f.stage, f.label, f.fraction_done, f.seconds_left) for f in feedback]
        assert {f.stage for f in feedback} - {"start"}, {f.stage for f in feedback}
        assert max(f.fraction_done for f in feedback) > 0.5
        # the result: the folder `latest` points at, every camera against the truth
        assert result.output_dir == str((tmp_path / "calib" / "latest").resolve())
        assert result.frame_sets == 2 and result.elapsed_s > 0
        stored = read_calibration(tmp_path / "calib" / "latest")
        assert result.reprojection_rms_px == pytest.approx(stored.quality.fit_rms_px(), abs=1e-6)
        truth = rig.ground_truth()
        assert [c.name for c in result.cameras] == list(CAMERAS)
        for camera in result.cameras:
            f_true = truth.cameras[camera.name].intrinsics.params[0]
            assert camera.registered, camera
            assert camera.model == stored.cameras[camera.name].intrinsics.model  # OPENCV: fx, fy
            assert camera.frame_id == f"{camera.name}_optical_frame"
            assert (camera.width, camera.height) == (320, 240)
            assert abs(camera.focal_px - f_true) / f_true < 0.05, (camera.name, camera.focal_px)
            assert camera.focal_px == pytest.approx(
                stored.cameras[camera.name].intrinsics.params[0])
            assert 0 < camera.reprojection_rms_px < 2.0 and camera.num_observations > 50
        # ~/status is latched: a subscriber arriving now gets the outcome
        late = ros.listener(node)
        assert wait_until(lambda: late.snapshot()["status"], 5.0), "no latched status"
        assert late.snapshot()["status"][0].startswith("done: calibrated 4/4 cameras")
        ros.remove(late)
    finally:
        for n in (client, other, caller, listener, node):
            ros.remove(n)


def test_a_cancel_mid_run_ends_the_goal_within_2_s_and_keeps_the_previous_calibration(
        ros, rig, tmp_path):
    stored_rig_with_floor(tmp_path)
    node = ros.densecalib(tmp_path)
    listener, client = ros.listener(node), ros.goal_client()
    try:
        before = stored_state(listener, tmp_path)
        publish_frame_sets(ros, node, rig.images)
        handle = client.send(Calibrate.Goal(from_scratch=True))
        assert handle.accepted
        wait_mid_run(client, node)
        asked = time.monotonic()
        cancel = handle.cancel_goal_async()
        assert wait_until(cancel.done, CANCEL_WITHIN_S)
        assert [bytes(g.goal_id.uuid) for g in cancel.result().goals_canceling] == \
            [bytes(handle.goal_id.uuid)]
        status, result = client.result(handle, CALIBRATION_TIMEOUT_S)
        took = time.monotonic() - asked
        assert status == GoalStatus.STATUS_CANCELED, (status, result.message)
        assert took <= CANCEL_WITHIN_S, f"the goal ended {took:.2f} s after the cancel"
        assert not result.success and result.output_dir == "" and not result.cameras
        assert "cancelled" in result.message and "nothing written" in result.message
        assert result.message.endswith("still publishing the calibration of 20260101T000000Z")
        # the previous calibration: still current on disk, still what a late subscriber gets
        assert not node.busy
        late = ros.listener(node)
        assert stored_state(late, tmp_path) == before
        assert node.calibration_dir.resolve() == before[2]
        assert wait_until(lambda: any(s.startswith("cancelled: cancelled after")
                                      for s in late.snapshot()["status"]), 5.0)
        ros.remove(late)
        # the slot is free again: the next goal is taken
        again = client.send(Calibrate.Goal(from_scratch=True))
        assert again.accepted
        again.cancel_goal_async()
        assert client.result(again, CALIBRATION_TIMEOUT_S)[0] == GoalStatus.STATUS_CANCELED
    finally:
        for n in (client, listener, node):
            ros.remove(n)


def test_cancel_service_stops_the_trigger_calibration_and_a_goal(ros, rig, tmp_path):
    stored_rig_with_floor(tmp_path)
    node = ros.densecalib(tmp_path)
    listener, client = ros.listener(node), ros.goal_client()
    calibrate, cancel = ros.caller("calibrate"), ros.caller("cancel")
    try:
        before = stored_state(listener, tmp_path)
        idle = cancel.call(10.0)
        assert not idle.success and idle.message == \
            "nothing cancelled: no calibration is running"
        publish_frame_sets(ros, node, rig.images)
        # the Trigger's calibration
        answer = calibrate.call_async()
        # from the published calibration it takes only seconds on a fast machine: cancelled as
        # soon as its first frame set is matched, it is mid-run wherever it runs
        assert wait_until(lambda: any(s.startswith("calibrating: matched frame set 1/")
                                      for s in listener.snapshot()["status"]), 30.0)
        assert node.busy, "the calibration ended before it could be cancelled mid-run"
        asked = time.monotonic()
        stopped = cancel.call(10.0)
        assert wait_until(answer.done, CALIBRATION_TIMEOUT_S)
        took = time.monotonic() - asked
        assert took <= CANCEL_WITHIN_S, f"the calibration answered {took:.2f} s after ~/cancel"
        assert stopped.success and "stopped after" in stopped.message, stopped.message
        assert "nothing written" in stopped.message
        assert not answer.result().success
        assert answer.result().message.startswith("cancelled after")
        assert "(cancelled by ~/cancel): nothing written" in answer.result().message
        # a goal stopped by ~/cancel (no cancel of the goal itself) ends ABORTED, saying why
        handle = client.send(Calibrate.Goal(from_scratch=True))
        assert handle.accepted
        wait_mid_run(client, node)
        asked = time.monotonic()
        assert cancel.call(10.0).success
        status, result = client.result(handle, CALIBRATION_TIMEOUT_S)
        took = time.monotonic() - asked
        assert status == GoalStatus.STATUS_ABORTED and "cancelled by ~/cancel" in result.message
        assert took <= CANCEL_WITHIN_S, f"the goal ended {took:.2f} s after ~/cancel"
        late = ros.listener(node)
        assert stored_state(late, tmp_path) == before
        ros.remove(late)
    finally:
        for n in (calibrate, cancel, client, listener, node):
            ros.remove(n)


def test_goal_options_are_checked_as_the_parameters_are(ros, tmp_path):
    node = ros.densecalib(tmp_path / "calib")
    client = ros.goal_client()
    try:
        for goal, said in (
                (Calibrate.Goal(preset="wide"), "preset must be one of regular, fisheye"),
                (Calibrate.Goal(pipeline="magic"), "pipeline must be one of"),
                (Calibrate.Goal(matcher="nope"), "matcher must be one of"),
                (Calibrate.Goal(consensus_runs=50), "consensus_runs must be 0 (the node's "
                                                    "parameter) or 1..20, got 50")):
            handle = client.send(goal)
            assert handle.accepted
            status, result = client.result(handle, 30.0)
            assert status == GoalStatus.STATUS_ABORTED
            assert result.message.startswith("invalid goal: ") and said in result.message, \
                result.message
        # valid options with nothing buffered: the reason, as ~/calibrate gives it
        handle = client.send(Calibrate.Goal(preset="fisheye", matcher="sift"))
        status, result = client.result(handle, 30.0)
        assert status == GoalStatus.STATUS_ABORTED and not result.success
        assert "0 synchronised frame set(s) buffered, 2 needed" in result.message
        assert not (tmp_path / "calib" / "latest").exists()
    finally:
        ros.remove(client)
        ros.remove(node)
