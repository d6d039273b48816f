"""The calibration node with real rclpy on loopback (own ROS_DOMAIN_ID, localhost discovery):
camera publisher nodes -> densecalib_node -> ~/calibrate from an rclpy client -> a listener gets
CameraInfo and /tf_static matching the generated rig's ground truth; busy refusal; restart
republishes the last good calibration; a failing calibration leaves every output untouched; bags
written with `rosbags` (sqlite3 raw, mcap compressed) replay into the node to the same result;
parameters are validated."""
import os
from pathlib import Path
import re
import threading
import time

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

rclpy = pytest.importorskip("rclpy", reason="node tests need rclpy (ROS 2 Jazzy)")
import rclpy.node  # noqa: E402
pytest.importorskip("tf2_msgs.msg", reason="tf2_msgs missing: run scripts/setup_env.sh")

from diagnostic_msgs.msg import DiagnosticStatus  # noqa: E402
from rcl_interfaces.msg import Log  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from sensor_msgs.srv import SetCameraInfo  # noqa: E402

from densecalib_ros.core.io.bag import read_frame_sets, write_image_bag  # noqa: E402
from densecalib_ros.core.config import DEFAULT_PIPELINE, make_config  # noqa: E402
from densecalib_ros.core.errors import InputError  # noqa: E402
from densecalib_ros.core.io.camera_info import camera_info_yaml
from densecalib_ros.core.io.export import read_calibration, read_saved_model
from densecalib_ros.core.products.floor import reconstruction_points_in_rig  # noqa: E402
from densecalib_ros.core.metrics import relative_pose_errors  # noqa: E402
from densecalib_ros.core import calibrate_rig  # noqa: E402
from densecalib_ros.core.products.scale import camera_distance  # noqa: E402
from densecalib_ros.core.synthetic import RigSpec, generate_rig  # noqa: E402
from densecalib_ros.core.types import CameraIntrinsics  # noqa: E402
from densecalib_ros.ros.conversions import (numpy_to_compressed_msg,  # noqa: E402
                                            point_cloud_to_numpy)
from densecalib_ros.ros.rig_nodes import CameraPublisherNode, wait_until  # noqa: E402
from densecalib_ros.ros.settings import pipeline_config  # noqa: E402
from motion_fixtures import arena_views  # noqa: E402
from ros_fixtures import (CALIBRATION_TIMEOUT_S, CAMERAS, DOMAIN_ID, Ros,  # noqa: E402
                          RosoutListener, camera_info_values, diagnostic_state,
                          publish_frame_sets, stored_rig_with_floor)
from sfm_fixtures import turned_image  # noqa: E402

pytestmark = [pytest.mark.ros, pytest.mark.slow]


@pytest.fixture(scope="module")
def ros():
    r = Ros()
    yield r
    r.close()


@pytest.fixture(scope="module")
def rig():
    return generate_rig(RigSpec(lenses="ideal", num_cameras=4, camera_model="RADIAL", width=320, height=240,
                                num_time_steps=2, seed=1))


class SetCameraInfoDriver(rclpy.node.Node):
    """The set_camera_info end of a camera driver: accepts, refuses, or answers too late."""

    def __init__(self, camera, answer, **kwargs):
        super().__init__(f"{camera}_calibration_store", **kwargs)
        self.answer, self.received, self.answered = answer, [], 0
        self.create_service(SetCameraInfo, f"/rig/{camera}/set_camera_info", self._on_set)

    def _on_set(self, request, response):
        self.received.append(request.camera_info)
        if self.answer == "slow":
            time.sleep(2.0)
        response.success = self.answer != "refuse"
        response.status_message = "stored" if response.success else "no thanks"
        self.answered += 1
        return response


def check_against_truth(listener, rig, node):
    """The listener's CameraInfo and /tf_static against the generated rig's ground truth."""
    gt = rig.ground_truth()
    assert wait_until(lambda: len(listener.snapshot()["camera_info"]) == 4 and
                      listener.rig_from_optical(), 10.0)
    infos = listener.snapshot()["camera_info"]
    for name, cam in gt.cameras.items():
        info = infos[name]
        assert info.header.frame_id == f"{name}_optical_frame"
        assert (info.width, info.height, info.distortion_model) == (320, 240, "plumb_bob")
        f_true = cam.intrinsics.params[0]
        assert abs(info.k[0] - f_true) / f_true < 0.05, (name, info.k[0], f_true)
        assert abs(info.k[4] / info.k[0] - 1) < 0.01  # fx, fy: square pixels within 1 %
    rig_from_optical = listener.rig_from_optical()
    assert sorted(rig_from_optical) == [f"{n}_optical_frame" for n in sorted(gt.cameras)]
    est = {n: np.linalg.inv(rig_from_optical[f"{n}_optical_frame"]) for n in gt.cameras}
    assert np.allclose(est[node.calibration.reference_camera], np.eye(4), atol=1e-9)
    errors = relative_pose_errors(est, {n: c.cam_from_rig for n, c in gt.cameras.items()})
    assert len(errors) == 6
    assert max(e.rot_err_deg for e in errors) < 3.0, errors
    assert max(e.trans_dir_err_deg for e in errors) < 6.0, errors


def calibration_values(rig):
    return {n: (np.round(c.intrinsics.params, 9).tolist(), np.round(c.cam_from_rig, 9).tolist())
            for n, c in rig.cameras.items()}


