"""The other ends of the calibration node, for the demo and the node tests: camera publisher
nodes (one rclpy node per camera, as a real camera driver would be), a listener of the node's
outputs, and non-blocking clients of its Trigger services and of its Calibrate action."""
from __future__ import annotations

import threading
import time
from typing import Callable, Optional

import numpy as np
from densecalib_interfaces.action import Calibrate
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.action import ActionClient
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, CompressedImage, Image, PointCloud2
from std_msgs.msg import String
from std_srvs.srv import Trigger
from tf2_msgs.msg import TFMessage

from ..core.io.image_encoding import COMPRESSED_FORMATS
from .conversions import numpy_to_compressed_msg, numpy_to_image_msg, transform_to_matrix
from .publishing import LATCHED_QOS

# Reliable (a best-effort subscriber still matches) and deep enough for a burst of frame sets.
CAMERA_QOS = QoSProfile(depth=20, reliability=ReliabilityPolicy.RELIABLE)
# The node's latched ~/status: a listener arriving late gets the current line, and keeps the lines
# that follow in bursts.
STATUS_QOS = QoSProfile(depth=20, reliability=ReliabilityPolicy.RELIABLE,
                        durability=DurabilityPolicy.TRANSIENT_LOCAL)


class CameraPublisherNode(Node):
    """Publishes one camera's images on `topic` with `encoding` (raw or jpeg/png compressed)."""

    def __init__(self, camera_name: str, topic: str, encoding: str = "rgb8", **node_kwargs):
        super().__init__(f"{camera_name}_driver", **node_kwargs)
        self.camera_name, self.topic, self.encoding = camera_name, topic, encoding
        self.compressed = encoding in COMPRESSED_FORMATS
        self.frame_id = f"{camera_name}_optical_frame"
        self.publisher = self.create_publisher(CompressedImage if self.compressed else Image,
                                               topic, CAMERA_QOS)

    def publish_image(self, image: np.ndarray, t_ns: int) -> None:
        """image: uint8 RGB (H, W, 3) or gray (H, W); t_ns: header stamp in nanoseconds."""
        if self.compressed:
            msg = numpy_to_compressed_msg(image, self.encoding, t_ns, self.frame_id)
        else:
            msg = numpy_to_image_msg(image, self.encoding, t_ns, self.frame_id)
        self.publisher.publish(msg)

    def num_subscribers(self) -> int:
        return self.publisher.get_subscription_count()


class CalibrationListener(Node):
    """Subscribes to what the calibration node publishes: CameraInfo per camera and /tf_static
    (transient local, so a listener started later still gets the last calibration), the node's
    status (latched too: the current line), /diagnostics and (points_topic) its scene points.
    Thread-safe accessors for the latest messages."""

    def __init__(self, camera_info_topics: dict[str, str], status_topic: str,
                 name: str = "densecalib_listener", points_topic: Optional[str] = None,
                 **node_kwargs):
        super().__init__(name, **node_kwargs)
        self._lock = threading.Lock()
        self.camera_info: dict[str, CameraInfo] = {}
        self.tf_static: list[TFMessage] = []
        self.status: list[str] = []
        self.diagnostics: list[DiagnosticArray] = []
        self.points: list[PointCloud2] = []
        if points_topic:
            self.create_subscription(PointCloud2, points_topic,
                                     lambda m: self._store("points", m), LATCHED_QOS)
        for camera, topic in camera_info_topics.items():
            self.create_subscription(CameraInfo, topic,
                                     lambda m, c=camera: self._store("camera_info", m, c),
                                     LATCHED_QOS)
        self.create_subscription(TFMessage, "/tf_static", lambda m: self._store("tf", m),
                                 LATCHED_QOS)
        self.create_subscription(String, status_topic, lambda m: self._store("status", m),
                                 STATUS_QOS)
        self.create_subscription(DiagnosticArray, "/diagnostics",
                                 lambda m: self._store("diag", m), 10)

    def _store(self, kind: str, msg, camera: Optional[str] = None) -> None:
        with self._lock:
            if kind == "camera_info":
                self.camera_info[camera] = msg
            elif kind == "tf":
                self.tf_static.append(msg)
            elif kind == "status":
                self.status.append(msg.data)
            elif kind == "points":
                self.points.append(msg)
            else:
                self.diagnostics.append(msg)

    def rig_from_optical(self) -> dict[str, np.ndarray]:
        """child frame -> 4x4 parent_from_child of the latest /tf_static message (empty if none)."""
        with self._lock:
            if not self.tf_static:
                return {}
            return {t.child_frame_id: transform_to_matrix(t)
                    for t in self.tf_static[-1].transforms}

    def snapshot(self) -> dict:
        with self._lock:
            return {"camera_info": dict(self.camera_info), "tf_static": list(self.tf_static),
                    "status": list(self.status), "diagnostics": list(self.diagnostics),
                    "points": list(self.points)}


