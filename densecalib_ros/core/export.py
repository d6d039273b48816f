"""Calibration files: calibration.json (rig), camera_info YAML per camera (ROS conventions), and the
ROS CameraInfo content of a camera. All writes are atomic; a directory of outputs is written to a
temporary sibling and renamed into place, so a failed run never leaves a half-written folder.

ROS conventions (REP 104 / image_pipeline): pixel centre of the top-left pixel at (0, 0), so
cx_ros = cx_colmap - 0.5; distortion model names plumb_bob (k1 k2 p1 p2 k3), rational_polynomial
(k1 k2 p1 p2 k3 k4 k5 k6), equidistant (k1 k2 k3 k4).
"""
from __future__ import annotations

import datetime
import functools
import json
import logging
import os
import re
import shutil
import tempfile
from pathlib import Path
from typing import Callable, Optional, Sequence

import numpy as np

from .errors import InputError
from .json_text import json_text, jsonable
from .types import (CameraIntrinsics, CameraQuality, RigCalibration, RigCamera,
                    check_camera_names)

log = logging.getLogger(__name__)

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


def opencv_intrinsics(intrinsics: CameraIntrinsics) -> tuple[np.ndarray, np.ndarray, bool]:
    """(K 3x3, distortion coefficients, fisheye) in OpenCV's terms and pixel convention (top-left
    pixel centre at 0, 0): cv2.projectPoints, cv2.undistortPoints (or their cv2.fisheye versions
    when fisheye) take them as they are. InputError for a model OpenCV has no counterpart of."""
    info = ros_camera_info("", intrinsics)
    return (np.reshape(info["camera_matrix"]["data"], (3, 3)),
            np.asarray(info["distortion_coefficients"]["data"], dtype=np.float64),
            info["distortion_model"] == "equidistant")


def _yaml_scalar(key: str, value: str) -> str:
    """`key: value` quoted where YAML would read the plain text as something else (a camera
    named 0003 would load as the integer 3, and no longer name its camera)."""
    import yaml

    return yaml.safe_dump({key: value}, default_flow_style=False, allow_unicode=True)


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
            + _yaml_scalar("camera_name", name) + mat("camera_matrix")
            + f"distortion_model: {info['distortion_model']}\n" + mat("distortion_coefficients")
            + mat("rectification_matrix") + mat("projection_matrix"))


# Written into every calibration.json so that a reader without our README reads it right
# (informational: calibration_from_dict ignores it).
FILE_CONVENTIONS = {
    "params": "COLMAP camera model parameters (model names COLMAP's) in COLMAP's pixel "
              "convention: the top-left pixel's centre is (0.5, 0.5), so cx and cy are 0.5 "
              "larger than OpenCV's and ROS's (the camera_info YAMLs beside this file are in "
              "OpenCV's)",
    "cam_from_rig": "4x4 row-major: x_cam = R x_rig + t; camera frame x right, y down, "
                    "z forward; the rig frame is reference_camera's",
    "units": "translations in metres when metric_scale is true, else in rig units (the "
             "scene's own, unknown scale)",
}


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
            if cam.quality.estimated_intrinsics is not None:
                entry["quality"]["estimated_intrinsics"] = list(cam.quality.estimated_intrinsics)
        cams[name] = entry
    return {"reference_camera": rig.reference_camera, "cameras": cams,
            "failed_cameras": list(rig.failed_cameras), "metric_scale": bool(rig.metric_scale),
            "quality": jsonable(rig.quality), "conventions": FILE_CONVENTIONS}


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
                quality=CameraQuality(**{k: float("nan") if v is None else v  # null: unmeasured
                                         for k, v in q.items()}) if q else None)
        rig = RigCalibration(reference_camera=data["reference_camera"], cameras=cams,
                             failed_cameras=list(data.get("failed_cameras", [])),
                             quality=dict(data.get("quality", {})),
                             metric_scale=bool(data.get("metric_scale", False)))
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise InputError(f"Not a densecalib calibration file ({exc!r}): expected keys "
                         "reference_camera and cameras{name: model, params, width, height, "
                         "cam_from_rig}.") from exc
    problem = calibration_problem(rig)
    if problem:
        raise InputError(f"A damaged calibration file: {problem}. Restore it or calibrate "
                         "again.")
    return rig