def test_parameters_are_validated(ros, tmp_path):
    with pytest.raises(InputError, match="at least two image topics"):
        ros.densecalib(tmp_path, name="bad1", image_topics=["/only/image_raw"], camera_names=None,
                       transports=None)
    with pytest.raises(InputError, match="preset must be one of regular, fisheye"):
        ros.densecalib(tmp_path, name="bad2", preset="wide")
    with pytest.raises(InputError, match="known_baseline_m > 0 needs baseline_cameras"):
        ros.densecalib(tmp_path, name="bad3", known_baseline_m=0.5)
    with pytest.raises(InputError, match="transports must be one of"):
        ros.densecalib(tmp_path, name="bad4", transports=["theora"])
    with pytest.raises(InputError, match="stamp_offsets_s must be empty or one offset"):
        ros.densecalib(tmp_path, name="bad5", stamp_offsets_s=[0.1])
    node = ros.densecalib(tmp_path, name="params_node")
    try:
        result = node.set_parameters([Parameter("matcher", value="nonexistent")])[0]
        assert not result.successful and "matcher must be one of" in result.reason
        result = node.set_parameters([Parameter("stamp_offsets_s", value=[0.1, 0.2])])[0]
        assert not result.successful and "one offset [s] per camera (4)" in result.reason
        result = node.set_parameters([Parameter("min_frame_sets", value=100)])[0]
        assert not result.successful and "cannot exceed buffer_size" in result.reason
        # list values as `ros2 param set` sends them: "[]" an empty BOOL_ARRAY, "[800, 810, 820,
        # 830]" INTEGER_ARRAY, "[0, 0.35, ...]" (ints and floats) a STRING; all readable back
        names = node.settings.camera_names
        for value, expected in (([800, 810, 820, 830], dict(zip(names, [800.0, 810, 820, 830]))),
                                (Parameter.Type.BOOL_ARRAY, {})):
            param = (Parameter("initial_focal_px", value, []) if value == Parameter.Type.BOOL_ARRAY
                     else Parameter("initial_focal_px", value=value))
            assert node.set_parameters([param])[0].successful
            assert node.settings.initial_focal_px == expected
        assert node.set_parameters([Parameter("stamp_offsets_s",
                                              value="[0, 0.35, -0.8, 0.5]")])[0].successful
        assert node.settings.stamp_offsets_s == [0.0, 0.35, -0.8, 0.5]
        result = node.set_parameters([Parameter("stereo_pairs", value="cam0")])[0]
        assert not result.successful and "stereo_pairs is a list" in result.reason
        assert node.set_parameters([Parameter("stamp_offsets_s", value=[0.0] * 4)])[0].successful
        assert node.get_parameter("camera_lens").value == []  # unset lists are gettable
        result = node.set_parameters([Parameter("image_topics", value=["/a", "/b"])])[0]
        assert not result.successful and "read-only" in result.reason
        result = node.set_parameters([Parameter("known_baseline_m", value=0.12)])[0]
        assert not result.successful and "needs baseline_cameras" in result.reason
        result = node.set_parameters_atomically([Parameter("known_baseline_m", value=0.12),
                                                 Parameter("baseline_cameras",
                                                           value=["cam0", "cam2"])])
        assert result.successful, result.reason
        assert node.settings.known_baseline_m == 0.12
        assert node.settings.baseline_cameras == ["cam0", "cam2"]
        # not the driver's /rig/cam2/camera_info: the node's own
        assert node.settings.camera_info_topics[2] == "~/cam2/camera_info"
        assert node.resolve_topic_name("~/cam2/camera_info") == \
            f"/{node.get_name()}/cam2/camera_info"
        assert node.settings.set_camera_info_services[0] == "/rig/cam0/set_camera_info"
        assert not pipeline_config(node.settings).sfm.share_intrinsics
        assert node.set_parameters([Parameter("share_intrinsics", value=True)])[0].successful
        assert pipeline_config(node.settings).sfm.share_intrinsics
        assert pipeline_config(node.settings).cameras.units_from_images
        assert node.set_parameters([Parameter("separate_intrinsics", value=True)])[0].successful
        assert not pipeline_config(node.settings).cameras.units_from_images
        assert pipeline_config(node.settings).consensus_runs == 5
        assert node.set_parameters([Parameter("consensus_runs", value=1)])[0].successful
        assert pipeline_config(node.settings).consensus_runs == 1
        assert not node.set_parameters([Parameter("consensus_runs", value=0)])[0].successful
        result = node.set_parameters([Parameter("mask_files", value=[str(tmp_path / "no.png")])])[0]
        assert not result.successful and "Cannot read mask" in result.reason
        mask = np.full((240, 320), 255, np.uint8)
        mask[-20:] = 0
        cv2.imwrite(str(tmp_path / "strip.png"), mask)
        masks = ["", str(tmp_path / "strip.png"), "", ""]
        assert node.set_parameters([Parameter("mask_files", value=masks)])[0].successful
        camera_masks = pipeline_config(node.settings).cameras.masks
        assert list(camera_masks) == ["cam1"] and camera_masks["cam1"][-20:].all()
        assert pipeline_config(node.settings).cameras.initial_focal_px == {}
        assert node.set_parameters([Parameter("initial_focal_px", value=[800.0])])[0].successful
        assert pipeline_config(node.settings).cameras.initial_focal_px == {"*": 800.0}
        assert node.set_parameters([Parameter("initial_focal_px",
                                              value=[800.0, 810.0, 820.0, 830.0])])[0].successful
        assert pipeline_config(node.settings).cameras.initial_focal_px == {
            "cam0": 800.0, "cam1": 810.0, "cam2": 820.0, "cam3": 830.0}
        result = node.set_parameters([Parameter("initial_focal_px", value=[800.0, 810.0])])[0]
        assert not result.successful and "one per camera (4)" in result.reason
        assert not node.set_parameters([Parameter("initial_focal_px",
                                                  value=[-1.0])])[0].successful
        assert pipeline_config(node.settings).cameras.lens == {}
        lenses = ["pinhole", "fisheye", "pinhole", "pinhole"]
        assert node.set_parameters([Parameter("camera_lens", value=lenses)])[0].successful
        assert pipeline_config(node.settings).cameras.lens == dict(zip(node.settings.camera_names,
                                                                      lenses))
        for bad in (["fisheye"], ["pinhole", "tele", "pinhole", "pinhole"]):
            result = node.set_parameters([Parameter("camera_lens", value=bad)])[0]
            assert not result.successful and "one lens per camera (4)" in result.reason
        # Given intrinsics: one camera_info YAML per camera ('' = calibrate that one).
        assert pipeline_config(node.settings).cameras.known_intrinsics == {}
        lab = CameraIntrinsics("OPENCV", 320, 240, np.array([300.0, 300.0, 160.0, 120.0, -0.05,
                                                             0.0, 0.0, 0.0]))
        (tmp_path / "lab2.yaml").write_text(camera_info_yaml("lab_name", lab))
        files = ["", "", str(tmp_path / "lab2.yaml"), ""]
        assert node.set_parameters([Parameter("intrinsics_files", value=files)])[0].successful
        known = pipeline_config(node.settings).cameras.known_intrinsics
        assert list(known) == ["cam2"] and known["cam2"].model == "OPENCV"
        result = node.set_parameters([Parameter("intrinsics_files", value=files[:2])])[0]
        assert not result.successful and "intrinsics_files has 2 entries" in result.reason
        result = node.set_parameters([Parameter("intrinsics_files",
                                                value=[str(tmp_path / "lab2.yaml")])])[0]
        assert not result.successful and "lab_name, which are not among" in result.reason
        assert list(pipeline_config(node.settings).cameras.known_intrinsics) == ["cam2"]  # kept
    finally:
        ros.remove(node)


def test_the_config_file_lists_every_parameter_and_starts_the_node(ros, tmp_path):
    """config/densecalib.yaml, what users copy: every parameter is there (optional lists
    commented out), with its default, and the node starts from it."""
    import yaml

    from densecalib_ros.ros.settings import PARAMETERS

    text = (Path(__file__).resolve().parents[1] / "config" / "densecalib.yaml").read_text()
    values = yaml.safe_load(text)["/**"]["ros__parameters"]
    assert set(values) <= set(PARAMETERS)
    assert [n for n in PARAMETERS if not re.search(rf"^\s*#?\s*{n}:", text, re.M)] == []
    for name, value in values.items():
        default = PARAMETERS[name][0]
        if not isinstance(default, Parameter.Type):  # the EXAMPLE lists have no default
            assert value == default, name
    values.pop("output_dir")
    node = ros.densecalib(tmp_path, name="from_config", camera_names=None, transports=None,
                          **values)
    try:
        assert node.settings.camera_names == ["cam0", "cam1", "cam2"]
    finally:
        ros.remove(node)


