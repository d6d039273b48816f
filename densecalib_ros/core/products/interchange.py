"""A rig calibration in the files other tools read.

- anipose / aniposelib `calibration.toml` (multi-camera animal pose: anipose, DeepLabCut 3D,
  freemocap): per camera `[cam_i]` with name, size [w, h], matrix (OpenCV pixel convention),
  distortions (OpenCV k1 k2 p1 p2 k3, or fisheye k1..k4 with `fisheye = true`), rotation
  (Rodrigues vector) and translation of cam_from_world; world = our rig frame, or the floor frame
  of a calibration that found one (calibrate --floor).
- Kalibr camchain YAML (read by OpenVINS, VINS-Fusion, ORB-SLAM3's converters, ...): per camera
  `camN` with pinhole intrinsics [fu, fv, pu, pv], radtan or equidistant distortion, resolution,
  rostopic, and T_cn_cnm1 (camN from cam(N-1)) for N >= 1.

- OpenCV FileStorage YAML, one `<camera>.yml` per camera (what OpenCV's calibration sample and
  tutorial write and OpenCV-based programs load with `fs["camera_matrix"]`): image_width,
  image_height, fisheye_model (0/1), camera_matrix, distortion_coefficients (k1 k2 p1 p2 k3
  [k4 k5 k6], or fisheye k1..k4), and R, T of cam_from_rig (x_cam = R x_rig + T, as
  stereoCalibrate's R, T from the first camera: for a stereo pair the second camera's R, T are
  the stereo extrinsics).
- DANNCE / Label3D (rodent 3D pose in arenas; MATLAB's camera model), one
  `hires_cam<i>_params.mat` per camera with K (MATLAB's IntrinsicMatrix: the transpose of
  OpenCV's, principal point + 1 for MATLAB's 1-based pixels), r and t (row vectors:
  x_cam = X_world r + t, so r = R' of cam_from_world; t in millimetres for a metric rig, as
  DANNCE's volumes are), RDistort [k1 k2 (k3)] and TDistort [p1 p2]; world as anipose's.
- JARVIS (JARVIS-MoCap's HybridNet, 3D pose in arenas), one OpenCV FileStorage `<camera>.yaml`
  per camera as its calibration folders hold them: intrinsicMatrix (the transpose of OpenCV's K,
  OpenCV's 0-based pixels), distortionCoefficients (k1 k2 p1 p2 k3; JARVIS's projection uses k1
  and k2), R and T (x_cam = X_world R + T on row vectors, so R = R' of cam_from_world; T in
  millimetres for a metric rig); world as anipose's. Taken from JARVIS's own loader
  (`jarvis/utils/reprojection.py`: cameraMatrix = ([R; T] intrinsicMatrix)').
- A stereo pair (core.products.stereo), for stereo matchers that work on rectified images:
  `ros-stereo`, the two camera_info YAMLs ROS's stereo calibrator writes (left.yaml, right.yaml:
  rectification_matrix R1/R2 and projection_matrix P1/P2, the right one with Tx = -fx' baseline),
  read by camera_info_manager and used by stereo_image_proc; `opencv-stereo`, one FileStorage file
  with K1 D1 K2 D2 (read back by --intrinsics LEFT,RIGHT=FILE), R T E F R1 R2 P1 P2 Q.

All take the camera parameters from core.io.camera_info.ros_camera_info (ROS = OpenCV conventions),
so the pixel convention and the distortion mapping live in one place. Translations are in the rig's
units: metres when a known baseline set the scale, else the reconstruction's arbitrary unit
(the files say which in a comment).
"""
from __future__ import annotations

import json
import re

import cv2
import numpy as np

from ..errors import InputError
from ..io.camera_info import camera_info_yaml, ros_camera_info, yaml_text
from ..types import RigCalibration
from .floor import world_from_rig
from .scale import HOW_TO_SCALE
from .stereo import StereoRectification