def calibration_problem(rig: RigCalibration) -> Optional[str]:
    """What makes a read calibration unusable (None: nothing): what hand edits or damage leave
    and every later step would trip over (NaN, a mirrored or skewed pose, a focal <= 0, a model
    pycolmap does not know or the wrong number of its parameters)."""
    import pycolmap

    if not rig.cameras:
        return "it has no cameras"
    try:
        check_camera_names(rig.cameras)
    except InputError as exc:
        return str(exc)
    if rig.reference_camera not in rig.cameras:
        return f"its reference camera {rig.reference_camera!r} is not among its cameras"
    for name, cam in rig.cameras.items():
        k = cam.intrinsics
        if k.width <= 0 or k.height <= 0:
            return f"camera {name} has image size {k.width}x{k.height}"
        try:
            model = getattr(pycolmap.CameraModelId, k.model)
            expected = len(pycolmap.Camera.create_from_model_id(1, model, 1.0, k.width,
                                                                k.height).params)
        except (AttributeError, TypeError):  # not a model name pycolmap has
            return f"camera {name} has model {k.model!r}, which COLMAP does not know"
        if k.params.shape != (expected,) or not np.isfinite(k.params).all():
            return (f"camera {name} ({k.model}) has params {k.params.tolist()}; the model takes "
                    f"{expected} finite numbers")
        focal = [k.params[i] for i, n in enumerate(k.parameter_names) if n in ("f", "fx", "fy")]
        if min(focal) <= 0:
            return f"camera {name} has focal length {min(focal):g} px"
        pose = cam.cam_from_rig
        rotation = pose[:3, :3]
        if (not np.isfinite(pose).all() or not np.allclose(pose[3], [0, 0, 0, 1])
                or not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-6)
                or np.linalg.det(rotation) < 0):
            return f"camera {name}'s cam_from_rig is not a rotation and translation"
    return None


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
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:  # ValueError: not UTF-8, not JSON
        raise InputError(f"Cannot read calibration file {path} ({type(exc).__name__}: {exc}): "
                         "it is not a calibration.json densecalib wrote, or it was damaged; "
                         "restore it or calibrate again.") from exc
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