def wait_until(predicate: Callable[[], bool], timeout_s: float, period_s: float = 0.02) -> bool:
    """Poll `predicate` until it holds or `timeout_s` passes; returns its last value."""
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            return False
        time.sleep(period_s)
    return True


class TriggerCaller(Node):
    """Calls a std_srvs/Trigger service without blocking the executor that spins this node."""

    def __init__(self, service: str, name: str = "densecalib_caller", **node_kwargs):
        super().__init__(name, **node_kwargs)
        self.client = self.create_client(Trigger, service)

    def call_async(self, wait_for_service_s: float = 10.0):
        if not wait_until(self.client.service_is_ready, wait_for_service_s):
            raise TimeoutError(f"service {self.client.srv_name} not available after "
                               f"{wait_for_service_s} s")
        return self.client.call_async(Trigger.Request())

    def call(self, timeout_s: float) -> Trigger.Response:
        future = self.call_async()
        if not wait_until(future.done, timeout_s, 0.05):
            self.client.remove_pending_request(future)
            raise TimeoutError(f"no answer from {self.client.srv_name} within {timeout_s} s")
        return future.result()


class CalibrateGoalClient(Node):
    """Sends goals to a Calibrate action (`action`: e.g. /densecalib_node/calibrate) without
    blocking the executor that spins this node, and keeps each feedback with its arrival time
    (time.monotonic())."""

    def __init__(self, action: str, name: str = "densecalib_goal_client", **node_kwargs):
        super().__init__(name, **node_kwargs)
        self.action = action
        self.client = ActionClient(self, Calibrate, action)
        self._lock = threading.Lock()
        self._feedback: list[tuple[float, Calibrate.Feedback]] = []
        self.on_feedback: Optional[Callable[[Calibrate.Feedback], None]] = None

    def _store(self, msg) -> None:
        with self._lock:
            self._feedback.append((time.monotonic(), msg.feedback))
        if self.on_feedback is not None:
            self.on_feedback(msg.feedback)

    def feedback(self) -> list[tuple[float, Calibrate.Feedback]]:
        with self._lock:
            return list(self._feedback)

    def send(self, goal: Optional[Calibrate.Goal] = None, timeout_s: float = 10.0,
             wait_for_server_s: float = 10.0):
        """Send `goal` (default: all options from the node's parameters); the goal handle once
        the server answered (`.accepted` says whether it took the goal)."""
        if not self.client.wait_for_server(timeout_sec=wait_for_server_s):
            raise TimeoutError(f"action {self.action} not available after "
                               f"{wait_for_server_s} s")
        future = self.client.send_goal_async(goal or Calibrate.Goal(),
                                             feedback_callback=self._store)
        if not wait_until(future.done, timeout_s):
            raise TimeoutError(f"the goal was not answered within {timeout_s} s")
        return future.result()

    @staticmethod
    def result(goal_handle, timeout_s: float):
        """(status, result) of an accepted goal once it ended (status: action_msgs GoalStatus's
        STATUS_SUCCEEDED, STATUS_CANCELED or STATUS_ABORTED)."""
        future = goal_handle.get_result_async()
        if not wait_until(future.done, timeout_s, 0.01):
            raise TimeoutError(f"the goal did not end within {timeout_s} s")
        return future.result().status, future.result().result
