"""ROS message <-> numpy / core types, without cv_bridge or tf2_ros.

Images: sensor_msgs/Image (rgb8, bgr8, mono8, mono16, bayer_<pattern>8; more read: see
core.io.image_encoding.RAW_ENCODINGS) and CompressedImage (jpeg, png) <-> uint8 RGB (H, W, 3) / gray
(H, W) arrays (core.io.image_encoding does the pixels).
Calibration: CameraInfo from core.io.camera_info.ros_camera_info (ROS pixel convention, ROS
distortion model names); TransformStamped parent=rig frame -> child=<camera>_optical_frame holding
rig_from_cam = inverse(cam_from_rig) (tf's convention: the child frame's pose in the parent frame).
"""
from __future__ import annotations

from typing import Optional

import numpy as np
from builtin_interfaces.msg import Time
from geometry_msgs.msg import TransformStamped
from scipy.spatial.transform import Rotation
from sensor_msgs.msg import CameraInfo, CompressedImage, Image, PointCloud2, PointField
from tf2_msgs.msg import TFMessage

from ..core.io.bag import stamp_ns
from ..core.io.camera_info import ros_camera_info
from ..core.io.image_encoding import decode_compressed, decode_raw, encode_compressed, encode_raw
from ..core.types import CameraIntrinsics, RigCalibration


def time_from_ns(t_ns: int) -> Time:
    return Time(sec=int(t_ns // 1_000_000_000), nanosec=int(t_ns % 1_000_000_000))


def image_msg_to_numpy(msg) -> np.ndarray:
    """sensor_msgs/Image or CompressedImage (an rclpy message or a `rosbags` one read from a bag)
    -> uint8 RGB (H, W, 3) or gray (H, W)."""
    if not hasattr(msg, "encoding"):  # CompressedImage
        return decode_compressed(msg.format, msg.data)
    return decode_raw(msg.encoding, msg.height, msg.width, msg.step, msg.data,
                      bool(msg.is_bigendian))


def motion_image(msg) -> np.ndarray:
    """An image message, decoded only as finely as a motion signal needs (core.io.motion_sync
    shrinks it to SIGNAL_WIDTH_PX anyway): JPEG/PNG at half size in grey, which costs a fraction
    of a full decode on every frame of a live stream."""
    if hasattr(msg, "encoding"):
        return image_msg_to_numpy(msg)
    return decode_compressed(msg.format, msg.data, half_grey=True)


def numpy_to_image_msg(image: np.ndarray, encoding: str, t_ns: int, frame_id: str) -> Image:
    """uint8 RGB (H, W, 3) or gray (H, W) -> sensor_msgs/Image in rgb8, bgr8, mono8, mono16 or
    bayer_<pattern>8."""
    height, width, step, data = encode_raw(image, encoding)
    msg = Image(height=height, width=width, encoding=encoding, is_bigendian=0, step=step)
    msg.data = data
    msg.header.stamp = time_from_ns(t_ns)
    msg.header.frame_id = frame_id
    return msg


def numpy_to_compressed_msg(image: np.ndarray, fmt: str, t_ns: int,
                            frame_id: str) -> CompressedImage:
    """uint8 RGB (H, W, 3) or gray (H, W) -> sensor_msgs/CompressedImage (jpeg or png)."""
    msg = CompressedImage(format=fmt)
    msg.data = encode_compressed(image, fmt)
    msg.header.stamp = time_from_ns(t_ns)
    msg.header.frame_id = frame_id
    return msg


# x, y, z float32 and rgb packed into a float32's bytes (0x00RRGGBB): what RViz's PointCloud2
# display and PCL's PointXYZRGB read.
_CLOUD_DTYPE = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("rgb", "<u4")])


def point_cloud_msg(points_xyz: np.ndarray, colours_rgb: Optional[np.ndarray], frame_id: str,
                    t_ns: int) -> PointCloud2:
    """(N, 3) points in frame_id and (N, 3) uint8 RGB colours (None: grey) -> an unorganised
    sensor_msgs/PointCloud2 (fields x y z rgb)."""
    points = np.asarray(points_xyz, np.float64).reshape(-1, 3)
    rgb = (np.full((len(points), 3), 128, np.uint32) if colours_rgb is None
           else np.asarray(colours_rgb, np.uint32).reshape(-1, 3))
    cloud = np.empty(len(points), _CLOUD_DTYPE)
    cloud["x"], cloud["y"], cloud["z"] = points.T
    cloud["rgb"] = (rgb[:, 0] << 16) | (rgb[:, 1] << 8) | rgb[:, 2]
    msg = PointCloud2(height=1, width=len(points), is_bigendian=False,
                      point_step=_CLOUD_DTYPE.itemsize, row_step=_CLOUD_DTYPE.itemsize * len(points),
                      is_dense=True)
    msg.fields = [PointField(name=name, offset=_CLOUD_DTYPE.fields[name][1],
                             datatype=PointField.FLOAT32, count=1)
                  for name in ("x", "y", "z", "rgb")]
    msg.data = cloud.tobytes()
    msg.header.stamp = time_from_ns(t_ns)
    msg.header.frame_id = frame_id
    return msg


