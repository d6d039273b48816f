"""What the node publishes of a calibration: CameraInfo per camera (the stereo_pairs' with their
pair's rectification), the cameras in one latched /tf_static message (and floor_frame ->
rig_frame), the scene points on ~/points, and the CameraInfo sent to the drivers'
set_camera_info services."""
from __future__ import annotations

import time
from pathlib import Path
from typing import Optional

import numpy as np
from rclpy.callback_groups import ReentrantCallbackGroup
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CameraInfo, PointCloud2
from sensor_msgs.srv import SetCameraInfo
from tf2_msgs.msg import TFMessage

from ..core.errors import InputError
from ..core.products.stereo import stereo_pair
from ..core.types import RigCalibration
from .conversions import camera_info_msg, frame_from_rig, point_cloud_msg, rig_tf_message
from .settings import Settings

LATCHED_QOS = QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST,
                         reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)


def floor_parent(s: Settings) -> Optional[str]:
    """The frame /tf_static puts above rig_frame: floor_frame where floor is on, else none."""
    return s.floor_frame if s.floor else None


class CalibrationPublisher:
    """The node's publishers and set_camera_info clients for its calibration; the topics are
    the settings' at start-up, what is published follows the current settings."""

    def __init__(self, node):
        s = node.settings
        self._node = node
        self.stereo_problem: Optional[str] = None  # why stereo_pairs' CameraInfo lack R, P
        self._info_pubs = [node.create_publisher(CameraInfo, topic, LATCHED_QOS)
                           for topic in s.camera_info_topics]
        self._tf_pub = node.create_publisher(TFMessage, "/tf_static", LATCHED_QOS)
        self._points_pub = node.create_publisher(PointCloud2, "~/points", LATCHED_QOS)
        group = ReentrantCallbackGroup()
        self._set_info_clients = [node.create_client(SetCameraInfo, srv, callback_group=group)
                                  for srv in s.set_camera_info_services]

    def publish(self, rig: RigCalibration, directory: Path) -> None:
        """CameraInfo per calibrated camera, all extrinsics in one /tf_static message, the scene
        points."""
        t_ns = self._node.get_clock().now().nanoseconds
        self.publish_camera_infos(rig, t_ns)
        self.publish_tf(rig, t_ns)
        self.publish_points(rig, directory, t_ns)

    def publish_tf(self, rig: RigCalibration, t_ns: int) -> None:
        """Replace the latched /tf_static message: the cameras, and floor_frame -> rig_frame
        when floor is on and the calibration found its floor. Turning floor off republishes
        without it, so late joiners never see it (tf2 listeners that already hold it keep it:
        tf2 never forgets a static transform)."""
        s = self._node.settings
        frames = dict(zip(s.camera_names, s.frame_names))
        self._tf_pub.publish(rig_tf_message(rig, s.rig_frame, frames, t_ns, floor_parent(s),
                                            s.rig_frame_axes))

    def publish_points(self, rig: RigCalibration, directory: Path, t_ns: int) -> None:
        """Replace the latched ~/points cloud with the scene points of the calibration's saved
        COLMAP model, in rig_frame and the rig's units, in their image colours (RViz shows the
        scene beside the camera frames); an empty cloud when it saved none."""
        from ..core.products.floor import saved_scene_points

        points, colours = np.zeros((0, 3)), None
        try:
            points, colours = saved_scene_points(directory, rig) or (points, colours)
        except Exception as exc:  # an unreadable model costs the view, never the calibration
            self._node.get_logger().warning(f"no scene points published: {exc}")
        to_frame = frame_from_rig(self._node.settings.rig_frame_axes)[:3, :3]
        self._points_pub.publish(point_cloud_msg(points @ to_frame.T, colours,
                                                 self._node.settings.rig_frame, t_ns))

    def publish_camera_infos(self, rig: RigCalibration, t_ns: int) -> None:
        infos = self.camera_infos(rig, t_ns)
        for name, pub in zip(self._node.settings.camera_names, self._info_pubs):
            if name in infos:
                pub.publish(infos[name])

    def camera_infos(self, rig: RigCalibration, t_ns: int) -> dict:
        """CameraInfo per calibrated camera, the stereo_pairs' with their rectification. A pair
        that cannot be rectified (see core.products.stereo) keeps R = I, and self.stereo_problem
        says why."""
        frames = dict(zip(self._node.settings.camera_names, self._node.settings.frame_names))
        rectified, problems = self.rectifications(rig, warn=True)
        self.stereo_problem = "; ".join(problems) or None
        return {name: camera_info_msg(name, cam.intrinsics, frames[name], t_ns,
                                      *rectified.get(name, (None, None)))
                for name, cam in rig.cameras.items() if name in frames}

    def rectifications(self, rig: RigCalibration, warn: bool = False
                        ) -> tuple[dict, list[str]]:
        """{camera: (rect_from_cam, projection)} of the stereo_pairs that rectify, and what is
        wrong with the others (a pair that cannot be rectified also at WARN with `warn`)."""
        rectified, problems = {}, []
        for left, right in self._node.settings.stereo_pairs:
            if left not in rig.cameras or right not in rig.cameras:
                problems.append(f"stereo pair {left}-{right} not rectified: not both calibrated")
                continue
            try:
                pair = stereo_pair(rig, (left, right))
            except InputError as exc:
                problems.append(f"stereo pair {left}-{right} not rectified: {exc}")
                if warn:
                    self._node.get_logger().warning(problems[-1])
                continue
            rectified[left] = (pair.rect_from_left, pair.projection_left)
            rectified[right] = (pair.rect_from_right, pair.projection_right)
            if not pair.metric:
                problems.append(f"stereo pair {left}-{right} rectified, but without metric "
                                "scale: its baseline and stereo depths are in arbitrary units "
                                "(set known_baseline_m and baseline_cameras)")
        return rectified, problems

    def call_set_camera_info(self, rig: RigCalibration) -> str:
        """Call every calibrated camera's set_camera_info concurrently, waiting at most
        set_camera_info_timeout_s in all; returns the per-camera outcome ("cam0 ok, cam1 timeout,
        ...")."""
        s = self._node.settings
        infos = self.camera_infos(rig, self._node.get_clock().now().nanoseconds)
        calls = []  # (camera, client, future or None when the service is not there)
        for name, client in zip(s.camera_names, self._set_info_clients):
            if name not in infos:
                continue
            future = None
            if client.service_is_ready():
                request = SetCameraInfo.Request()
                request.camera_info = infos[name]
                future = client.call_async(request)
            calls.append((name, client, future))
        deadline = time.monotonic() + s.set_camera_info_timeout_s
        outcomes = []
        for name, client, future in calls:
            if future is None:
                outcome = f"{name} no service {client.srv_name}"
            else:
                while not future.done() and time.monotonic() < deadline:
                    time.sleep(0.01)
                if not future.done():
                    client.remove_pending_request(future)
                    outcome = f"{name} timeout"
                elif future.result() is None or not future.result().success:
                    reason = future.result().status_message if future.result() else "no answer"
                    outcome = f"{name} refused ({reason})"
                else:
                    outcome = f"{name} ok"
            self._node.get_logger().info(f"set_camera_info: {outcome}")
            outcomes.append(outcome)
        return ", ".join(outcomes) or "no calibrated camera"
