"""A camera's intrinsics in ROS's and OpenCV's forms: the CameraInfo content (ros_camera_info),
camera_info YAML (camera_calibration_parsers' format) and OpenCV's K and D.

ROS conventions (REP 104 / image_pipeline): pixel centre of the top-left pixel at (0, 0), so
cx_ros = cx_colmap - 0.5; distortion model names plumb_bob (k1 k2 p1 p2 k3), rational_polynomial
(k1 k2 p1 p2 k3 k4 k5 k6), equidistant (k1 k2 k3 k4).
"""
from __future__ import annotations

from typing import Optional

import numpy as np

from ..errors import InputError
from ..types import CameraIntrinsics

# COLMAP model -> (ROS distortion model, function params -> (fx, fy, cx, cy, D list))
_PINHOLE_LIKE = {
    "SIMPLE_PINHOLE": ("plumb_bob", lambda p: (p[0], p[0], p[1], p[2], [0.0] * 5)),
    "PINHOLE": ("plumb_bob", lambda p: (p[0], p[1], p[2], p[3], [0.0] * 5)),
    "SIMPLE_RADIAL": ("plumb_bob", lambda p: (p[0], p[0], p[1], p[2], [p[3], 0.0, 0.0, 0.0, 0.0])),
    "RADIAL": ("plumb_bob", lambda p: (p[0], p[0], p[1], p[2], [p[3], p[4], 0.0, 0.0, 0.0])),
    "OPENCV": ("plumb_bob", lambda p: (p[0], p[1], p[2], p[3], [p[4], p[5], p[6], p[7], 0.0])),
    "FULL_OPENCV": ("rational_polynomial", lambda p: (p[0], p[1], p[2], p[3], list(p[4:12]))),
    "SIMPLE_RADIAL_FISHEYE": ("equidistant",
                              lambda p: (p[0], p[0], p[1], p[2], [p[3], 0.0, 0.0, 0.0])),
    "RADIAL_FISHEYE": ("equidistant", lambda p: (p[0], p[0], p[1], p[2], [p[3], p[4], 0.0, 0.0])),
    "OPENCV_FISHEYE": ("equidistant", lambda p: (p[0], p[1], p[2], p[3], list(p[4:8]))),
}


def ros_camera_info(name: str, intrinsics: CameraIntrinsics,
                    rectification: Optional[np.ndarray] = None,
                    projection: Optional[np.ndarray] = None) -> dict:
    """The CameraInfo content of one camera in ROS conventions (plain lists, row-major).
    rectification (3x3, rect_from_cam) and projection (3x4) are a stereo pair's
    (core.products.stereo); a lone camera gets the identity and P = [K | 0]."""
    model = intrinsics.model
    if model not in _PINHOLE_LIKE:
        raise InputError(f"Camera model {model} has no ROS CameraInfo equivalent: use one of "
                         f"{', '.join(sorted(_PINHOLE_LIKE))}.")
    ros_model, split = _PINHOLE_LIKE[model]
    fx, fy, cx, cy, dist = split([float(v) for v in intrinsics.params])
    if ros_model == "rational_polynomial" and not any(dist[5:]):
        ros_model, dist = "plumb_bob", dist[:5]  # k1 k2 p1 p2 k3 (a lab plumb_bob read back)
    cx, cy = cx - 0.5, cy - 0.5  # COLMAP -> ROS/OpenCV pixel convention
    k = [fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0]
    r = np.eye(3) if rectification is None else np.asarray(rectification, np.float64)
    p = (np.array([[fx, 0.0, cx, 0.0], [0.0, fy, cy, 0.0], [0.0, 0.0, 1.0, 0.0]])
         if projection is None else np.asarray(projection, np.float64))
    return {
        "image_width": int(intrinsics.width),
        "image_height": int(intrinsics.height),
        "camera_name": name,
        "camera_matrix": {"rows": 3, "cols": 3, "data": k},
        "distortion_model": ros_model,
        "distortion_coefficients": {"rows": 1, "cols": len(dist), "data": [float(d) for d in dist]},
        "rectification_matrix": {"rows": 3, "cols": 3,
                                 "data": [float(v) for v in r.reshape(-1)]},
        "projection_matrix": {"rows": 3, "cols": 4, "data": [float(v) for v in p.reshape(-1)]},
    }


def opencv_intrinsics(intrinsics: CameraIntrinsics) -> tuple[np.ndarray, np.ndarray, bool]:
    """(K 3x3, distortion coefficients, fisheye) in OpenCV's terms and pixel convention (top-left
    pixel centre at 0, 0): cv2.projectPoints, cv2.undistortPoints (or their cv2.fisheye versions
    when fisheye) take them as they are. InputError for a model OpenCV has no counterpart of."""
    info = ros_camera_info("", intrinsics)
    return (np.reshape(info["camera_matrix"]["data"], (3, 3)),
            np.asarray(info["distortion_coefficients"]["data"], dtype=np.float64),
            info["distortion_model"] == "equidistant")


def yaml_text(data: dict) -> str:
    """`data` as YAML by PyYAML (safe_dump), keys in their given order, lists of numbers in flow
    style ([1.0, 2.0]) as camera_calibration writes them; strings YAML would read as something
    else are quoted (a camera named 0003 would load as the integer 3, and no longer name its
    camera). PyYAML is imported here only: the core imports without it."""
    import yaml

    return yaml.safe_dump(data, sort_keys=False, default_flow_style=None, allow_unicode=True,
                          width=1000)  # one line per matrix, as camera_calibration's files


def camera_info_yaml(name: str, intrinsics: CameraIntrinsics,
                     rectification: Optional[np.ndarray] = None,
                     projection: Optional[np.ndarray] = None) -> str:
    """camera_info YAML text as written by camera_calibration / read by camera_info_manager
    (camera_calibration_parsers' keys, in its order; rectification, projection: see
    ros_camera_info)."""
    return yaml_text(ros_camera_info(name, intrinsics, rectification, projection))