FORMATS = ("anipose", "kalibr", "opencv", "dannce", "jarvis", "ros-stereo", "opencv-stereo",
           "ply")  # ply: the cameras with the scene points (core.products.scene_ply)
# Formats written as a folder of files, one per camera, rather than one file
FOLDER_FORMATS = ("opencv", "dannce", "jarvis", "ros-stereo")
# Formats of one camera pair (core.products.stereo)
STEREO_FORMATS = ("ros-stereo", "opencv-stereo")
DEFAULT_TOPIC_PATTERN = "/{name}/image_raw"
# A ROS 2 topic name: /-separated tokens, none starting with a digit (no substitutions here)
_ROS_TOPIC = re.compile(r"^/?[A-Za-z_][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*$")


def _units(rig: RigCalibration) -> str:
    return "metres" if rig.metric_scale else \
        f"arbitrary SfM units (for metres: {HOW_TO_SCALE})"


def _lens(name: str, rig: RigCalibration, fmt: str) -> tuple[dict, list[float], bool]:
    """(ROS CameraInfo dict, distortion coefficients, fisheye?) of a camera, checked for fmt."""
    info = ros_camera_info(name, rig.cameras[name].intrinsics)
    dist = [float(d) for d in info["distortion_coefficients"]["data"]]
    model = info["distortion_model"]
    if model == "equidistant":
        return info, dist, True
    if fmt == "opencv" and model == "rational_polynomial":
        return info, dist, False  # cv::calibrateCamera's CALIB_RATIONAL_MODEL, 8 coefficients
    if model != "plumb_bob" or (fmt == "kalibr" and dist[4] != 0.0):
        raise InputError(f"Camera {name} ({rig.cameras[name].intrinsics.model}) has a lens model "
                         f"{fmt} cannot hold: it takes pinhole + radial-tangential "
                         f"({'k1 k2 p1 p2' if fmt == 'kalibr' else 'k1 k2 p1 p2 k3'})"
                         + ("." if fmt in ("dannce", "jarvis") else
                            " or equidistant fisheye."))
    return info, (dist[:4] if fmt == "kalibr" else dist), False


def _toml_list(values) -> str:
    return "[ " + ", ".join(repr(float(v)) for v in values) + ",]"


def _world(rig: RigCalibration) -> tuple[np.ndarray, str]:
    """(rig_from_world, its description) of the world frame of arena tools (floor.world_from_rig:
    the floor frame when the calibration has one, else the rig frame)."""
    world_from_rig_, world = world_from_rig(rig)
    return np.linalg.inv(world_from_rig_), world


def anipose_toml(rig: RigCalibration) -> str:
    """aniposelib CameraGroup.load() text (format in the module docstring), in _world."""
    rig_from_world, world = _world(rig)
    lines = [f"# densecalib rig calibration; world = {world}; translations in {_units(rig)}",
             ""]
    for i, name in enumerate(rig.cameras):
        info, dist, fisheye = _lens(name, rig, "anipose")
        k = np.asarray(info["camera_matrix"]["data"], float).reshape(3, 3)
        cam_from_world = np.asarray(rig.cameras[name].cam_from_rig, float) @ rig_from_world
        rvec = cv2.Rodrigues(cam_from_world[:3, :3])[0].ravel()
        lines += [f"[cam_{i}]", f"name = {json.dumps(name)}",
                  f"size = [ {info['image_width']}, {info['image_height']},]",
                  "matrix = [ " + ", ".join(_toml_list(row) for row in k) + ",]",
                  f"distortions = {_toml_list(dist)}",
                  f"rotation = {_toml_list(rvec)}",
                  f"translation = {_toml_list(cam_from_world[:3, 3])}"]
        if fisheye:
            lines.append("fisheye = true")
        lines.append("")
    rms = rig.quality.reprojection_rms_px
    lines += ["[metadata]", "adjusted = false",
              f"error = {float(rms) if rms is not None else 0.0!r}", ""]
    return "\n".join(lines)