def test_calibrate_busy_restart_and_failure(ros, rig, tmp_path):
    out = tmp_path / "calib"
    node = ros.densecalib(out)
    listener, caller = ros.listener(node), ros.caller()

    # Too few frame sets: refused with the reason, nothing written.
    response = caller.call(30.0)
    assert not response.success and "0 synchronised frame set(s) buffered, 2 needed" in \
        response.message
    assert "no image received from cam0 (/rig/cam0/image_raw), cam1" in response.message
    rosout = ros.add(RosoutListener(ros.context))
    assert not out.exists() or not any(out.iterdir())

    # Drivers offering set_camera_info: cam0 accepts, cam1 refuses, cam2 is too slow, cam3 has none.
    drivers = {name: ros.add(SetCameraInfoDriver(name, answer, context=ros.context))
               for name, answer in (("cam0", "ok"), ("cam1", "refuse"), ("cam2", "slow"))}
    assert all(r.successful for r in node.set_parameters([
        Parameter("call_set_camera_info", value=True),
        Parameter("set_camera_info_timeout_s", value=1.0)]))

    publish_frame_sets(ros, node, rig.images)
    first = caller.call_async()
    assert wait_until(lambda: node.busy, 10.0)
    second = caller.call(10.0)  # while the first one runs
    assert not second.success and second.message.startswith("busy")
    assert wait_until(first.done, CALIBRATION_TIMEOUT_S, 0.1)
    response = first.result()
    assert response.success, response.message
    assert response.message.startswith("calibrated 4/4 cameras (cam0, cam1, cam2, cam3)")
    assert "reprojection RMS" in response.message and "2 frame sets" in response.message
    source = node.calibration.quality.input
    assert source["source"] == "topics" and source["topics"] == [c[0] for c in CAMERAS.values()]
    assert [s[0] for s in source["frame_set_stamps_ns"]] == [1_000_000_000, 2_000_000_000]
    check_against_truth(listener, rig, node)
    # the core's own log lines reach /rosout under the node's name
    assert wait_until(lambda: any(m.name == "densecalib_node.core" and "sampled" in m.msg
                                  for m in rosout.copy()), 5.0)
    # No baseline known: the reply, the log (WARN) and /diagnostics say /tf_static is in rig units
    assert "; warning: no metric scale: /tf_static and the files are in rig units, not metres" \
        in response.message
    assert wait_until(lambda: any(m.level == Log.WARN and "no metric scale" in m.msg
                                  for m in rosout.copy()), 5.0)
    ros.remove(rosout)
    assert response.message.endswith(
        "set_camera_info: cam0 ok, cam1 refused (no thanks), cam2 timeout, "
        "cam3 no service /rig/cam3/set_camera_info")
    received = drivers["cam0"].received
    assert len(received) == 1 and received[0].header.frame_id == "cam0_optical_frame"
    assert list(received[0].k) == list(listener.snapshot()["camera_info"]["cam0"].k)
    for d in drivers.values():  # a node destroyed inside its own callback breaks the executor
        assert wait_until(lambda: d.answered == len(d.received) == 1, 5.0)
        ros.remove(d)

    # Files: a timestamped folder and the `latest` symlink onto it, equal to what was published.
    latest = out / "latest"
    assert latest.is_symlink() and (latest / "calibration.json").is_file()
    assert sorted(p.name for p in latest.iterdir()) == [
        "calibration.json", "cam0.yaml", "cam1.yaml", "cam2.yaml", "cam3.yaml", "colmap",
        "reference_views"]
    assert sorted(p.name for p in (latest / "reference_views").iterdir()) == [
        f"cam{i}.jpg" for i in range(4)]
    assert calibration_values(read_calibration(latest)) == calibration_values(node.calibration)
    # ~/points: the saved model's scene points in the rig frame, in their image colours
    assert wait_until(lambda: listener.snapshot()["points"], 5.0)
    cloud = listener.snapshot()["points"][-1]
    assert cloud.header.frame_id == "rig"
    xyz, rgb = point_cloud_to_numpy(cloud)
    model = read_saved_model(latest)
    assert len(xyz) == model.num_points3D() > 50
    np.testing.assert_allclose(xyz, reconstruction_points_in_rig(model, node.calibration),
                               rtol=1e-5, atol=1e-5)
    assert rgb.std() > 10
    assert wait_until(lambda: any(s.startswith("done: calibrated")
                                  for s in listener.snapshot()["status"]), 5.0)
    assert any(s.startswith("calibrating: matched frame set")
               for s in listener.snapshot()["status"])

    def diag_state():
        return diagnostic_state(listener)

    assert wait_until(lambda: diag_state() and diag_state()[0] == DiagnosticStatus.OK, 5.0)
    level, _, values = diag_state()
    assert float(values["reprojection_rms_px"]) == pytest.approx(
        node.calibration.quality.reprojection_rms_px, abs=1e-3)
    assert float(values["age_s"]) >= 0.0 and values["metric_scale"] == "no (rig units)"
    assert set(values["focal_std_px"].split(", ")) == {
        f"{n}={c.quality.focal_std_px:.1f}" for n, c in node.calibration.cameras.items()}
    assert len(values["projection_std_px"].split(", ")) == len(node.calibration.cameras)
    # ~/check: the buffered images still fit the calibration just made from them.
    checker = ros.caller("check")
    response = checker.call(60.0)
    assert response.success and response.message.startswith("the calibration fits"), \
        response.message
    assert "2 frame sets" in response.message and "transfer error px: cam0" in response.message
    assert "reference views: every judged camera still sees its reference view" in \
        response.message
    # cam2 tilted by 1 deg before two more frame sets: the check judges those two and says when
    truth = rig.ground_truth()
    tilt = Rotation.from_euler("x", 1.0, degrees=True).as_matrix()
    publish_frame_sets(ros, node, [[*fs[:2], turned_image(fs[2], truth.cameras["cam2"].intrinsics,
                                                          tilt), fs[3]] for fs in rig.images],
                       first_stamp_s=3.0)
    response = checker.call(60.0)
    assert not response.success and "no longer fits: cam2 moved or changed" in response.message, \
        response.message
    assert ("frame sets 1-2 fit it, the rig changed after frame set 2 (figures from the 2 since) "
            "(the change came before the frame set stamped 3.000 s); reference views: changed "
            "since the calibration: cam2 turned " in response.message)  # its own view: 1 deg
    assert re.search(r"cam2 turned (0\.9\d|1\.0\d) deg \(\d\.\d px\); 4 frame sets",
                     response.message)
    ros.remove(checker)
    # floor turned on after calibrating without it: found in the saved scene points, recorded in
    # calibration.json and published; turned off again: gone from /tf_static
    assert read_calibration(latest).quality.floor is None
    assert node.set_parameters([Parameter("floor", value="upright")])[0].successful
    assert wait_until(lambda: "rig" in listener.rig_from_optical(), 10.0), \
        listener.snapshot()["status"][-2:]
    assert read_calibration(latest).quality.floor["num_points"] > 30
    assert any(s.startswith("floor: found in") for s in listener.snapshot()["status"])
    assert node.set_parameters([Parameter("floor", value="")])[0].successful
    assert wait_until(lambda: "rig" not in listener.rig_from_optical(), 10.0)
    published = camera_info_values(listener)
    published_tf = listener.rig_from_optical()
    files_before = sorted(p.name for p in out.iterdir())
    ros.remove(listener)
    ros.remove(node)

    # Restart: the last good calibration is republished from the files.
    node = ros.densecalib(out)
    listener = ros.listener(node)
    assert wait_until(lambda: len(listener.snapshot()["camera_info"]) == 4 and
                      listener.rig_from_optical(), 10.0)
    assert camera_info_values(listener) == published
    assert wait_until(lambda: listener.snapshot()["points"], 5.0)  # republished from the files
    assert len(point_cloud_to_numpy(listener.snapshot()["points"][-1])[0]) == len(xyz)
    restarted_tf = listener.rig_from_optical()
    assert all(np.allclose(restarted_tf[k], published_tf[k], atol=1e-9) for k in published_tf)
    checker = ros.caller("check")
    response = checker.call(30.0)  # the loaded calibration, but nothing buffered to check it with
    assert not response.success and "no synchronised frame sets buffered" in response.message
    ros.remove(checker)

    # A failing calibration (images of unrelated noise) changes nothing published or written.
    # It uses one of the two buffered sets (max_frame_sets, evenly spaced over the buffer).
    rng = np.random.default_rng(5)
    noise = [[rng.integers(0, 256, (240, 320, 3), dtype=np.uint8) for _ in CAMERAS]
             for _ in range(2)]
    publish_frame_sets(ros, node, noise, first_stamp_s=100.0)
    assert node.set_parameters([Parameter("max_frame_sets", value=1)])[0].successful
    response = caller.call(CALIBRATION_TIMEOUT_S)
    assert any(s.startswith("calibrating 1 frame sets") for s in listener.snapshot()["status"])
    assert not response.success
    assert response.message.startswith("calibration failed after")
    assert f"still publishing the calibration of {latest.resolve().name}" in response.message
    assert sorted(p.name for p in out.iterdir()) == files_before
    assert calibration_values(read_calibration(latest)) == calibration_values(node.calibration)
    late = ros.listener(node)  # a subscriber arriving now still gets the good calibration
    assert wait_until(lambda: len(late.snapshot()["camera_info"]) == 4, 10.0)
    assert camera_info_values(late) == published
    assert wait_until(lambda: late.snapshot()["points"], 5.0)
    assert len(point_cloud_to_numpy(late.snapshot()["points"][-1])[0]) == len(xyz)
    assert wait_until(lambda: diag_state() and "last calibration failed" in diag_state()[1], 5.0)
    # ~/clear: the buffered sets are gone, the next calibration waits for new ones
    clearer = ros.caller("clear")
    response = clearer.call(10.0)
    assert response.success and response.message.startswith("dropped 2 buffered frame sets")
    assert len(node.sync) == 0 and clearer.call(10.0).message.startswith("dropped 0")
    response = caller.call(30.0)
    assert not response.success and "0 synchronised frame set(s) buffered" in response.message
    assert camera_info_values(late) == published
    for n in (clearer, late, listener, node, caller):
        ros.remove(n)