def point_cloud_to_numpy(msg: PointCloud2) -> tuple[np.ndarray, np.ndarray]:
    """A point_cloud_msg message -> ((N, 3) float points, (N, 3) uint8 RGB)."""
    cloud = np.frombuffer(bytes(msg.data), _CLOUD_DTYPE, count=msg.width * msg.height)
    rgb = np.column_stack([(cloud["rgb"] >> shift) & 0xFF for shift in (16, 8, 0)])
    return (np.column_stack([cloud["x"], cloud["y"], cloud["z"]]).astype(np.float64),
            rgb.astype(np.uint8))


def message_stamp_ns(msg) -> int:
    return stamp_ns(msg.header)


def camera_info_msg(name: str, intrinsics: CameraIntrinsics, frame_id: str, t_ns: int,
                    rectification=None, projection=None) -> CameraInfo:
    """CameraInfo of one calibrated camera in ROS conventions: K, D, and R = I, P = [K | 0], or a
    stereo pair's rectification R and projection P (core.products.stereo)."""
    info = ros_camera_info(name, intrinsics, rectification, projection)
    msg = CameraInfo(width=info["image_width"], height=info["image_height"],
                     distortion_model=info["distortion_model"])
    msg.k = [float(v) for v in info["camera_matrix"]["data"]]
    msg.d = [float(v) for v in info["distortion_coefficients"]["data"]]
    msg.r = [float(v) for v in info["rectification_matrix"]["data"]]
    msg.p = [float(v) for v in info["projection_matrix"]["data"]]
    msg.header.stamp = time_from_ns(t_ns)
    msg.header.frame_id = frame_id
    return msg


def transform_msg(parent_frame: str, child_frame: str, parent_from_child: np.ndarray,
                  t_ns: int) -> TransformStamped:
    """TransformStamped holding the 4x4 `parent_from_child` (child's pose in the parent frame)."""
    m = np.asarray(parent_from_child, dtype=np.float64)
    msg = TransformStamped()
    msg.header.stamp = time_from_ns(t_ns)
    msg.header.frame_id = parent_frame
    msg.child_frame_id = child_frame
    msg.transform.translation.x, msg.transform.translation.y, msg.transform.translation.z = (
        float(v) for v in m[:3, 3])
    qx, qy, qz, qw = Rotation.from_matrix(m[:3, :3]).as_quat()
    q = msg.transform.rotation
    q.x, q.y, q.z, q.w = float(qx), float(qy), float(qz), float(qw)
    return msg


def transform_to_matrix(msg: TransformStamped) -> np.ndarray:
    """TransformStamped -> 4x4 parent_from_child."""
    t, q = msg.transform.translation, msg.transform.rotation
    m = np.eye(4)
    m[:3, :3] = Rotation.from_quat([q.x, q.y, q.z, q.w]).as_matrix()
    m[:3, 3] = [t.x, t.y, t.z]
    return m


# REP-103 body axes (x forward, y left, z up) from a camera's optical axes (z forward, x right,
# y down), for a camera mounted level and looking forward along the body's x axis (REP-103's
# optical-frame convention, as every camera driver's <camera>_link -> <camera>_optical_frame).
BODY_FROM_OPTICAL = np.array([[0.0, 0.0, 1.0, 0.0],
                              [-1.0, 0.0, 0.0, 0.0],
                              [0.0, -1.0, 0.0, 0.0],
                              [0.0, 0.0, 0.0, 1.0]])


def frame_from_rig(rig_frame_axes: str) -> np.ndarray:
    """The published rig frame from the calibration's rig frame (the reference camera's optical
    frame): identity for 'optical', BODY_FROM_OPTICAL for 'body'."""
    return BODY_FROM_OPTICAL if rig_frame_axes == "body" else np.eye(4)


def rig_tf_message(rig: RigCalibration, rig_frame: str, optical_frames: dict[str, str],
                   t_ns: int, floor_frame: Optional[str] = None,
                   rig_frame_axes: str = "optical") -> TFMessage:
    """All cameras' extrinsics in one TFMessage: rig_frame -> optical_frames[name] for each
    calibrated camera (frame_from_cam = frame_from_rig @ inverse(cam_from_rig), rig_frame's
    axes as rig_frame_axes says); with floor_frame and a calibration that found its floor
    (core.products.floor), also floor_frame -> rig_frame."""
    published_from_rig = frame_from_rig(rig_frame_axes)
    transforms = [transform_msg(rig_frame, optical_frames[name], published_from_rig @ np.linalg.inv(
                      np.asarray(cam.cam_from_rig, dtype=np.float64)), t_ns)
                  for name, cam in rig.cameras.items()]
    floor = rig.quality.floor
    if floor_frame and floor:
        floor_from_rig = np.asarray(floor["floor_from_rig"], dtype=np.float64).reshape(4, 4)
        transforms.append(transform_msg(
            floor_frame, rig_frame, floor_from_rig @ np.linalg.inv(published_from_rig), t_ns))
    return TFMessage(transforms=transforms)