def recorded_image_topics(rig: RigCalibration) -> dict[str, str]:
    """{camera: the image topic it was calibrated from}, for calibrations made from a bag or by
    the node (their provenance, core.io.export.record_provenance); {} for images and videos."""
    record = rig.quality.input or {}
    topics = record.get("topics") or []
    if record.get("source") == "bag":
        from ..io.bag import camera_names_from_topics
        return dict(zip(camera_names_from_topics(list(topics)), topics))
    if record.get("source") == "topics" and record.get("camera_names"):
        return dict(zip(record["camera_names"], topics))
    return {}


def kalibr_camchain_yaml(rig: RigCalibration,
                         topic_pattern: str = DEFAULT_TOPIC_PATTERN) -> str:
    """Kalibr camchain.yaml text (format in the module docstring); camN follow the rig's camera
    order, the reference camera first; rostopic = topic_pattern.format(name=camera name), or with
    the default pattern the topic the camera was calibrated from (recorded_image_topics)."""
    names = [rig.reference_camera] + [n for n in rig.cameras if n != rig.reference_camera]
    recorded = recorded_image_topics(rig) if topic_pattern == DEFAULT_TOPIC_PATTERN else {}
    try:
        topics = {n: recorded.get(n) or topic_pattern.format(name=n) for n in names}
    except (KeyError, IndexError, ValueError) as exc:
        raise InputError(f"--topic-pattern {topic_pattern!r} cannot be filled in ({exc!r}): "
                         "write {name} where the camera name goes, e.g. "
                         "/{name}/image_raw.") from None
    shared = sorted({t for t in topics.values() if list(topics.values()).count(t) > 1})
    if shared:
        raise InputError(f"--topic-pattern {topic_pattern!r} gives several cameras the topic "
                         f"{shared[0]!r}: Kalibr would read one camera's images for all of "
                         "them. Write {name} where the camera name goes, e.g. "
                         "/{name}/image_raw.")
    invalid = {n: t for n, t in topics.items() if not _ROS_TOPIC.match(t)}
    if invalid:
        raise InputError(
            "Kalibr reads the images from these topics, which are not valid ROS topic names "
            "(each part a letter or _ then letters, digits, _): " + ", ".join(
                f"{n}: {t!r}" for n, t in invalid.items()) + ". Give --topic-pattern with the "
            "topics the bag has, e.g. '/cam_{name}/image_raw' for cameras named by numbers.")
    chain, previous = {}, None
    for n, name in enumerate(names):
        info, dist, fisheye = _lens(name, rig, "kalibr")
        k = info["camera_matrix"]["data"]
        cam_from_rig = np.asarray(rig.cameras[name].cam_from_rig, float)
        entry = {"camera_model": "pinhole",
                 "intrinsics": [float(v) for v in (k[0], k[4], k[2], k[5])],
                 "distortion_model": "equidistant" if fisheye else "radtan",
                 "distortion_coeffs": [float(v) for v in dist],
                 "resolution": [int(info["image_width"]), int(info["image_height"])],
                 "rostopic": topics[name]}
        if previous is not None:
            entry["T_cn_cnm1"] = (cam_from_rig @ np.linalg.inv(previous)).tolist()
        chain[f"cam{n}"] = entry
        previous = cam_from_rig
    cameras = ", ".join(f"cam{n} = {name}" for n, name in enumerate(names))
    return f"# densecalib rig calibration; translations in {_units(rig)}; {cameras}\n" + \
        yaml_text(chain)