def test_recalibration_after_a_bump_leaves_out_the_frame_sets_from_before(ros, rig, tmp_path):
    """Calibrated, then cam2 turned by 2 deg and two more frame sets buffered: ~/calibrate leaves
    out the two older sets (they still fit the previous calibration) and says so. With
    keep_calibrations 1 the first calibration's folder is then removed."""
    from scipy.spatial.transform import Rotation

    from densecalib_ros.core.io.calibration_store import stored_calibrations
    from sfm_fixtures import turned_image

    node = ros.densecalib(tmp_path / "calib", keep_calibrations=1)
    caller = ros.caller()
    try:
        publish_frame_sets(ros, node, rig.images)
        assert caller.call(CALIBRATION_TIMEOUT_S).success
        (first,) = stored_calibrations(tmp_path / "calib")
        turn = Rotation.from_euler("z", 2.0, degrees=True).as_matrix()
        lens = rig.ground_truth().cameras["cam2"].intrinsics
        turned = [[turned_image(im, lens, turn) if c == 2 else im for c, im in enumerate(fs)]
                  for fs in rig.images]
        publish_frame_sets(ros, node, turned, first_stamp_s=10.0)
        response = caller.call(CALIBRATION_TIMEOUT_S)
        assert response.success, response.message
        assert "from 2 frame sets" in response.message
        assert "the 2 older frame sets still fitted the previous calibration" in response.message
        assert "removed the 1 oldest calibration(s) (keep_calibrations 1)" in response.message
        assert stored_calibrations(tmp_path / "calib") == [node.calibration_dir] != [first]
        stamps = node.calibration.quality.input["frame_set_stamps_ns"]
        assert [row[0] for row in stamps] == [10_000_000_000, 11_000_000_000]
        change = node.calibration.quality.change_vs_previous
        assert max(change, key=lambda n: change[n]["rotation_change_deg"]) == "cam2"
    finally:
        for n in (caller, node):
            ros.remove(n)


def test_watch_checks_new_frame_sets_and_recalibrates_when_a_camera_moved(ros, rig, tmp_path):
    """check_interval_s > 0: the true calibration is checked against new frame sets on its own
    (fits: /diagnostics OK, last_check said). cam2 turned by 2 deg before one more frame set:
    the next check finds it (WARN naming cam2), and waits for a second frame set to confirm it
    before recalibrating (recalibrate_on_change); with it, a recalibration from the two sets
    since the change puts cam2 where it is now."""
    from densecalib_ros.core.io.export import write_calibration_files

    truth = rig.ground_truth()
    truth.quality.reprojection_rms_px = 0.5
    write_calibration_files(truth, tmp_path / "20260101T000000Z")
    os.symlink("20260101T000000Z", tmp_path / "latest")
    node = ros.densecalib(tmp_path, recalibrate_on_change=True)
    listener = ros.listener(node)

    def watching(on: bool):  # off while frame sets are published: each check sees them whole
        assert node.set_parameters([Parameter("check_interval_s", value=1.0 if on else 0.0)])[0] \
            .successful

    def last_check():
        return (diagnostic_state(listener) or (0, "", {}))[2].get("last_check", "")

    def watched():
        return [m for m in listener.snapshot()["status"] if m.startswith("watch: ")]

    try:
        publish_frame_sets(ros, node, rig.images)
        watching(True)
        assert wait_until(lambda: last_check().startswith("the calibration fits"), 60.0), \
            listener.snapshot()["status"][-3:]
        assert diagnostic_state(listener)[0] == DiagnosticStatus.OK
        watching(False)
        turn = Rotation.from_euler("z", 2.0, degrees=True).as_matrix()
        lens = truth.cameras["cam2"].intrinsics
        turned = [[turned_image(im, lens, turn) if c == 2 else im for c, im in enumerate(fs)]
                  for fs in rig.images]
        before = node.calibration_dir
        publish_frame_sets(ros, node, turned[:1], first_stamp_s=10.0)
        watching(True)
        assert wait_until(lambda: "no longer fits" in last_check(), 60.0), last_check()
        level, message, values = diagnostic_state(listener)
        assert level == DiagnosticStatus.WARN and message.startswith(
            "the calibration no longer fits the latest images: a camera moved"), message
        assert "cam2 moved or changed" in values["last_check"]
        # it matched the new frame set and the one before it
        assert "frame sets 1-1 fit it" in values["last_check"] and "; 2 frame sets" in \
            values["last_check"]
        assert wait_until(lambda: watched()[-1].startswith("watch: 1 frame set does not fit; "
                                                           "recalibrating when the next"), 5.0)
        assert node.calibration_dir == before  # one frame set is not enough

        watching(False)
        publish_frame_sets(ros, node, turned[1:], first_stamp_s=11.0)
        watching(True)
        assert wait_until(lambda: node.calibration_dir != before, CALIBRATION_TIMEOUT_S), \
            listener.snapshot()["status"][-3:]
        assert watched()[-1] == "watch: recalibrating, the calibration no longer fits", watched()
        change = node.calibration.quality.change_vs_previous
        assert max(change, key=lambda n: change[n]["rotation_change_deg"]) == "cam2"
        assert [row[0] for row in node.calibration.quality.input["frame_set_stamps_ns"]] == \
            [10_000_000_000, 11_000_000_000]
        # the new calibration has not been checked (no frame sets since): no last_check
        assert wait_until(lambda: diagnostic_state(listener)[2].get("files") ==
                          str(node.calibration_dir), 5.0)
        _, message, values = diagnostic_state(listener)
        assert "last_check" not in values and "no longer fits" not in message, message
        # stamps that jump back (a bag replayed again) are new frame sets all the same
        watching(False)
        publish_frame_sets(ros, node, turned[1:], first_stamp_s=5.0)
        watching(True)
        assert wait_until(lambda: last_check().startswith("the calibration fits"), 60.0), \
            listener.snapshot()["status"][-3:]
    finally:
        for n in (listener, node):
            ros.remove(n)


def test_stereo_pairs_camera_info_carry_the_pair_rectification(ros, tmp_path):
    """With stereo_pairs set, the last good calibration is republished with each pair's stereo
    rectification in R and P (Tx = -fx' baseline), the other cameras with R = I; a pair in the
    wrong order falls back to R = I with the reason, and changing the parameter republishes."""
    from densecalib_ros.core.io.export import write_calibration_files
    from densecalib_ros.core.products.stereo import rectify_pair
    from densecalib_ros.core.types import RigCalibration, RigCamera

    lens = CameraIntrinsics("RADIAL", 320, 240, np.array([300.0, 160.0, 120.0, -0.05, 0.01]))
    poses = {"cam0": np.eye(4)}
    for name, x, y in (("cam1", 0.1, 0.002), ("cam2", 0.2, 0.0), ("cam3", 0.3, 0.005)):
        poses[name] = np.eye(4)
        poses[name][:3, 3] = [-x, y, 0.001]  # cameras in a row, cam0 leftmost
    rig = RigCalibration("cam0", {n: RigCamera(n, lens, p) for n, p in poses.items()},
                         metric_scale=True)
    write_calibration_files(rig, tmp_path / "20260101T000000Z")
    os.symlink("20260101T000000Z", tmp_path / "latest")
    for bad in (["cam0", "cam9"], ["cam0", "cam1", "cam1", "cam2"], ["cam0"]):
        with pytest.raises(InputError, match="stereo_pairs must list pairs of cameras"):
            ros.densecalib(tmp_path, name="bad_pair", stereo_pairs=bad)
    node = ros.densecalib(tmp_path, stereo_pairs=["cam0", "cam1"])
    listener = ros.listener(node)
    try:
        def published(name, field):
            info = listener.snapshot()["camera_info"].get(name)
            return None if info is None else np.array(getattr(info, field))

        assert wait_until(lambda: len(listener.snapshot()["camera_info"]) == 4, 10.0)
        want = rectify_pair(rig, "cam0", "cam1")
        np.testing.assert_allclose(published("cam0", "r"), want.rect_from_left.ravel())
        np.testing.assert_allclose(published("cam1", "p"), want.projection_right.ravel())
        p_right = published("cam1", "p")
        assert -p_right[3] / p_right[0] == pytest.approx(np.linalg.norm([0.1, 0.002, 0.001]))
        np.testing.assert_allclose(published("cam2", "r"), np.eye(3).ravel())
        assert node.publisher.stereo_problem is None
        # the pair named right-to-left: not rectifiable for stereo_image_proc, so R = I again
        assert node.set_parameters([Parameter("stereo_pairs",
                                              value=["cam1", "cam0"])])[0].successful
        assert wait_until(lambda: np.allclose(published("cam0", "r"), np.eye(3).ravel()), 10.0)
        assert "--pair cam0 cam1" in node.publisher.stereo_problem
        assert node.set_parameters([Parameter("stereo_pairs",
                                              value=["cam2", "cam3"])])[0].successful
        assert wait_until(lambda: not np.allclose(published("cam3", "r"), np.eye(3).ravel()),
                          10.0)
        np.testing.assert_allclose(published("cam0", "r"), np.eye(3).ravel())
        # two pairs at once (front and rear heads): each camera gets its own pair's R and P
        assert node.set_parameters([Parameter("stereo_pairs", value=[
            "cam0", "cam1", "cam2", "cam3"])])[0].successful
        assert wait_until(lambda: not np.allclose(published("cam0", "r"), np.eye(3).ravel()),
                          10.0)
        rear = rectify_pair(rig, "cam2", "cam3")
        np.testing.assert_allclose(published("cam3", "p"), rear.projection_right.ravel())
        np.testing.assert_allclose(published("cam1", "p"), want.projection_right.ravel())
        assert node.publisher.stereo_problem is None
        rig.metric_scale = False  # a pair without a known baseline is rectified, with a caveat
        infos = node.publisher.camera_infos(rig, 0)
        assert infos["cam3"].p[3] < 0 and "arbitrary units" in node.publisher.stereo_problem
        # the files a calibration writes say what is published: the pairs' YAML their R and P
        import yaml
        written = node.write_files(rig)
        for name in ("cam0", "cam3"):
            data = yaml.safe_load((written / f"{name}.yaml").read_text())
            np.testing.assert_allclose(data["rectification_matrix"]["data"], infos[name].r)
            np.testing.assert_allclose(data["projection_matrix"]["data"], infos[name].p)
        # floor turned on for a calibration that saved no scene points: said, nothing changes
        assert node.set_parameters([Parameter("floor", value="upright")])[0].successful
        assert wait_until(lambda: any("floor: not found in 20260101T000000Z" in s and
                                      "no COLMAP model" in s
                                      for s in listener.snapshot()["status"]), 10.0)
        assert read_calibration(tmp_path / "latest").quality.floor is None
        assert "rig" not in listener.rig_from_optical()
    finally:
        ros.remove(listener)
        ros.remove(node)