def _umask() -> int:
    """The process umask, read without setting it (os.umask would, racing other threads)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("Umask:"):
                return int(line.split()[1], 8)
    except (OSError, ValueError):
        pass
    return 0o022


def _usual_mode(path: Path, directory: bool = False) -> int:
    """The mode an ordinary open()/mkdir would give `path` (its own when it exists): mkstemp and
    mkdtemp make owner-only files and folders, which drivers, camera_info_manager or colleagues
    running as another user could not read."""
    try:
        return path.stat().st_mode & 0o7777
    except OSError:
        return (0o777 if directory else 0o666) & ~_umask()


def write_text_atomic(path: str | os.PathLike, text: str | bytes) -> None:
    """Write `text` (or bytes) to a temporary sibling of path, then rename it into place: a
    reader never sees a half-written file."""
    path = Path(path)
    tmp = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        clean_leftovers(path.parent, lambda name: name == path.name)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.tmp.{os.getpid()}.", dir=path.parent)
        with os.fdopen(fd, "wb" if isinstance(text, bytes) else "w") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.chmod(tmp, _usual_mode(path))
        os.replace(tmp, path)
    except BaseException as exc:
        if tmp is not None:
            Path(tmp).unlink(missing_ok=True)
        if isinstance(exc, OSError):
            raise InputError(f"Cannot write {path}: {exc.strerror or exc}. "
                             + disk_hint(path.parent)) from exc
        raise


def write_calibration_json(rig: RigCalibration, directory: str | os.PathLike) -> Path:
    """(Re)write `directory`/calibration.json atomically; returns its path."""
    path = Path(directory) / "calibration.json"
    write_text_atomic(path, json_text(calibration_to_dict(rig)) + "\n")
    return path


def read_saved_model(folder: str | os.PathLike):
    """The pycolmap.Reconstruction that write_calibration_files saved in folder/colmap, or None
    when there is none (a dense matcher without keypoint matches writes no model)."""
    import pycolmap

    model = Path(folder) / "colmap"
    if not any((model / f"points3D.{ext}").is_file() for ext in ("bin", "txt")):
        return None
    problem = _binary_model_problem(model)
    if problem is None:
        try:
            return pycolmap.Reconstruction(str(model))
        except (RuntimeError, ValueError, IndexError) as exc:  # pycolmap's read errors
            problem = str(exc).strip().splitlines()[-1] if str(exc).strip() else repr(exc)
    raise InputError(f"The COLMAP model in {model} is damaged ({problem}): calibrate again, or "
                     "restore the folder.")


# The least bytes one record of each COLMAP binary file takes: a file that claims more records
# than its size holds is damaged, and pycolmap would allocate for the claim (a zero-byte
# points3D.bin took 17 GB and 106 s before failing).
_MIN_RECORD_BYTES = {"cameras.bin": 24, "images.bin": 73, "points3D.bin": 51, "rigs.bin": 1,
                     "frames.bin": 1}


def _binary_model_problem(model: Path) -> Optional[str]:
    for name, record_bytes in _MIN_RECORD_BYTES.items():
        path = model / name
        if not path.is_file():
            continue
        size = path.stat().st_size
        with open(path, "rb") as f:
            head = f.read(8)
        if len(head) < 8:
            return f"{name} holds {size} bytes"
        count = int.from_bytes(head, "little")
        if count * record_bytes > size - 8:
            return f"{name} claims {count} records in {size} bytes"
    return None


def write_calibration_files(rig: RigCalibration, directory: str | os.PathLike,
                            reconstruction=None, reference_views: Optional[dict] = None) -> None:
    """Write calibration.json, <camera>.yaml per camera and (optionally) the COLMAP model under
    `directory`/colmap and the cameras' reference views (core.reference_views: {camera: image})
    into `directory` (made if missing). Files of another calibration already there stay: give
    a new folder, or let core.calibration_store.write_new_calibration make one."""
    check_camera_names(rig.cameras)
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    write_calibration_json(rig, directory)
    for name, cam in rig.cameras.items():
        write_text_atomic(directory / f"{name}.yaml", camera_info_yaml(name, cam.intrinsics))
    if reconstruction is not None:
        write_colmap_model(reconstruction, directory / "colmap")
    if reference_views:
        from .reference_view_files import write_reference_views
        write_reference_views(directory, reference_views)


def write_colmap_model(reconstruction, directory: Path) -> None:
    """Write a COLMAP model into `directory` (made if missing) and read it back: pycolmap's
    writer returns normally when the disk fills, leaving a truncated model."""
    directory.mkdir(parents=True, exist_ok=True)
    reconstruction.write(str(directory))
    import pycolmap

    written = (reconstruction.num_cameras(), reconstruction.num_images(),
               reconstruction.num_points3D())
    try:
        back = pycolmap.Reconstruction(str(directory))
        read = (back.num_cameras(), back.num_images(), back.num_points3D())
    except Exception as exc:  # pycolmap raises its own types for a damaged model
        read = f"nothing readable ({exc})"
    if read != written:
        raise InputError(f"Cannot write the COLMAP model {directory}: read back it holds "
                         f"{read} (cameras, images, points) of {written}. "
                         + disk_hint(directory))


def disk_hint(path: Path) -> str:
    """What to check after a write failed: the disk's free space, if it can be told."""
    folder = next((p for p in [path, *path.parents] if p.exists()), None)
    try:
        free_mib = shutil.disk_usage(folder).free / 2**20
    except (OSError, TypeError):
        return "Check that the folder is writable and the disk has room."
    return (f"Check that the folder is writable and the disk has room ({free_mib:.0f} MiB free "
            f"on the disk holding {folder}).")


CALIBRATION_MARKERS = ("calibration.json",)  # what makes a folder a calibration's, to replace


def calibration_entries(folder: Path) -> set[str]:
    """The names write_calibration_files writes in `folder` for the calibration there (its
    cameras' YAML files read from its calibration.json; every YAML file when that does not
    read): what a new calibration written over it replaces."""
    names = {"calibration.json", "colmap", "reference_views"}
    try:
        cameras = json.loads((folder / "calibration.json").read_text(encoding="utf-8"))["cameras"]
        return names | {f"{name}.yaml" for name in cameras}
    except (OSError, ValueError, KeyError, TypeError):
        return names | {p.name for p in folder.glob("*.yaml")}