def opencv_files(rig: RigCalibration) -> dict[str, str]:
    """File name -> OpenCV FileStorage YAML text of each camera (format in the module
    docstring)."""
    out = {}
    for name, cam in rig.cameras.items():
        info, dist, fisheye = _lens(name, rig, "opencv")
        cam_from_rig = np.asarray(cam.cam_from_rig, dtype=np.float64)
        fs = cv2.FileStorage(f"{name}.yml", cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY)
        fs.writeComment(f"densecalib calibration of camera {name}; R, T: cam_from_rig (rig = "
                        f"the reference camera {rig.reference_camera}), T in {_units(rig)}")
        fs.write("camera_name", name)
        fs.write("image_width", int(info["image_width"]))
        fs.write("image_height", int(info["image_height"]))
        fs.write("fisheye_model", int(fisheye))
        fs.write("camera_matrix", np.asarray(info["camera_matrix"]["data"], float).reshape(3, 3))
        fs.write("distortion_coefficients", np.asarray(dist, dtype=np.float64).reshape(-1, 1))
        fs.write("reference_camera", rig.reference_camera)
        fs.write("R", cam_from_rig[:3, :3])
        fs.write("T", cam_from_rig[:3, 3].reshape(3, 1))
        out[f"{name}.yml"] = fs.releaseAndGetString()
    return out


def dannce_files(rig: RigCalibration) -> dict[str, bytes]:
    """File name -> MATLAB .mat bytes of each camera's `hires_cam<i>_params.mat` (i from 1 in the
    rig's camera order), as DANNCE and Label3D load them, plus `cameras.txt` naming the cameras
    (format in the module docstring)."""
    import io

    from scipy.io import savemat

    rig_from_world, world = _world(rig)
    to_file_units = 1000.0 if rig.metric_scale else 1.0  # DANNCE works in millimetres
    out, names = {}, []
    for i, name in enumerate(rig.cameras, start=1):
        info, dist, fisheye = _lens(name, rig, "dannce")
        _refuse_fisheye(name, fisheye, "DANNCE")
        k = np.asarray(info["camera_matrix"]["data"], float).reshape(3, 3)
        matlab_k = k.T.copy()
        matlab_k[2, :2] += 1.0  # MATLAB's top-left pixel centre is (1, 1), OpenCV's (0, 0)
        cam_from_world = np.asarray(rig.cameras[name].cam_from_rig, float) @ rig_from_world
        k1, k2, p1, p2, k3 = dist[:5]
        buffer = io.BytesIO()
        savemat(buffer, {"K": matlab_k, "r": cam_from_world[:3, :3].T,
                         "t": cam_from_world[:3, 3].reshape(1, 3) * to_file_units,
                         "RDistort": np.array([[k1, k2, k3]] if k3 else [[k1, k2]]),
                         "TDistort": np.array([[p1, p2]])})
        out[f"hires_cam{i}_params.mat"] = buffer.getvalue()
        names.append(f"hires_cam{i}_params.mat = Camera{i} = {name}")
    units = "millimetres" if rig.metric_scale else _units(rig)
    out["cameras.txt"] = ("\n".join([f"# densecalib rig calibration for DANNCE / Label3D; world = "
                                      f"{world}; t in {units}", *names]) + "\n").encode()
    return out


def _refuse_fisheye(name: str, fisheye: bool, tool: str) -> None:
    if fisheye:
        raise InputError(f"Camera {name} has a fisheye lens, which {tool}'s camera model cannot "
                         "hold: `densecalib undistort --videos` them to pinhole ones and export "
                         "that calibration.")


def jarvis_files(rig: RigCalibration) -> tuple[dict[str, str], list[str]]:
    """(file name -> JARVIS calibration YAML of each camera (format in the module docstring),
    the cameras whose p1, p2 or k3 JARVIS's projection leaves out)."""
    rig_from_world, world = _world(rig)
    to_file_units = 1000.0 if rig.metric_scale else 1.0  # JARVIS works in millimetres
    units = "millimetres" if rig.metric_scale else _units(rig)
    out, ignored = {}, []
    for name, cam in rig.cameras.items():
        info, dist, fisheye = _lens(name, rig, "jarvis")
        _refuse_fisheye(name, fisheye, "JARVIS")
        if any(abs(d) > 1e-12 for d in dist[2:5]):
            ignored.append(name)
        k = np.asarray(info["camera_matrix"]["data"], float).reshape(3, 3)
        cam_from_world = np.asarray(cam.cam_from_rig, float) @ rig_from_world
        fs = cv2.FileStorage(f"{name}.yaml", cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY)
        fs.writeComment(f"densecalib calibration of camera {name} for JARVIS; world = {world}; "
                        f"T in {units}")
        fs.write("intrinsicMatrix", k.T)
        fs.write("distortionCoefficients", np.asarray(dist[:5], np.float64).reshape(1, 5))
        fs.write("R", cam_from_world[:3, :3].T)
        fs.write("T", cam_from_world[:3, 3].reshape(3, 1) * to_file_units)
        out[f"{name}.yaml"] = fs.releaseAndGetString()
    return out, ignored