def test_floor_frame_is_published_above_the_rig(ros, tmp_path):
    """With floor on, a calibration that found its floor (calibrate --floor) is republished with
    floor_frame -> rig_frame beside the cameras on /tf_static, and without it once floor is
    turned off; bad floor settings are refused."""
    floor_from_rig = stored_rig_with_floor(tmp_path, metric_scale=True)
    with pytest.raises(InputError, match="floor must be '' \\(off\\) or one of upright, top"):
        ros.densecalib(tmp_path, name="bad_floor", floor="sideways")
    with pytest.raises(InputError, match="floor_frame 'rig' must be a valid tf frame id"):
        ros.densecalib(tmp_path, name="bad_floor_frame", floor="upright", floor_frame="rig")
    node = ros.densecalib(tmp_path, floor="upright")
    listener = ros.listener(node)
    try:
        assert wait_until(lambda: "rig" in listener.rig_from_optical(), 10.0)
        np.testing.assert_allclose(listener.rig_from_optical()["rig"], floor_from_rig, atol=1e-9)
        parents = {t.child_frame_id: t.header.frame_id
                   for t in listener.snapshot()["tf_static"][-1].transforms}
        assert parents == {"rig": "floor", **{f"{n}_optical_frame": "rig" for n in CAMERAS}}
        # turned off, and on again, at run time: /tf_static is replaced at once each time
        assert node.set_parameters([Parameter("floor", value="")])[0].successful
        assert wait_until(lambda: "rig" not in listener.rig_from_optical(), 10.0)
        assert set(listener.rig_from_optical()) == {f"{n}_optical_frame" for n in CAMERAS}
        assert node.set_parameters([Parameter("floor", value="top")])[0].successful
        assert wait_until(lambda: "rig" in listener.rig_from_optical(), 10.0)
    finally:
        ros.remove(listener)
        ros.remove(node)