def check_output_folder(out_dir: str | os.PathLike, markers: Sequence[str],
                        inputs: Sequence[str | os.PathLike] = ()) -> Path:
    """The resolved out_dir, after making sure that replacing it as a whole loses nothing: raises
    InputError when it is empty (the current folder), a file, holds one of `inputs` (or is one),
    or is a folder with contents but none of `markers` (the files by which a command knows its
    own earlier output: calibration.json, sync.json). A user's own folder is never emptied."""
    if not str(out_dir).strip():
        raise InputError("The output folder is empty (''): give a folder to write, e.g. "
                         "--out calib.")
    out = Path(out_dir).resolve()
    if out.exists() and not out.is_dir():
        raise InputError(f"{out_dir} is a file, not a folder: give a new folder to write.")
    for given in inputs:
        source = Path(given).resolve()
        if source == out or out in source.parents:
            what = "is" if source == out else "holds"
            raise InputError(f"The output folder {out_dir} {what} the input {given}: writing "
                             f"it would replace the input. Give another folder, e.g. "
                             f"{out}_out.")
    if out.is_dir() and any(out.iterdir()) and not any((out / m).exists() for m in markers):
        raise InputError(f"{out_dir} exists and is not an earlier output of this command (no "
                         f"{' or '.join(markers)} in it): writing there would replace all it "
                         "holds. Give a new or empty folder, or remove this one first.")
    parent = next(p for p in out.parents if p.exists())  # the folder written into (swap)
    if not parent.is_dir() or not os.access(parent, os.W_OK | os.X_OK):
        raise InputError(f"Cannot write {out_dir}: {parent} is not a writable folder. Give a "
                         "folder you can write to.")
    return out


def _calibration_file(path: Path, calibration: Path) -> bool:
    """Whether `path` is one of the files write_calibration_files wrote into `calibration`."""
    if path.parent == calibration:
        return path.name == "calibration.json" or (path.suffix == ".yaml" and path.exists())
    return any(calibration / sub in path.parents for sub in ("colmap", "reference_views"))


def check_output_files(paths: Sequence[str | os.PathLike],
                       calibration_dir: Optional[str | os.PathLike] = None,
                       input_dir: Optional[str | os.PathLike] = None) -> None:
    """Raise InputError when writing `paths` would lose data: an empty path, a path that is a
    folder, a file of the calibration being read (its calibration.json, camera_info YAMLs,
    COLMAP model, reference views: an export must not replace what it reads; other files beside
    them are fine, an earlier export's included), or any file in the input images' folder."""
    calibration = Path(calibration_dir).resolve() if calibration_dir is not None else None
    inputs = Path(input_dir).resolve() if input_dir is not None else None
    for given in paths:
        if not str(given).strip():
            raise InputError("The output path is empty (''): give a file or folder to write.")
        path = Path(given).resolve()
        if path.is_dir():
            raise InputError(f"{given} is a folder: give the file to write (this writes one "
                             "file).")
        if calibration is not None and _calibration_file(path, calibration):
            raise InputError(f"{given} is a file of the calibration {calibration}: writing it "
                             "would replace what this command reads. Write somewhere else.")
        if inputs is not None and inputs in path.parents:
            raise InputError(f"{given} is in the input folder {inputs}: write somewhere else, "
                             "so that the inputs stay as they are.")