def ros_stereo_files(rig: RigCalibration, rect: StereoRectification) -> dict[str, str]:
    """File name -> camera_info YAML of the pair's two cameras with their rectification."""
    out = {}
    for name, rect_from_cam, projection in (
            (rect.left, rect.rect_from_left, rect.projection_left),
            (rect.right, rect.rect_from_right, rect.projection_right)):
        out[f"{name}.yaml"] = (
            f"# densecalib stereo pair {rect.left} (left) / {rect.right} (right); baseline "
            f"{rect.baseline:.6g} {_units(rig)}\n"
            + camera_info_yaml(name, rig.cameras[name].intrinsics, rect_from_cam, projection))
    return out


def opencv_stereo_yaml(rig: RigCalibration, rect: StereoRectification) -> str:
    """OpenCV FileStorage YAML of the pair: the stereo samples' K1 D1 K2 D2 R T E F R1 R2 P1 P2 Q
    (x_right = R x_left + T, E = [T]x R), plus the image size, fisheye_model and the camera
    names."""
    rot, t = rect.right_from_left[:3, :3], rect.right_from_left[:3, 3]
    tx = np.array([[0.0, -t[2], t[1]], [t[2], 0.0, -t[0]], [-t[1], t[0], 0.0]])
    essential = tx @ rot
    fs = cv2.FileStorage("stereo.yml", cv2.FILE_STORAGE_WRITE | cv2.FILE_STORAGE_MEMORY)
    fs.writeComment(f"densecalib stereo pair: K1 D1 = {rect.left} (left), K2 D2 = {rect.right} "
                    f"(right); x_right = R x_left + T; T and Q in {_units(rig)}")
    fs.write("left_camera", rect.left)
    fs.write("right_camera", rect.right)
    fs.write("image_width", rect.width)
    fs.write("image_height", rect.height)
    fs.write("fisheye_model", int(rect.fisheye))
    fs.write("K1", rect.k_left)
    fs.write("D1", rect.d_left.reshape(-1, 1))
    fs.write("K2", rect.k_right)
    fs.write("D2", rect.d_right.reshape(-1, 1))
    fs.write("R", rot)
    fs.write("T", t.reshape(3, 1))
    fs.write("E", essential)
    # F, as stereoCalibrate's, relates undistorted pixels (K times normalised coordinates)
    fs.write("F", np.linalg.inv(rect.k_right).T @ essential @ np.linalg.inv(rect.k_left))
    fs.write("R1", rect.rect_from_left)
    fs.write("R2", rect.rect_from_right)
    fs.write("P1", rect.projection_left)
    fs.write("P2", rect.projection_right)
    fs.write("Q", rect.disparity_to_depth)
    fs.write("baseline", rect.baseline)
    return fs.releaseAndGetString()


def export_text(rig: RigCalibration, fmt: str, **options) -> str:
    if fmt == "anipose":
        return anipose_toml(rig)
    if fmt == "kalibr":
        return kalibr_camchain_yaml(rig, **options)
    if fmt in FOLDER_FORMATS:
        raise InputError(f"Format {fmt} is a folder of files: use {fmt.replace('-', '_')}_files.")
    raise InputError(f"Unknown export format {fmt!r}: use one of {', '.join(FORMATS)}.")
