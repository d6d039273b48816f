"""Calibration files: calibration.json (rig), camera_info YAML per camera (ROS conventions), and the
ROS CameraInfo content of a camera. All writes are atomic; a directory of outputs is written to a
temporary sibling and renamed into place, so a failed run never leaves a half-written folder.

ROS conventions (REP 104 / image_pipeline): pixel centre of the top-left pixel at (0, 0), so
cx_ros = cx_colmap - 0.5; distortion model names plumb_bob (k1 k2 p1 p2 k3), rational_polynomial
(k1 k2 p1 p2 k3 k4 k5 k6), equidistant (k1 k2 k3 k4).
"""
from __future__ import annotations

import datetime
import json
import os
import shutil
import tempfile
from pathlib import Path
from typing import Optional

import numpy as np

from .errors import InputError
from .types import CameraIntrinsics, CameraQuality, RigCalibration, RigCamera

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
    rectification (3x3, rect_from_cam) and projection (3x4) are a stereo pair's (core.stereo);
    a lone camera gets the identity and P = [K | 0]."""
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


def camera_info_yaml(name: str, intrinsics: CameraIntrinsics,
                     rectification: Optional[np.ndarray] = None,
                     projection: Optional[np.ndarray] = None) -> str:
    """camera_info YAML text as written by camera_calibration / read by camera_info_manager
    (rectification, projection: see ros_camera_info)."""
    info = ros_camera_info(name, intrinsics, rectification, projection)

    def mat(key):
        m = info[key]
        data = ", ".join(repr(float(v)) for v in m["data"])
        return f"{key}:\n  rows: {m['rows']}\n  cols: {m['cols']}\n  data: [{data}]\n"

    return (f"image_width: {info['image_width']}\nimage_height: {info['image_height']}\n"
            f"camera_name: {name}\n" + mat("camera_matrix")
            + f"distortion_model: {info['distortion_model']}\n" + mat("distortion_coefficients")
            + mat("rectification_matrix") + mat("projection_matrix"))


def calibration_to_dict(rig: RigCalibration) -> dict:
    cams = {}
    for name, cam in rig.cameras.items():
        entry = {"model": cam.intrinsics.model,
                 "params": [float(v) for v in cam.intrinsics.params],
                 "width": int(cam.intrinsics.width), "height": int(cam.intrinsics.height),
                 "cam_from_rig": [float(v) for v in np.asarray(cam.cam_from_rig).reshape(-1)]}
        if cam.quality is not None:
            entry["quality"] = {"reprojection_rms_px": float(cam.quality.reprojection_rms_px),
                                "num_observations": int(cam.quality.num_observations),
                                "coverage": float(cam.quality.coverage)}
            if cam.quality.num_multiview_observations is not None:
                entry["quality"]["num_multiview_observations"] = int(
                    cam.quality.num_multiview_observations)
            for key in ("focal_std_px", "principal_point_std_px", "projection_std_px"):
                if getattr(cam.quality, key) is not None:
                    entry["quality"][key] = float(getattr(cam.quality, key))
        cams[name] = entry
    return {"reference_camera": rig.reference_camera, "cameras": cams,
            "failed_cameras": list(rig.failed_cameras), "metric_scale": bool(rig.metric_scale),
            "quality": _jsonable(rig.quality)}


def calibration_from_dict(data: dict) -> RigCalibration:
    try:
        cams = {}
        for name, c in data["cameras"].items():
            q = c.get("quality")
            cams[name] = RigCamera(
                name=name,
                intrinsics=CameraIntrinsics(c["model"], int(c["width"]), int(c["height"]),
                                            np.array(c["params"], dtype=np.float64)),
                cam_from_rig=np.array(c["cam_from_rig"], dtype=np.float64).reshape(4, 4),
                quality=CameraQuality(**q) if q else None)
        return RigCalibration(reference_camera=data["reference_camera"], cameras=cams,
                              failed_cameras=list(data.get("failed_cameras", [])),
                              quality=dict(data.get("quality", {})),
                              metric_scale=bool(data.get("metric_scale", False)))
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"Not a densecalib calibration file ({exc!r}): expected keys "
                         "reference_camera and cameras{name: model, params, width, height, "
                         "cam_from_rig}.") from exc


def calibration_folder(path: str | os.PathLike) -> Path:
    """The folder of a calibration: `path` itself, or a node output_dir's `latest`."""
    path = Path(path)
    if path.is_file():
        return path.parent
    latest = path / "latest"
    return latest if not (path / "calibration.json").exists() and \
        (latest / "calibration.json").exists() else path


