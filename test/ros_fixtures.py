"""What the node tests share: one rclpy context and executor per test module on a domain of its
own (localhost discovery), the generated rig's cameras and topics, publishing frame sets from real
camera driver nodes, listeners of the node's outputs, and a stored calibration to start from."""
import os
import threading
import time

import numpy as np
import rclpy
import rclpy.node
from rcl_interfaces.msg import Log
from rclpy.context import Context
from rclpy.exceptions import InvalidHandle
from rclpy.executors import MultiThreadedExecutor
from rclpy.parameter import Parameter
from scipy.spatial.transform import Rotation

from densecalib_ros.core.types import CameraIntrinsics, RigQuality
from densecalib_ros.ros.node import DenseCalibNode
from densecalib_ros.ros.rig_nodes import (CalibrateGoalClient, CalibrationListener,
                                          CameraPublisherNode, TriggerCaller, wait_until)

# A domain of our own (the process id keeps parallel runs apart) and no discovery beyond this host.
DOMAIN_ID = 30 + os.getpid() % 70
os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"

# camera -> (topic, what the camera publishes, the node's `transports` entry). All lossless, so
# the live run, the replays and the offline read see identical images.
CAMERAS = {
    "cam0": ("/rig/cam0/image_raw", "rgb8", "auto"),  # type discovered from the graph
    "cam1": ("/rig/cam1/image_raw", "bgr8", "raw"),
    "cam2": ("/rig/cam2/image_raw/compressed", "png", "auto"),  # compressed by its name
    "cam3": ("/rig/cam3/image", "png", "auto"),  # CompressedImage discovered from the graph
}
CALIBRATION_TIMEOUT_S = 240.0


class Ros:
    """One rclpy context + multi-threaded executor for the module; nodes are added and removed."""

    def __init__(self):
        self.context = Context()
        rclpy.init(context=self.context, domain_id=DOMAIN_ID)
        self.executor = MultiThreadedExecutor(num_threads=6, context=self.context)
        self._closing = threading.Event()
        self.thread = threading.Thread(target=self._spin, daemon=True)
        self.thread.start()

    def _spin(self):
        while not self._closing.is_set():
            try:
                self.executor.spin_once(timeout_sec=0.1)
            except InvalidHandle:  # rclpy#1355: a node removed while the wait set was built
                continue

    def add(self, node):
        self.executor.add_node(node)
        return node

    def remove(self, node):
        self.executor.remove_node(node)
        node.destroy_node()

    def densecalib(self, output_dir, name="densecalib_node", **params):
        values = dict(image_topics=[c[0] for c in CAMERAS.values()], camera_names=list(CAMERAS),
                      transports=[c[2] for c in CAMERAS.values()], output_dir=str(output_dir),
                      min_frame_sets=2, preset="regular", matcher="sift", slop_s=0.01)
        values.update(params)
        overrides = [Parameter(k, value=v) for k, v in values.items() if v is not None]
        return self.add(DenseCalibNode(name, context=self.context, parameter_overrides=overrides))

    def listener(self, node):
        topics = {name: node.resolve_topic_name(topic) for name, topic in
                  zip(node.settings.camera_names, node.settings.camera_info_topics)}
        return self.add(CalibrationListener(topics, "/densecalib_node/status",
                                            name=f"listener_{time.monotonic_ns()}",
                                            points_topic="/densecalib_node/points",
                                            context=self.context))

    def caller(self, service="calibrate"):
        return self.add(TriggerCaller(f"/densecalib_node/{service}",
                                      name=f"caller_{time.monotonic_ns()}", context=self.context))

    def goal_client(self, action="/densecalib_node/calibrate"):
        return self.add(CalibrateGoalClient(action, name=f"goal_client_{time.monotonic_ns()}",
                                            context=self.context))

    def close(self):
        self._closing.set()
        self.thread.join(5)
        self.executor.shutdown(timeout_sec=5)
        rclpy.shutdown(context=self.context)