def replace_directory_atomic(build, out_dir: str | os.PathLike,
                             markers: Optional[Sequence[str]] = None,
                             inputs: Sequence[str | os.PathLike] = (),
                             owned: Optional[Callable[[Path], set]] = None) -> None:
    """Call build(tmp_dir) to fill a fresh temporary sibling of out_dir, then make it out_dir in
    one step: the two folders are exchanged atomically where the filesystem can (Linux
    renameat2), else renamed twice, and an old copy a kill left between the two renames is put
    back at the next run. If build raises, out_dir is untouched. With `markers`, out_dir is
    first checked to be safe to replace (check_output_folder; commands check before their work
    too, to fail early). With `owned(out_dir)`, the names in the old out_dir that the command
    writes: every other entry build did not write (an export, a user's notes) is copied into
    the new folder, and named once at WARNING."""
    if markers is not None:
        check_output_folder(out_dir, markers, inputs)
    out_dir = Path(out_dir).resolve()
    clean_leftovers(out_dir.parent, lambda name: name == out_dir.name)
    tmp, building, old = None, None, None
    try:
        out_dir.parent.mkdir(parents=True, exist_ok=True)
        tmp = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.tmp.{os.getpid()}.",
                                    dir=out_dir.parent))
        building = str(tmp)
        os.chmod(tmp, _usual_mode(out_dir, directory=True))
        build(tmp)
        if owned is not None and out_dir.is_dir():
            _carry_over(out_dir, tmp, owned(out_dir))
        if out_dir.exists() and _exchange(tmp, out_dir):
            old, tmp = tmp, None  # tmp now holds the previous folder
        else:
            if out_dir.exists():
                old = out_dir.with_name(f".{out_dir.name}.old.{os.getpid()}")
                os.replace(out_dir, old)
            os.replace(tmp, out_dir)
    except BaseException as exc:
        if old is not None and tmp is not None and not out_dir.exists():
            os.replace(old, out_dir)  # the second rename failed: the old folder goes back
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
        if isinstance(exc, OSError):
            raise InputError(f"Cannot write {out_dir}: {exc.strerror or exc}. "
                             + disk_hint(out_dir) + " Nothing was replaced.") from exc
        if isinstance(exc, InputError) and building and building in str(exc):
            # a file of the hidden temporary folder, named as the user knows it
            raise InputError(str(exc).replace(building, str(out_dir))
                             + " Nothing was replaced.") from exc
        raise
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


def _carry_over(old_dir: Path, new_dir: Path, owned: set) -> None:
    kept = []
    for entry in sorted(old_dir.iterdir()):
        if entry.name in owned or (new_dir / entry.name).exists():
            continue
        if entry.is_dir() and not entry.is_symlink():
            shutil.copytree(entry, new_dir / entry.name, symlinks=True)
        else:
            shutil.copy2(entry, new_dir / entry.name, follow_symlinks=False)
        kept.append(entry.name)
    if kept:
        log.warning("kept in %s what this command does not write: %s (files exported from the "
                    "earlier calibration follow it, not this one: export them again)",
                    old_dir, ", ".join(kept))


_RENAME_EXCHANGE = 2  # linux/fs.h


@functools.lru_cache(maxsize=1)
def _renameat2():
    """libc's renameat2, or None (not Linux, an old C library)."""
    import ctypes

    try:
        return ctypes.CDLL(None, use_errno=True).renameat2
    except (OSError, AttributeError):
        return None


def _exchange(a: Path, b: Path) -> bool:
    """Swap two paths atomically (renameat2 RENAME_EXCHANGE); False where the system or the
    filesystem cannot, so that the caller renames instead."""
    renameat2, at_fdcwd = _renameat2(), -100
    return renameat2 is not None and renameat2(at_fdcwd, os.fsencode(a), at_fdcwd,
                                               os.fsencode(b), _RENAME_EXCHANGE) == 0


# what a write killed part-way leaves beside its target: `.<name>.tmp.<pid>.<any>` (a folder or
# file being written) and `.<name>.old.<pid>` (a folder being replaced)
_LEFTOVER = re.compile(r"^\.(?P<name>.+)\.(?P<kind>tmp|old)\.(?P<pid>\d+)(\..*)?$")


def clean_leftovers(parent: Path, targets: Callable[[str], bool]) -> None:
    """Remove from `parent` what writes of the targets it names left when their process was
    killed (one no longer running); an old copy whose folder is missing (killed between two
    renames) is put back first. Said once at WARNING."""
    try:
        entries = list(parent.iterdir())
    except OSError:
        return
    done = []
    for entry in sorted(entries, key=lambda e: e.name):
        m = _LEFTOVER.match(entry.name)
        if not m or not targets(m["name"]) or _running(int(m["pid"])):
            continue
        target = parent / m["name"]
        try:
            if m["kind"] == "old" and not target.exists() and not target.is_symlink():
                os.replace(entry, target)
                done.append(f"put back {target} (a run was killed while replacing it)")
                continue
            if entry.is_dir() and not entry.is_symlink():
                shutil.rmtree(entry)
            else:
                entry.unlink()
            done.append(f"removed {entry.name}")
        except OSError:
            continue
    if done:
        log.warning("left by runs killed while writing in %s: %s", parent, "; ".join(done))


def _running(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's
        return True
    return True