def node_reload_hint(folder: Path) -> str:
    """For a calibration changed in a node's output_dir: how the running node publishes it."""
    if folder.name != "latest":
        return ""
    return ("; a densecalib_node running on this output_dir publishes it after `ros2 service "
            "call /densecalib_node/reload std_srvs/srv/Trigger` (or a restart)")


def read_calibration(path: str | os.PathLike) -> RigCalibration:
    """A calibration.json, or the one in a folder; a node's output_dir (calibrations in
    time-stamped folders) gives its `latest`."""
    path = Path(path)
    if path.is_dir():
        path = calibration_folder(path) / "calibration.json"
    try:
        data = json.loads(path.read_text())
    except (OSError, json.JSONDecodeError) as exc:
        raise InputError(f"Cannot read calibration file {path}: {exc}") from exc
    return calibration_from_dict(data)


def record_provenance(rig: RigCalibration, source: dict) -> None:
    """Note in rig.quality what the calibration was made from (`source`: e.g. the image files of
    each frame set, the video times, or the bag's topics and stamps), by which densecalib version
    and when: a calibration file that says how to reproduce it."""
    from .. import __version__

    rig.quality["input"] = source
    rig.quality["densecalib_version"] = __version__
    rig.quality["calibrated_utc"] = datetime.datetime.now(datetime.timezone.utc).isoformat(
        timespec="seconds")


def write_text_atomic(path: str | os.PathLike, text: str | bytes) -> None:
    """Write `text` (or bytes) to a temporary sibling of path, then rename it into place: a
    reader never sees a half-written file."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "wb" if isinstance(text, bytes) else "w") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def write_calibration_json(rig: RigCalibration, directory: str | os.PathLike) -> Path:
    """(Re)write `directory`/calibration.json atomically; returns its path."""
    path = Path(directory) / "calibration.json"
    write_text_atomic(path, json.dumps(calibration_to_dict(rig), indent=2) + "\n")
    return path


def read_saved_model(folder: str | os.PathLike):
    """The pycolmap.Reconstruction that write_calibration_files saved in folder/colmap, or None
    when there is none (a dense matcher without keypoint matches writes no model)."""
    import pycolmap

    model = Path(folder) / "colmap"
    if not any((model / f"points3D.{ext}").is_file() for ext in ("bin", "txt")):
        return None
    return pycolmap.Reconstruction(str(model))


def write_calibration_files(rig: RigCalibration, directory: Path, reconstruction=None,
                            reference_views: Optional[dict] = None) -> None:
    """Write calibration.json, <camera>.yaml per camera and (optionally) the COLMAP model under
    `directory`/colmap and the cameras' reference views (core.reference_views: {camera: image})
    into `directory`, which must not exist yet or is replaced as a whole."""
    directory.mkdir(parents=True, exist_ok=True)
    write_calibration_json(rig, directory)
    for name, cam in rig.cameras.items():
        write_text_atomic(directory / f"{name}.yaml", camera_info_yaml(name, cam.intrinsics))
    if reconstruction is not None:
        (directory / "colmap").mkdir(exist_ok=True)
        reconstruction.write(str(directory / "colmap"))
    if reference_views:
        from .reference_views import write_reference_views
        write_reference_views(directory, reference_views)


def replace_directory_atomic(build, out_dir: str | os.PathLike) -> None:
    """Call build(tmp_dir) to fill a fresh temporary sibling of out_dir, then swap it into place.
    If build raises, out_dir is untouched."""
    out_dir = Path(out_dir).resolve()
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.tmp.", dir=out_dir.parent))
    try:
        build(tmp)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    old = None
    if out_dir.exists():
        old = out_dir.with_name(f".{out_dir.name}.old.{os.getpid()}")
        os.replace(out_dir, old)
    os.replace(tmp, out_dir)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


def _jsonable(value):
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.generic):
        return value.item()
    return value