def publish_frame_sets(ros, node, frame_sets, first_stamp_s=1.0):
    """Publish frame_sets[t][c] from one driver node per camera, set t stamped first + t seconds,
    and wait until the node buffered each set (republishing a set that got lost)."""
    drivers = [ros.add(CameraPublisherNode(name, topic, encoding, context=ros.context))
               for name, (topic, encoding, _) in CAMERAS.items()]
    try:  # discovery on a loaded 2-core CI machine once took over 10 s: wait up to 30
        assert wait_until(lambda: node.camera_subscriptions.complete, 30.0), "topics not discovered"
        assert wait_until(lambda: all(d.num_subscribers() > 0 for d in drivers), 30.0)
        start = len(node.sync)
        for t, images in enumerate(frame_sets):
            for _attempt in range(3):
                for driver, image in zip(drivers, images):
                    driver.publish_image(image, int((first_stamp_s + t) * 1e9))
                if wait_until(lambda: len(node.sync) >= start + t + 1, 5.0):
                    break
            assert len(node.sync) == start + t + 1, node.sync.stats()
    finally:
        for d in drivers:
            ros.remove(d)


def diagnostic_state(listener):
    """(level, message, {key: value}) of the node's latest /diagnostics status, or None."""
    diags = listener.snapshot()["diagnostics"]
    if not diags:
        return None
    status = diags[-1].status[0]
    return status.level, status.message, {kv.key: kv.value for kv in status.values}


class RosoutListener(rclpy.node.Node):
    def __init__(self, context):
        super().__init__(f"rosout_{time.monotonic_ns()}", context=context)
        self._lock, self._logs = threading.Lock(), []
        self.create_subscription(Log, "/rosout", self._store, 100)

    def _store(self, msg):
        with self._lock:
            self._logs.append(msg)

    def copy(self):
        with self._lock:
            return list(self._logs)


def camera_info_values(listener):
    return {n: (tuple(m.k), tuple(m.d), m.header.frame_id)
            for n, m in listener.snapshot()["camera_info"].items()}


def stored_rig_with_floor(folder, turn_deg=0.0, metric_scale=False):
    """A calibration of the CAMERAS written under folder/20260101T000000Z with `latest` on it:
    cameras 0.2 apart along -x (each turned by turn_deg more about y than the last), the floor
    1.5 m below the reference camera. Returns the floor_from_rig it records."""
    from densecalib_ros.core.io.export import write_calibration_files
    from densecalib_ros.core.types import RigCalibration, RigCamera

    lens = CameraIntrinsics("RADIAL", 320, 240, np.array([300.0, 160.0, 120.0, 0.0, 0.0]))
    poses = {name: np.eye(4) for name in CAMERAS}
    for i, name in enumerate(CAMERAS):
        poses[name][:3, :3] = Rotation.from_euler("y", turn_deg * i, degrees=True).as_matrix()
        poses[name][:3, 3] = [-0.2 * i, 0.05 * turn_deg * i / 100, 0.0]
    floor_from_rig = np.eye(4)
    floor_from_rig[:3, :3] = [[1, 0, 0], [0, 0, 1], [0, -1, 0]]  # optical y down = floor -z
    floor_from_rig[:3, 3] = [0.0, 0.0, 1.5]  # the reference camera 1.5 m above the floor
    rig = RigCalibration("cam0", {n: RigCamera(n, lens, p) for n, p in poses.items()},
                         quality=RigQuality(floor={
                             "floor_from_rig": floor_from_rig.ravel().tolist(), "num_points": 500,
                             "rms": 0.002, "camera_heights": {n: 1.5 for n in CAMERAS}}),
                         metric_scale=metric_scale)
    write_calibration_files(rig, folder / "20260101T000000Z")
    os.symlink("20260101T000000Z", folder / "latest")
    return floor_from_rig