def test_a_body_rig_frame_by_rep_103(ros, tmp_path):
    """rig_frame_axes 'body': rig_frame has REP-103 axes (x forward, y left, z up) at the
    reference camera, whose optical frame below it looks along x; every camera, and the floor
    above it, end where they were (floor_from_camera unchanged); bad values are refused."""
    stored_rig_with_floor(tmp_path, turn_deg=10.0)
    with pytest.raises(InputError, match="rig_frame_axes must be one of optical, body"):
        ros.densecalib(tmp_path, name="bad_axes", rig_frame_axes="enu")
    seen = {}
    for axes in ("optical", "body"):
        node = ros.densecalib(tmp_path, floor="upright", rig_frame_axes=axes)
        listener = ros.listener(node)
        try:
            assert wait_until(lambda: "rig" in listener.rig_from_optical(), 10.0)
            seen[axes] = listener.rig_from_optical()
        finally:
            ros.remove(listener)
            ros.remove(node)
    body = seen["body"]
    # the reference camera looks along the body's x axis, its image's down is the body's -z
    np.testing.assert_allclose(body["cam0_optical_frame"][:3, 2], [1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(body["cam0_optical_frame"][:3, 1], [0, 0, -1], atol=1e-12)
    for name in CAMERAS:
        frame = f"{name}_optical_frame"
        np.testing.assert_allclose(body["rig"] @ body[frame],
                                   seen["optical"]["rig"] @ seen["optical"][frame], atol=1e-12)


@pytest.mark.parametrize("damage", ["dangling", "not utf-8"])
def test_a_damaged_latest_falls_back_to_the_newest_calibration_that_reads(ros, tmp_path, damage):
    """`latest` pointing at nothing, or at a calibration.json of bytes that are not text: at
    start-up the node publishes the newest kept calibration that reads, and says so at WARN
    (it published nothing before: issue 40)."""
    from densecalib_ros.core.io.export import write_calibration_files
    from densecalib_ros.core.types import RigCalibration, RigCamera

    lens = CameraIntrinsics("RADIAL", 320, 240, np.array([300.0, 160.0, 120.0, 0.0, 0.0]))
    poses = {name: np.eye(4) for name in CAMERAS}
    for i, name in enumerate(CAMERAS):
        poses[name][:3, 3] = [-0.3 * i, 0.0, 0.0]
    write_calibration_files(RigCalibration("cam0", {n: RigCamera(n, lens, p)
                                                   for n, p in poses.items()}),
                            tmp_path / "20260101T000000Z")
    if damage == "dangling":
        os.symlink("20260102T000000Z", tmp_path / "latest")
    else:
        write_calibration_files(RigCalibration("cam0", {n: RigCamera(n, lens, np.eye(4))
                                                       for n in CAMERAS}),
                                tmp_path / "20260102T000000Z")
        (tmp_path / "20260102T000000Z" / "calibration.json").write_bytes(b"\xff\xfe{")
        os.symlink("20260102T000000Z", tmp_path / "latest")
    rosout = ros.add(RosoutListener(ros.context))
    time.sleep(0.5)  # /rosout is volatile: the listener must be matched before the start-up
    node = ros.densecalib(tmp_path)
    listener = ros.listener(node)
    try:
        assert wait_until(lambda: listener.rig_from_optical().get(
            "cam1_optical_frame", np.eye(4))[0, 3] == pytest.approx(0.3), 10.0)
        assert wait_until(lambda: any(
            m.level == Log.WARN and "20260101T000000Z, is published instead" in m.msg
            for m in rosout.copy()), 5.0)
    finally:  # a node left behind answers the next test's services under the same name
        ros.remove(rosout)
        ros.remove(listener)
        ros.remove(node)


def test_reload_publishes_the_calibration_changed_on_disk(ros, tmp_path):
    """`densecalib scale` on a running node's output_dir, then ~/reload: the node publishes the
    scaled calibration (cameras and floor); `latest` pointed at a calibration of other cameras:
    ~/reload refuses and the scaled one stays published."""
    from densecalib_ros.cli import main
    from densecalib_ros.core.io.export import write_calibration_files
    from densecalib_ros.core.types import RigCalibration, RigCamera

    stored_rig_with_floor(tmp_path)
    lens = CameraIntrinsics("RADIAL", 320, 240, np.array([300.0, 160.0, 120.0, 0.0, 0.0]))
    node = ros.densecalib(tmp_path, floor="upright")
    listener, reloader = ros.listener(node), ros.caller("reload")
    rosout = ros.add(RosoutListener(ros.context))
    try:
        def cam1_x():
            return listener.rig_from_optical().get("cam1_optical_frame", np.eye(4))[0, 3]

        assert wait_until(lambda: cam1_x() == pytest.approx(0.2), 10.0)
        assert wait_until(lambda: listener.snapshot()["points"], 5.0)
        assert listener.snapshot()["points"][-1].width == 0  # no COLMAP model saved: no points
        # cam0-cam1 measured 0.5 m: every length x 2.5
        assert main(["scale", str(tmp_path), "--baseline", "cam0", "cam1", "0.5"]) == 0
        assert cam1_x() == pytest.approx(0.2)  # the node does not watch its files
        response = reloader.call(30.0)
        assert response.success, response.message
        assert response.message.startswith(
            f"published {(tmp_path / '20260101T000000Z').resolve()}: 4 cameras")
        assert response.message.endswith("metric and with its floor")
        assert wait_until(lambda: cam1_x() == pytest.approx(0.5), 10.0)
        assert listener.rig_from_optical()["rig"][2, 3] == pytest.approx(3.75)
        assert node.calibration.metric_scale
        assert wait_until(lambda: (diagnostic_state(listener) or (0, "", {}))[2].get(
            "metric_scale") == "yes (cam0-cam1 = 0.5 m)", 5.0)

        # `latest` onto a calibration of cameras the node does not have: refused, nothing changes
        other = RigCalibration("left", {"left": RigCamera("left", lens, np.eye(4)),
                                        "right": RigCamera("right", lens, read_calibration(
                                            tmp_path / "latest").cameras["cam1"].cam_from_rig)})
        write_calibration_files(other, tmp_path / "20260202T000000Z")
        (tmp_path / "latest").unlink()
        os.symlink("20260202T000000Z", tmp_path / "latest")
        response = reloader.call(30.0)
        assert not response.success
        assert "['left', 'right'], which are not among camera_names" in response.message
        assert wait_until(lambda: any(  # an operator finds it among the errors
            m.level == Log.ERROR and m.msg.startswith("reload: not loaded")
            for m in rosout.copy()), 5.0)
        assert response.message.endswith("still publishing the calibration of "
                                         f"{(tmp_path / '20260101T000000Z').resolve()}")
        time.sleep(0.5)
        assert cam1_x() == pytest.approx(0.5) and node.calibration.metric_scale
        (tmp_path / "latest").unlink()
        response = reloader.call(30.0)
        assert not response.success and "no calibration under" in response.message
    finally:
        for n in (rosout, reloader, listener, node):
            ros.remove(n)


def test_sync_service_measures_the_stamp_offsets(ros, tmp_path):
    """Cameras whose drivers stamp by clocks up to 1.1 s apart film an animal walking: ~/sync
    finds the clocks' offsets from the motion in the images received (raw and compressed) and
    sets stamp_offsets_s, dropping the frame sets paired by the old ones; from then on each
    frame set joins images taken together. Without motion tracking, or before enough images,
    ~/sync says what to do and changes nothing."""
    clocks = {"cam0": 0.0, "cam1": 0.3, "cam2": -0.45, "cam3": 1.1}
    phases = {"cam0": 0.0, "cam1": 0.002, "cam2": 0.004, "cam3": 0.006}  # within the slop
    boxes = {"cam0": (0, 360, 0, 560), "cam1": (20, 360, 60, 640), "cam2": (0, 330, 40, 600),
             "cam3": (0, 360, 0, 640)}
    fps = 12
    views = arena_views({n: (fps, phases[n], boxes[n], 1.0) for n in CAMERAS}, size=(160, 100))
    frames = zip(*views.values())  # one tick: every camera's next frame
    untracked = ros.densecalib(tmp_path / "a")
    caller = ros.caller("sync")
    try:
        response = caller.call(10.0)
        assert not response.success and "set sync_window_s > 0" in response.message
    finally:
        ros.remove(untracked)
    # slop and queue wide enough for stamps alone to pair frames taken up to 70 ms apart (and
    # 1.1 s = 13 frames late): the wrong ones
    node = ros.densecalib(tmp_path / "b", sync_window_s=30.0, slop_s=0.07,
                          sync_queue_size=30)
    drivers = [ros.add(CameraPublisherNode(name, topic, encoding, context=ros.context))
               for name, (topic, encoding, _) in CAMERAS.items()]
    listener = ros.listener(node)

    def publish(ticks, first_tick):
        before = min(node.sync.received)
        for n, (k, images) in enumerate(zip(range(first_tick, first_tick + ticks), frames)):
            for driver, name, image in zip(drivers, CAMERAS, images):
                stamp_s = 5.0 + k / fps + phases[name] + clocks[name]
                driver.publish_image(image, int(round(stamp_s * 1e9)))
            # lets the node keep up (best-effort topics drop what overflows their queue; on a
            # loaded 2-core machine one camera lost 45 % of its frames at a fixed pace)
            wait_until(lambda: min(node.sync.received) >= before + n + 1, 1.0, 0.002)

    try:
        assert wait_until(lambda: node.camera_subscriptions.complete, 10.0), "topics not discovered"
        assert wait_until(lambda: all(d.num_subscribers() > 0 for d in drivers), 10.0)
        response = caller.call(10.0)
        assert not response.success and "too short" in response.message
        assert node.settings.stamp_offsets_s == [0.0] * 4
        publish(fps * 15, 0)  # 15 s of the animal walking
        buffered = len(node.sync)
        assert buffered > 0
        response = caller.call(30.0)
        assert response.success, response.message
        dropped = re.search(r"(\d+) buffered frame sets dropped", response.message)
        assert dropped and int(dropped.group(1)) >= buffered  # the last ones may still arrive
        measured = dict(zip(CAMERAS, node.get_parameter("stamp_offsets_s").value))
        for name, clock in clocks.items():
            assert measured[name] == pytest.approx(clock, abs=0.25 / fps), (name, measured)
        assert len(node.sync) == 0
        publish(fps * 2, fps * 15)
        assert wait_until(lambda: len(node.sync) >= 3, 5.0), node.sync.stats()
        for frame_set in node.sync.snapshot():  # corrected stamps = when the images were taken
            taken = np.array(frame_set.stamps_ns) * 1e-9 - np.array(list(phases.values()))
            assert np.ptp(taken) < 0.5 / fps, frame_set.stamps_ns

        def diagnosed():
            last = listener.snapshot()["diagnostics"][-1:]
            return last and {v.key: v.value for v in last[0].status[0].values}.get(
                "stamp_offsets_s", "").startswith("cam0=+0.0000, cam1=+0.3")
        assert wait_until(diagnosed, 5.0)  # the offsets in use, on /diagnostics
    finally:
        for other in [*drivers, listener, caller, node]:
            ros.remove(other)


def test_frames_lost_on_the_way_are_counted_and_reported(ros, tmp_path):
    """cam1's driver loses every fourth frame of a steady 10 fps stream before the node sees it
    (what an overflowing shared-memory segment does): /diagnostics counts them per camera and
    warns, and /rosout says what to do; the cameras that lose nothing count 0."""
    node = ros.densecalib(tmp_path / "out")
    drivers = [ros.add(CameraPublisherNode(name, topic, encoding, context=ros.context))
               for name, (topic, encoding, _) in CAMERAS.items()]
    listener, rosout = ros.listener(node), ros.add(RosoutListener(ros.context))
    image = np.random.default_rng(0).integers(0, 255, (48, 64, 3), dtype=np.uint8)
    ticks, lost = 80, [k for k in range(80) if k % 4 == 3]
    try:
        assert wait_until(lambda: node.camera_subscriptions.complete, 30.0), "topics not discovered"
        assert wait_until(lambda: all(d.num_subscribers() > 0 for d in drivers), 30.0)
        for k in range(ticks):
            before = list(node.sync.received)
            for c, driver in enumerate(drivers):
                if not (c == 1 and k in lost):
                    driver.publish_image(image, int((5.0 + k / 10) * 1e9))
            # paced by what the node received, so that only the frames meant to be lost are
            wait_until(lambda: all(node.sync.received[c] > before[c] for c in (0, 2, 3)), 1.0,
                       0.002)
        assert node.sync.received[1] == ticks - len(lost), node.sync.received

        # what arrived, per camera by name: a report published after the last frame (diagnostics
        # go out periodically, and one from mid-stream counts only the losses so far)
        received = ", ".join(f"{n}={ticks - (len(lost) if n == 'cam1' else 0)}" for n in CAMERAS)

        def reported():
            state = diagnostic_state(listener)
            return state if state and state[2].get("received_per_camera") == received else None
        assert wait_until(reported, 5.0), diagnostic_state(listener)
        level, message, values = reported()
        counts = dict(re.findall(r"(cam\d)=(\d+)", values["lost_frames_per_camera"]))
        # the first intervals only find the period (ros.frame_loss.MIN_INTERVALS)
        assert {n: int(k) for n, k in counts.items() if n != "cam1"} == \
            {"cam0": 0, "cam2": 0, "cam3": 0}
        assert len(lost) - 4 <= int(counts["cam1"]) <= len(lost), values
        assert "10.0 fps" in values["lost_frames_per_camera"]
        assert level == DiagnosticStatus.WARN and "frames lost on the way from cam1" in message
        # the sets complete on every camera
        assert 1 <= int(values["matched_frame_sets"]) <= ticks - len(lost), values
        assert wait_until(lambda: any(
            m.level == Log.WARN and "fastdds_large_images.xml" in m.msg and "cam1" in m.msg
            for m in rosout.copy()), 5.0)
    finally:
        for other in [*drivers, listener, rosout, node]:
            ros.remove(other)


def test_a_frame_that_does_not_decode_is_dropped_counted_and_named(ros, rig, tmp_path):
    """cam2's driver sends one PNG that is not a PNG: ~/calibrate names cam2 and what to check,
    the set holding it leaves the buffer (it blocked every calibration until ~/clear: issue
    40) and /diagnostics counts it against cam2 and warns; the good set stays."""
    node = ros.densecalib(tmp_path / "out")
    drivers = [ros.add(CameraPublisherNode(name, topic, encoding, context=ros.context))
               for name, (topic, encoding, _) in CAMERAS.items()]
    listener, caller = ros.listener(node), ros.caller("calibrate")
    try:
        assert wait_until(lambda: node.camera_subscriptions.complete, 30.0), "topics not discovered"
        assert wait_until(lambda: all(d.num_subscribers() > 0 for d in drivers), 30.0)
        for t, stamp_s in enumerate((1.0, 2.0)):
            for c, (driver, image) in enumerate(zip(drivers, rig.images[t])):
                if t == 1 and c == 2:  # what the driver compressed, cut short on the way
                    msg = numpy_to_compressed_msg(image, "png", int(stamp_s * 1e9),
                                                  driver.frame_id)
                    msg.data = msg.data[:len(msg.data) // 3]
                    driver.publisher.publish(msg)
                else:
                    driver.publish_image(image, int(stamp_s * 1e9))
            assert wait_until(lambda: len(node.sync) == t + 1, 10.0), node.sync.stats()
        response = caller.call(30.0)
        assert not response.success, response.message
        assert "cam2 1" in response.message and "check that camera's driver" in response.message
        assert len(node.sync) == 1  # the good set

        def reported():
            state = diagnostic_state(listener)
            return state if state and "malformed_frames_per_camera" in state[2] else None
        assert wait_until(reported, 5.0)
        level, message, values = reported()
        assert values["malformed_frames_per_camera"].startswith("cam0=0, cam1=0, cam2=1 (")
        # WARN at least (ERROR here: the failed call and no calibration yet)
        assert level >= DiagnosticStatus.WARN and "do not decode from cam2" in message
    finally:
        for other in [*drivers, listener, caller, node]:
            ros.remove(other)


def test_a_stop_while_the_files_are_written_tells_the_caller_what_became_current(ros, rig,
                                                                                 tmp_path):
    """Shutdown (SIGTERM: stop()) while a calibration writes its files: the write ends, `latest`
    points at it, and the waiting ~/calibrate caller is told so (it was told 'abandoned; the last
    calibration stays' while latest switched: issue 40); a stop before the write writes nothing."""
    node = ros.densecalib(tmp_path / "calib")
    publish_frame_sets(ros, node, rig.images)
    write = node.write_files

    def slow_write(*args, **kwargs):  # the stop lands in the middle of the write
        out = write(*args, **kwargs)
        time.sleep(0.5)
        return out
    node.write_files = slow_write
    caller = ros.caller("calibrate")
    try:
        future = caller.call_async()
        assert wait_until(node.jobs.writing.is_set, CALIBRATION_TIMEOUT_S, 0.005)
        node.stop()
        assert wait_until(future.done, 10.0)
        answer = future.result()
        latest = (tmp_path / "calib" / "latest").resolve()
        assert answer.success and f"files in {latest}" in answer.message, answer.message
    finally:
        ros.remove(caller)
        ros.remove(node)


def test_destroying_the_node_during_a_calibration_ends_the_job(ros, rig, tmp_path):
    """Shutdown (destroy_node) while a calibration runs: the calibration is stopped, and the
    worker's publishing no longer kills its thread, so the job is still answered and nobody is
    left waiting on it."""
    node = ros.densecalib(tmp_path / "calib")
    publish_frame_sets(ros, node, rig.images)
    job = node.start_calibration("test")
    assert job is not None
    ros.remove(node)  # the calibration publishes its progress from here on
    assert job.done.wait(CALIBRATION_TIMEOUT_S)
    assert job.outcome is not None and not job.outcome.success, job.outcome
    # stopped at the core's next check (abandoned), or at a publisher destroyed under it
    assert re.search(r"shutting down: the calibration was abandoned|shut down before",
                     job.outcome.message), job.outcome.message


def test_timers_of_a_destroyed_node_end_quietly(ros, tmp_path):
    """A timer callback due when destroy_node runs publishes on destroyed publishers: it must not
    raise, since an exception from a callback ends the shared executor's spin() (every other node
    in the process would go silent). Called here after destroy_node, as the executor would."""
    from rclpy.exceptions import InvalidHandle

    node = ros.densecalib(tmp_path / "calib", image_topics=["/absent/a/image_raw",
                                                           "/absent/b/image_raw"],
                          camera_names=["a", "b"], transports=["auto"], check_interval_s=1.0)
    callbacks = [t.callback for t in node.timers]
    assert len(callbacks) == 3  # topic discovery, diagnostics, watch
    ros.remove(node)
    with pytest.raises(InvalidHandle):
        node.publish_diagnostics()  # what the diagnostics timer does, unguarded
    for callback in callbacks:
        callback()


def test_bag_replay_gives_the_same_result(ros, rig, tmp_path):
    """Bags of the rig's images (sqlite3 raw, mcap compressed png) replayed into the node calibrate
    to the same result; the live test above saw the same (lossless) images."""
    topics = [c[0] for c in CAMERAS.values()]
    stamps = [[int((1.0 + t) * 1e9) + 1_000_000 * c for c in range(4)] for t in range(2)]
    results = {}
    gt = rig.ground_truth()
    baseline_m = camera_distance(gt, "cam0", "cam2")  # the generator's units are metres
    for storage, encoding in (("sqlite3", "rgb8"), ("mcap", "png")):
        bag = tmp_path / f"bag_{storage}"
        write_image_bag(bag, rig.images, topics, stamps, storage=storage, encoding=encoding)
        scale = dict(known_baseline_m=baseline_m, baseline_cameras=["cam0", "cam2"]) \
            if storage == "mcap" else {}
        node = ros.densecalib(tmp_path / f"out_{storage}", replay_bag=str(bag),
                              calibrate_after_replay=True, transports=["auto"], **scale)
        try:
            assert wait_until(lambda: node.calibration is not None or node.last_failure,
                              CALIBRATION_TIMEOUT_S, 0.1)
            assert node.last_failure is None, node.last_failure
            assert node.sync.stats()["received"] == [2, 2, 2, 2]
            assert len(node.sync) == 2
            results[storage] = node.calibration
        finally:
            ros.remove(node)
    a, b = results["sqlite3"], results["mcap"]
    assert set(a.cameras) == set(b.cameras) == set(CAMERAS)
    # mcap's run has metric scale: cam0-cam2 at the true distance, everything else the same.
    assert b.metric_scale and not a.metric_scale
    assert camera_distance(b, "cam0", "cam2") == pytest.approx(baseline_m, rel=1e-9)
    factor = baseline_m / camera_distance(a, "cam0", "cam2")
    for name in CAMERAS:
        assert np.allclose(a.cameras[name].intrinsics.params, b.cameras[name].intrinsics.params,
                           rtol=1e-6, atol=1e-9)
        ta, tb = a.cameras[name].cam_from_rig, b.cameras[name].cam_from_rig
        assert np.allclose(ta[:3, :3], tb[:3, :3], atol=1e-6)
        assert np.allclose(ta[:3, 3] * factor, tb[:3, 3], atol=1e-6)
        # metric translations close to the truth (the SfM scale is fixed by one pair only)
        assert np.linalg.norm(tb[:3, 3] - gt.cameras[name].cam_from_rig[:3, 3]) < 0.05 * baseline_m
    # keep_intrinsics: a node restarted on the sqlite3 run's output recalibrates from the mcap
    # bag with that calibration's intrinsics kept exactly.
    node = ros.densecalib(tmp_path / "out_sqlite3", name="keep_node",
                          replay_bag=str(tmp_path / "bag_mcap"), calibrate_after_replay=True,
                          transports=["auto"], keep_intrinsics=True)
    try:
        assert wait_until(lambda: node.calibration is not a and node.calibration is not None
                          and node.calibration.quality.init is not None or node.last_failure,
                          CALIBRATION_TIMEOUT_S, 0.1)
        assert node.last_failure is None, node.last_failure
        kept = node.calibration
        assert sorted(kept.quality.given_intrinsics) == sorted(CAMERAS)
        for name in CAMERAS:
            np.testing.assert_array_equal(kept.cameras[name].intrinsics.params,
                                          a.cameras[name].intrinsics.params)
        errors = relative_pose_errors({n: c.cam_from_rig for n, c in kept.cameras.items()},
                                      {n: c.cam_from_rig for n, c in gt.cameras.items()})
        assert max(e.rot_err_deg for e in errors) < 1.0
    finally:
        ros.remove(node)
    # ... and to the same result as the ROS-free path: core.io.bag + calibrate_rig on the same bag.
    frame_sets, names = read_frame_sets(tmp_path / "bag_mcap", topics, slop_s=0.01)
    offline = calibrate_rig(frame_sets, list(CAMERAS),
                            make_config("regular", DEFAULT_PIPELINE, "sift"))
    assert names == ["rig_cam0", "rig_cam1", "rig_cam2", "rig_cam3"]
    for name in CAMERAS:
        assert np.allclose(offline.cameras[name].intrinsics.params,
                           a.cameras[name].intrinsics.params, rtol=1e-6, atol=1e-9)
        assert np.allclose(offline.cameras[name].cam_from_rig, a.cameras[name].cam_from_rig,
                           atol=1e-6)
    errors = relative_pose_errors({n: c.cam_from_rig for n, c in a.cameras.items()},
                                  {n: c.cam_from_rig for n, c in gt.cameras.items()})
    assert max(e.rot_err_deg for e in errors) < 3.0


def test_demo_command(tmp_path, capsys):
    """`densecalib demo` (the README main job) on a small rig: node, drivers, action, truth."""
    from densecalib_ros.cli import main

    out = tmp_path / "demo"
    code = main(["demo", "--cameras", "4", "--width", "320", "--height", "240", "--seed", "1",
                 "--out", str(out)])
    text = capsys.readouterr().out
    assert code == 0, text
    assert "result: success=True: calibrated 4/4 cameras" in text
    assert re.search(r"^  \[\s*\d+\.\d s\] .+ \(\d+ % done", text, re.M), text  # the feedback
    summary = re.search(r"all 6 camera pairs: AUC@3 ([\d.]+), AUC@30 ([\d.]+), max rotation "
                        r"error ([\d.]+) deg", text)
    assert summary and float(summary[2]) > 90.0 and float(summary[3]) < 3.0, text
    rows = [line.split() for line in text.splitlines() if re.match(r"cam\d ", line)]
    assert [r[0] for r in rows] == ["cam0", "cam1", "cam2", "cam3"]
    assert all(float(r[3]) < 5.0 for r in rows)  # focal error in percent
    assert (out / "latest" / "calibration.json").is_file()
    assert (out / "rig" / "ground_truth.json").is_file()
    assert (out / "rig" / "cam3" / "0001.png").is_file()


def test_the_node_process_ends_cleanly_on_sigterm_and_says_what_a_bad_value_is(tmp_path):
    """The node as systemd, docker stop or ros2 launch run it: SIGTERM ends it like Ctrl-C (exit
    0; glog's handler, which pycolmap installs, dumped a stack and exited 143), and a start-up
    value of the wrong type is one FATAL line, not a traceback."""
    import signal
    import subprocess
    import sys

    def start(*params):
        args = ["--ros-args", "-p", "image_topics:=['/t/cam0/image_raw','/t/cam1/image_raw']",
                "-p", f"output_dir:={tmp_path / 'out'}"]
        for p in params:
            args += ["-p", p]
        return subprocess.Popen(
            [sys.executable, "-c", "import sys; from densecalib_ros.ros.main import main; "
             "sys.exit(main())", *args], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
            text=True, env={**os.environ, "ROS_DOMAIN_ID": str(int(os.environ.get(
                "ROS_DOMAIN_ID", "0")) + 1)})

    bad = start("slop_s:=1")
    out, _ = bad.communicate(timeout=60)
    assert bad.returncode == 1 and "[FATAL]" in out and "slop_s" in out, out
    assert "Traceback" not in out
    node = start()
    lines = []
    for line in node.stdout:  # wait for it to be up
        lines.append(line)
        if "ready:" in line:
            break
    assert any("ready:" in line for line in lines), "".join(lines)
    node.send_signal(signal.SIGTERM)
    rest, _ = node.communicate(timeout=30)
    assert node.returncode == 0, "".join(lines) + rest
    assert "Aborted" not in rest


def test_ctrl_c_during_a_calibration_answers_the_caller_and_exits_cleanly(ros, rig, tmp_path):
    """The node process interrupted while its worker calibrates (inside OpenCV or COLMAP): the
    waiting ~/calibrate caller is told the calibration was abandoned, the process exits 0 at once
    (interpreter exit used to unwind the worker through C++ frames: SIGABRT, exit 134) and
    nothing is written."""
    import signal
    import subprocess
    import sys

    out = tmp_path / "out"
    topics = [c[0] for c in CAMERAS.values()]
    node = subprocess.Popen(
        [sys.executable, "-c", "import sys; from densecalib_ros.ros.main import main; "
         "sys.exit(main())", "--ros-args", "-p", f"image_topics:={topics}",
         "-p", f"camera_names:={list(CAMERAS)}", "-p", f"output_dir:={out}",
         "-p", f"transports:={[c[2] for c in CAMERAS.values()]}", "-p", "min_frame_sets:=2",
         "-p", "slop_s:=0.01", "-p", "matcher:=sift"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
        env={**os.environ, "ROS_DOMAIN_ID": str(DOMAIN_ID)})
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(node.stdout), daemon=True)
    reader.start()
    drivers = [ros.add(CameraPublisherNode(name, topic, encoding, context=ros.context))
               for name, (topic, encoding, _) in CAMERAS.items()]
    caller = ros.caller()
    try:
        assert wait_until(lambda: all(d.num_subscribers() > 0 for d in drivers), 60.0), lines
        for t, images in enumerate(rig.images * 2):  # 4 sets, 1 s apart
            for driver, image in zip(drivers, images):
                driver.publish_image(image, int((1.0 + t) * 1e9))
            time.sleep(0.3)
        answer = caller.call_async(wait_for_service_s=30.0)
        assert wait_until(lambda: any("matched frame set" in x for x in lines), 60.0), lines
        node.send_signal(signal.SIGINT)
        assert node.wait(timeout=15) == 0, "".join(lines)
        assert wait_until(answer.done, 10.0), "no answer"
        assert not answer.result().success
        assert "shutting down: the calibration was abandoned" in answer.result().message
        reader.join(5)
        text = "".join(lines)
        assert "Aborted" not in text and "Traceback" not in text and "never retrieved" not in text
        assert not (out / "latest").exists()
    finally:
        if node.poll() is None:
            node.kill()
        for n in drivers + [caller]:
            ros.remove(n)
