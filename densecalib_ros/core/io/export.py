"""A calibration's folder: calibration.json (the rig), camera_info YAML per camera
(core.io.camera_info), the COLMAP model and the reference views; reading it back, and what a new
calibration written over it replaces. Every write is atomic (core.io.safe_write)."""
from __future__ import annotations

import datetime
import json
import logging
import os
from pathlib import Path
from typing import Optional, Sequence

import numpy as np

from ..errors import InputError
from ..json_text import json_text, jsonable
from ..types import (CameraIntrinsics, CameraQuality, RigCalibration, RigCamera, RigQuality,
                     check_camera_names)
from .calibration_values import entry_problem, params_problem
from .camera_info import camera_info_yaml
from .colmap_files import model_problem
from .safe_write import disk_hint, write_text_atomic

log = logging.getLogger(__name__)

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
            for key in ("num_multiview_observations", "sfm_multiview_observations"):
                if getattr(cam.quality, key) is not None:
                    entry["quality"][key] = int(getattr(cam.quality, key))
            for key in ("focal_std_px", "principal_point_std_px", "projection_std_px",
                        "rotation_std_deg"):
                if getattr(cam.quality, key) is not None:
                    entry["quality"][key] = float(getattr(cam.quality, key))
            if cam.quality.estimated_intrinsics is not None:
                entry["quality"]["estimated_intrinsics"] = list(cam.quality.estimated_intrinsics)
            if cam.quality.principal_point_held is not None:
                entry["quality"]["principal_point_held"] = bool(cam.quality.principal_point_held)
        cams[name] = entry
    return {"reference_camera": rig.reference_camera, "cameras": cams,
            "failed_cameras": list(rig.failed_cameras), "metric_scale": bool(rig.metric_scale),
            "quality": jsonable(rig.quality.to_dict()), "conventions": FILE_CONVENTIONS}


def calibration_from_dict(data: dict, source: str = "") -> RigCalibration:
    """The calibration of a calibration.json's content; InputError naming `source` (the file)
    and what in it is of the wrong kind or no camera's (core.io.calibration_values)."""
    where = f" {source}" if source else ""
    try:
        cams = {}
        for name, c in data["cameras"].items():
            wrong = entry_problem(name, c)
            if wrong:
                raise InputError(f"A damaged calibration file{where}: {wrong}. Correct it, "
                                 "restore the file or calibrate again.")
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
                             quality=RigQuality.from_dict(data.get("quality", {})),
                             metric_scale=bool(data.get("metric_scale", False)))
    except (KeyError, TypeError, ValueError, AttributeError) as exc:
        raise InputError(f"Not a densecalib calibration file{where} ({exc!r}): expected keys "
                         "reference_camera and cameras{name: model, params, width, height, "
                         "cam_from_rig}.") from exc
    problem = calibration_problem(rig)
    if problem:
        raise InputError(f"A damaged calibration file{where}: {problem}. Correct it, restore "
                         "the file or calibrate again.")
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
        absurd = params_problem(name, k.width, k.height, k.parameter_names, k.params.tolist())
        if absurd:
            return absurd
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


def reference_views_of(calibration: str | Path, camera_names: Sequence[str]) -> dict:
    """The reference views beside a calibration given as a folder, a node's output_dir or its
    calibration.json ({} for a .json of another name: what lies beside it may be another's)."""
    from .reference_view_files import read_reference_views

    given = Path(calibration)
    if given.is_file() and given.name != "calibration.json":
        return {}
    return read_reference_views(calibration_folder(given), camera_names)


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
    return calibration_from_dict(data, str(path))


def record_provenance(rig: RigCalibration, source: dict) -> None:
    """Note in rig.quality what the calibration was made from (`source`: e.g. the image files of
    each frame set, the video times, or the bag's topics and stamps), by which densecalib version
    and when: a calibration file that says how to reproduce it."""
    from ... import __version__

    rig.quality.input = source
    rig.quality.densecalib_version = __version__
    rig.quality.calibrated_utc = datetime.datetime.now(datetime.timezone.utc).isoformat(
        timespec="seconds")


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
    problem = model_problem(model)  # before pycolmap allocates for what the files claim
    if problem is None:
        try:
            return pycolmap.Reconstruction(str(model))
        except (RuntimeError, ValueError, IndexError) as exc:  # pycolmap's read errors
            problem = str(exc).strip().splitlines()[-1] if str(exc).strip() else repr(exc)
    raise InputError(f"The COLMAP model in {model} is damaged ({problem}): calibrate again, or "
                     "restore the folder.")


def write_calibration_files(rig: RigCalibration, directory: str | os.PathLike,
                            reconstruction=None, reference_views: Optional[dict] = None) -> None:
    """Write calibration.json, <camera>.yaml per camera and (optionally) the COLMAP model under
    `directory`/colmap and the cameras' reference views (core.monitor.reference_views: {camera:
    image}) into `directory` (made if missing). Files of another calibration already there stay:
    give a new folder, or let core.io.calibration_store.write_new_calibration make one."""
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
    problem = model_problem(directory)  # a file cut short: pycolmap would read garbage counts
    try:
        if problem:
            raise InputError(problem)
        back = pycolmap.Reconstruction(str(directory))
        read = (back.num_cameras(), back.num_images(), back.num_points3D())
    except Exception as exc:  # pycolmap raises its own types for a damaged model
        read = f"nothing readable ({exc})"
    if read != written:
        raise InputError(f"Cannot write the COLMAP model {directory}: read back it holds "
                         f"{read} (cameras, images, points) of {written}. "
                         + disk_hint(directory))


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


def _calibration_file(path: Path, calibration: Path) -> bool:
    """Whether `path` is one of the files write_calibration_files wrote into `calibration`."""
    if path.parent == calibration:
        return path.name == "calibration.json" or (path.suffix == ".yaml" and path.exists())
    return any(calibration / sub in path.parents for sub in ("colmap", "reference_views"))


def check_output_files(paths: Sequence[str | os.PathLike],
                       calibration_dir: Optional[str | os.PathLike] = None,
                       input_dir: Optional[str | os.PathLike] = None) -> None:
    """Raise InputError when writing `paths` would lose data: an empty path, a path that is a
    folder (or ends with a separator), a file of the calibration being read or of another
    calibration folder (its calibration.json, camera_info YAMLs, COLMAP model, reference views:
    an export must not replace a calibration; other files beside them are fine, an earlier
    export's included), or any file in the input images' folder."""
    calibration = Path(calibration_dir).resolve() if calibration_dir is not None else None
    inputs = Path(input_dir).resolve() if input_dir is not None else None
    for given in paths:
        if not str(given).strip():
            raise InputError("The output path is empty (''): give a file or folder to write.")
        path = Path(given).resolve()
        if path.is_dir() or str(given).endswith(("/", os.sep)):
            said = "" if path.is_dir() else " (it ends with a separator)"
            raise InputError(f"{given} is a folder{said}: give the file to write (this writes "
                             "one file).")
        if calibration is not None and _calibration_file(path, calibration):
            raise InputError(f"{given} is a file of the calibration {calibration}: writing it "
                             "would replace what this command reads. Write somewhere else.")
        # another calibration's folder (its own files, or its COLMAP model's and reference views')
        for other in list(path.parents)[:3]:
            if (other / "calibration.json").is_file() and _calibration_file(path, other):
                raise InputError(f"{given} is a file of the calibration {other}: writing it "
                                 "would replace part of that calibration. Write somewhere else.")
        if inputs is not None and inputs in path.parents:
            raise InputError(f"{given} is in the input folder {inputs}: write somewhere else, "
                             "so that the inputs stay as they are.")

