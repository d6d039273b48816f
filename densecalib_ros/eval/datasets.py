"""Loaders of image sets with reference cameras, in the core's conventions, for evaluation.

Every loader returns a `Scene`: one frame set per time step (`frame_sets[t][c]`, (H, W, 3) uint8
RGB), the camera names, and the reference calibration as a RigCalibration (COLMAP models and pixels,
rig frame = first camera) plus cam_from_world per camera.
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import cv2
import numpy as np

from ..core.errors import InputError
from ..core.types import CameraIntrinsics, RigCalibration, RigCamera

_FISHEYE_MODELS = {"OPENCV_FISHEYE", "RADIAL_FISHEYE", "SIMPLE_RADIAL_FISHEYE", "FOV",
                   "THIN_PRISM_FISHEYE", "RAD_TAN_THIN_PRISM_FISHEYE"}


@dataclass
class Scene:
    """An evaluation scene: images of one rig and its reference calibration."""

    name: str
    camera_names: list[str]
    frame_sets: list[list[np.ndarray]]  # [time step][camera] (H, W, 3) uint8 RGB
    gt: RigCalibration  # cam_from_rig with rig = camera_names[0]
    gt_cam_from_world: dict[str, np.ndarray] = field(default_factory=dict)  # name -> 4x4
    lens: str = "pinhole"  # "pinhole" | "fisheye" | "mixed": picks the preset / peer camera model
    camera_lens: dict = field(default_factory=dict)  # "mixed": camera name -> "pinhole" | "fisheye"
    reference_is_estimate: bool = False  # True when the "ground truth" is itself an SfM result
    share_intrinsics: bool = False  # one physical camera: calibrate with shared intrinsics
    notes: str = ""


def rig_from_cam_from_world(cameras: dict[str, CameraIntrinsics],
                            cam_from_world: dict[str, np.ndarray],
                            reference: Optional[str] = None) -> RigCalibration:
    """RigCalibration whose rig frame is `reference` (default: first camera):
    cam_from_rig = cam_from_world @ inv(reference_from_world)."""
    reference = reference or next(iter(cameras))
    world_from_ref = np.linalg.inv(np.asarray(cam_from_world[reference], float))
    return RigCalibration(reference, {
        n: RigCamera(n, cam, np.asarray(cam_from_world[n], float) @ world_from_ref)
        for n, cam in cameras.items()})


def default_data_dir() -> Path:
    """$DENSECALIB_DATA, else ../shared/data beside the repository checkout."""
    env = os.environ.get("DENSECALIB_DATA")
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[3] / "shared" / "data"


def _cam_from_world(rotation, translation=None, centre=None) -> np.ndarray:
    """4x4 cam_from_world of a world -> camera rotation and either its translation or the
    camera's centre in the world (translation = -R centre); the rotation snapped to the nearest
    one (reference files print it to a few digits), so that poses stay rigid."""
    u, _, vt = np.linalg.svd(np.asarray(rotation, float))
    pose = np.eye(4)
    pose[:3, :3] = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
    pose[:3, 3] = (np.asarray(translation, float) if centre is None
                   else -pose[:3, :3] @ np.asarray(centre, float))
    return pose


def _downscaled_size(width: int, height: int, max_side_px: Optional[int]) -> tuple[int, int]:
    """(w, h) with the long side at most max_side_px (None: unchanged), aspect kept."""
    if not max_side_px or max(width, height) <= max_side_px:
        return width, height
    s = max_side_px / max(width, height)
    return int(round(width * s)), int(round(height * s))


def _read_rgb(path: Path) -> np.ndarray:
    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if bgr is None:
        raise InputError(f"Cannot read image {path}: check that it exists and is a valid image.")
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def _read_strecha_camera(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, int, int]:
    """K (3x3), radial distortion (3,), R camera-to-world (3x3), centre C (3,), width, height."""
    values = np.array(path.read_text().split(), dtype=np.float64)
    if values.size != 26:
        raise InputError(f"{path}: expected 26 numbers in a Strecha .camera file, got {values.size}.")
    k, dist, r, c = values[:9].reshape(3, 3), values[9:12], values[12:21].reshape(3, 3), values[21:24]
    return k, dist, r, c, int(values[24]), int(values[25])


def load_strecha(directory: str | os.PathLike, max_side_px: Optional[int] = 1024,
                 name: Optional[str] = None) -> Scene:
    """A Strecha multi-view set (e.g. entry-P10): `images/NNNN.jpg` + `gt_dense_cameras/NNNN.jpg.camera`.

    The `.camera` files give K, radial distortion (zero: the images are undistorted), R
    (camera-to-world rotation), C (centre, metres) and the image size, with P = K [R^T | -R^T C].
    So cam_from_world = [R^T | -R^T C].

    Pixel convention (assumed): Strecha's K puts the centre of the top-left pixel at (0, 0), as in
    OpenCV and openMVG (which loads these files unchanged); COLMAP's principal point is therefore
    cx + 0.5, cy + 0.5. The assumption moves the principal point by 0.5 px at full size (0.02 % of
    the focal length). Checked on 3 pairs at full size: the GT epipolar distance of SIFT matches has
    a median of 0.13-0.32 px under this assumption, and is larger in all three when K is taken as
    COLMAP's unchanged.

    Images are downscaled with area averaging so the long side is at most `max_side_px` (None = full
    size); K scales per axis by new/old size, which is exact in COLMAP's convention (the image edges
    0 and W map to 0 and W'). Reference model: PINHOLE (fx, fy, cx, cy), one camera per image.
    """
    root = Path(directory)
    cam_files = sorted((root / "gt_dense_cameras").glob("*.camera"))
    if not cam_files:
        raise InputError(f"No Strecha .camera files under {root / 'gt_dense_cameras'}: point the "
                         "loader at a folder holding images/ and gt_dense_cameras/.")
    names, frame, cameras, cam_from_world = [], [], {}, {}
    for cam_file in cam_files:
        image_name = cam_file.name[: -len(".camera")]
        k, dist, r, c, width, height = _read_strecha_camera(cam_file)
        if np.any(dist != 0):
            raise InputError(f"{cam_file}: non-zero distortion {dist}; only undistorted Strecha "
                             "sets are supported.")
        image = _read_rgb(root / "images" / image_name)
        if image.shape[:2] != (height, width):
            raise InputError(f"{image_name}: image is {image.shape[1]}x{image.shape[0]} but its "
                             f"camera file says {width}x{height}.")
        new_w, new_h = _downscaled_size(width, height, max_side_px)
        if (new_w, new_h) != (width, height):
            image = cv2.resize(image, (new_w, new_h), interpolation=cv2.INTER_AREA)
        sx, sy = new_w / width, new_h / height
        params = np.array([k[0, 0] * sx, k[1, 1] * sy, (k[0, 2] + 0.5) * sx, (k[1, 2] + 0.5) * sy])
        cam = Path(image_name).stem
        names.append(cam)
        frame.append(np.ascontiguousarray(image))
        cameras[cam] = CameraIntrinsics("PINHOLE", new_w, new_h, params)
        # The files print R with 6 digits (_cam_from_world snaps it).
        cam_from_world[cam] = _cam_from_world(r.T, centre=c)
    return Scene(name=name or root.name, camera_names=names, frame_sets=[frame],
                 gt=rig_from_cam_from_world(cameras, cam_from_world),
                 gt_cam_from_world=cam_from_world, lens="pinhole",
                 notes="Strecha et al. 2008 reference cameras (targets + LiDAR), one camera moved "
                       "between shots; undistorted images.")


def load_nerf_transforms(directory: str | os.PathLike, num_views: int = 6,
                         max_side_px: Optional[int] = 1024, name: Optional[str] = None) -> Scene:
    """`num_views` evenly spaced frames of a NeRF / instant-ngp capture (`transforms.json` with
    shared fl_x, fl_y, cx, cy, k1, k2, p1, p2, w, h and a camera-to-world `transform_matrix` per
    frame, OpenGL axes: x right, y up, z backwards), as a rig of one camera per frame.

    cam_from_world = inv(c2w @ diag(1, -1, -1, 1)) (OpenGL to OpenCV axes). Frames whose image is
    missing are skipped (instant-ngp's fox lists 67 frames and ships 50). Reference model: OPENCV;
    cx, cy are taken as OpenCV's (pixel centre at 0), so COLMAP's are +0.5; intrinsics scale with
    the downscaled image as in load_strecha. The poses are themselves an SfM estimate (COLMAP on
    all frames), so the reference is an estimate too.
    """
    root = Path(directory)
    path = root / "transforms.json"
    if not path.is_file():
        raise InputError(f"No transforms.json in {root}: point the loader at a NeRF capture folder.")
    meta = json.loads(path.read_text())
    frames = [f for f in sorted(meta["frames"], key=lambda f: f["file_path"])
              if (root / f["file_path"]).is_file()]
    if len(frames) < num_views:
        raise InputError(f"{root}: {len(frames)} frames with images, {num_views} needed.")
    pick = [frames[int(k)] for k in np.linspace(0, len(frames) - 1, num_views).round()]
    width, height = int(meta["w"]), int(meta["h"])
    new_w, new_h = _downscaled_size(width, height, max_side_px)
    sx, sy = new_w / width, new_h / height
    params = np.array([meta["fl_x"] * sx, meta["fl_y"] * sy, (meta["cx"] + 0.5) * sx,
                       (meta["cy"] + 0.5) * sy, meta.get("k1", 0.0), meta.get("k2", 0.0),
                       meta.get("p1", 0.0), meta.get("p2", 0.0)])
    names, frame, cameras, cam_from_world = [], [], {}, {}
    for f in pick:
        image = _read_rgb(root / f["file_path"])
        if image.shape[:2] != (height, width):
            raise InputError(f"{f['file_path']}: image is {image.shape[1]}x{image.shape[0]}, "
                             f"transforms.json says {width}x{height}.")
        if (new_w, new_h) != (width, height):
            image = cv2.resize(image, (new_w, new_h), interpolation=cv2.INTER_AREA)
        cam = Path(f["file_path"]).stem
        names.append(cam)
        frame.append(np.ascontiguousarray(image))
        cameras[cam] = CameraIntrinsics("OPENCV", new_w, new_h, params.copy())
        opengl_c2w = np.asarray(f["transform_matrix"], dtype=np.float64)
        cam_from_world[cam] = np.linalg.inv(opengl_c2w @ np.diag([1.0, -1.0, -1.0, 1.0]))
    return Scene(name=name or root.name, camera_names=names, frame_sets=[frame],
                 gt=rig_from_cam_from_world(cameras, cam_from_world),
                 gt_cam_from_world=cam_from_world, lens="pinhole", reference_is_estimate=True,
                 notes=f"{num_views} of the capture's frames (one phone camera walked around the "
                       "object); reference = the capture's own SfM poses and intrinsics.")


def _lenses(models: dict[str, str]) -> tuple[str, dict]:
    """(lens of the scene, {camera: lens} where the cameras mix lenses, else {})."""
    per_camera = {n: "fisheye" if m in _FISHEYE_MODELS else "pinhole" for n, m in models.items()}
    kinds = set(per_camera.values())
    return (kinds.pop(), {}) if len(kinds) == 1 else ("mixed", per_camera)


def scene_from_synthetic(rig, name: str) -> Scene:
    """A Scene of a generated rig (core.synthetic.SyntheticRig): exact ground truth."""
    lens, camera_lens = _lenses({n: cam.model for n, cam in zip(rig.names, rig.cameras)})
    return Scene(name=name, camera_names=list(rig.names),
                 frame_sets=[list(frame) for frame in rig.images], gt=rig.ground_truth(),
                 gt_cam_from_world=dict(zip(rig.names, rig.cam_from_world)),
                 lens=lens, camera_lens=camera_lens, notes="generated rig, exact ground truth")


def load_generated(directory: str | os.PathLike, name: Optional[str] = None) -> Scene:
    """A folder written by `densecalib generate` (core.synthetic.write_rig):
    <camera>/<t:04d>.png per camera and time step, and ground_truth.json."""
    from ..core.synthetic import read_ground_truth

    root = Path(directory)
    gt, cam_from_world = read_ground_truth(root)
    names = list(gt.cameras)
    steps = sorted(p.name for p in (root / names[0]).glob("*.png"))
    if not steps:
        raise InputError(f"No images under {root / names[0]}: expected <camera>/<t:04d>.png.")
    frame_sets = [[_read_rgb(root / n / step) for n in names] for step in steps]
    lens, camera_lens = _lenses({n: c.intrinsics.model for n, c in gt.cameras.items()})
    return Scene(name=name or root.name, camera_names=names, frame_sets=frame_sets, gt=gt,
                 gt_cam_from_world=cam_from_world, lens=lens, camera_lens=camera_lens,
                 notes="generated rig, exact ground truth")


def load_caliscope(directory: str | os.PathLike, num_sets: int = 8,
                   name: Optional[str] = None) -> Scene:
    """Caliscope's session of four webcams in a room (`calibration/extrinsic/cam_N.mp4` and
    `camera_array.toml`): `num_sets` frame sets at evenly spaced times, read as `densecalib
    calibrate --videos` reads them (core.io.video_io), at full size.

    Reference (ChArUco bundle adjustment, Caliscope): per `[cameras.N]` an OpenCV K (`matrix`;
    pixel centre at 0, so COLMAP's principal point is +0.5), `distortions` k1, k2, p1, p2, k3 (as
    FULL_OPENCV) and `rotation`, `translation` (m) from world to camera: cam_from_world =
    [rotation | translation]. A target-based estimate, not independent ground truth.
    """
    import tomllib

    from ..core.io.video_io import read_video_frame_sets

    root = Path(directory)
    videos = root / "calibration" / "extrinsic"
    array_file = root / "camera_array.toml"
    if not array_file.is_file() or not videos.is_dir():
        raise InputError(f"No Caliscope session in {root}: expected camera_array.toml and "
                         "calibration/extrinsic/cam_N.mp4.")
    table = tomllib.loads(array_file.read_text())["cameras"]
    frame_sets, names, _ = read_video_frame_sets(videos, num_sets)
    cameras, cam_from_world = {}, {}
    for cam in names:
        entry = table[cam.removeprefix("cam_")]
        width, height = (int(v) for v in entry["size"])
        k = np.asarray(entry["matrix"], float)
        k1, k2, p1, p2, k3 = (float(v) for v in entry["distortions"])
        cameras[cam] = CameraIntrinsics("FULL_OPENCV", width, height, np.array(
            [k[0, 0], k[1, 1], k[0, 2] + 0.5, k[1, 2] + 0.5, k1, k2, p1, p2, k3, 0.0, 0.0, 0.0]))
        cam_from_world[cam] = _cam_from_world(entry["rotation"], entry["translation"])
    return Scene(name=name or root.name, camera_names=names, frame_sets=frame_sets,
                 gt=rig_from_cam_from_world(cameras, cam_from_world),
                 gt_cam_from_world=cam_from_world, lens="pinhole",
                 notes="4 webcams in a furnished room, a person moving a board (57 frames); "
                       "reference = Caliscope's ChArUco bundle adjustment.")


def _read_krtd(path: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """K (3x3), R (3x3), T (3,) world -> camera, distortion coefficients of a KRTD file."""
    values = [float(v) for v in path.read_text().split()]
    if len(values) < 15:
        raise InputError(f"{path}: expected K, R, T (and D) in a KRTD file, got {len(values)} "
                         "numbers.")
    return (np.array(values[:9]).reshape(3, 3), np.array(values[9:18]).reshape(3, 3),
            np.array(values[18:21]), np.array(values[21:]))


def load_krtd_stills(directory: str | os.PathLike, name: Optional[str] = None) -> Scene:
    """One still per camera (`frames/<camera>.png`) with a KWIVER/TeleSculptor model each
    (`cameras/<camera>.krtd`: x = K distort(R X + T), D = k1, k2[, p1, p2]): MEVA's surveillance
    cameras. K's principal point is OpenCV's (pixel centre at 0: COLMAP's is +0.5). Images at
    full size (their heights may differ). Reference model: OPENCV. The references are a bundle
    adjustment on hand-annotated landmarks, not independent ground truth."""
    root = Path(directory)
    krtd_files = sorted((root / "cameras").glob("*.krtd"))
    krtd_files = [p for p in krtd_files if (root / "frames" / f"{p.stem}.png").is_file()]
    if len(krtd_files) < 2:
        raise InputError(f"{root}: fewer than two cameras/<name>.krtd with frames/<name>.png.")
    names, frame, cameras, cam_from_world = [], [], {}, {}
    for path in krtd_files:
        k, r, t, d = _read_krtd(path)
        image = _read_rgb(root / "frames" / f"{path.stem}.png")
        height, width = image.shape[:2]
        dist = np.zeros(4)
        dist[:min(4, d.size)] = d[:4]
        names.append(path.stem)
        frame.append(np.ascontiguousarray(image))
        cameras[path.stem] = CameraIntrinsics("OPENCV", width, height, np.array(
            [k[0, 0], k[1, 1], k[0, 2] + 0.5, k[1, 2] + 0.5, *dist]))
        cam_from_world[path.stem] = _cam_from_world(r, t)
    return Scene(name=name or root.name, camera_names=names, frame_sets=[frame],
                 gt=rig_from_cam_from_world(cameras, cam_from_world),
                 gt_cam_from_world=cam_from_world, lens="pinhole", reference_is_estimate=True,
                 notes="stills of outdoor surveillance cameras 10-230 m apart, long lenses, "
                       "partial overlap; reference = a bundle adjustment on annotated landmarks.")


def load_qualisys_videos(directory: str | os.PathLike, num_sets: int = 8,
                         name: Optional[str] = None) -> Scene:
    """Pose2Sim's demo ring (`videos/camNN.mp4`, `calibration/Calib.qca.txt`, a Qualisys QTM
    wand calibration): `num_sets` frame sets read as `calibrate --videos` reads them.

    Per `<camera serial>`: `<intrinsic>` focal lengths and principal point in 1/64 px of the
    `<fov_video>` window (its left/top subtracted), k1, k2, p1, p2 as OpenCV's (raw; the set's
    notes find them more likely than Pose2Sim's division by 64); `<transform>` the camera centre
    (mm) and M, whose rows are the camera's axes in the world with y up and -z forward:
    cam_from_world = [diag(1, -1, -1) M | -diag(1, -1, -1) M C]. A video narrower than the window
    is the window scaled to its width and letterboxed (the set's cam01, cam02: 1088 -> 1080 px,
    7 rows at top and bottom): K follows the scale and the letterbox's offset, in COLMAP's pixel
    convention (OpenCV's + 0.5). A reference of its own kind, not independent ground truth.
    """
    import xml.etree.ElementTree as ElementTree

    from ..core.io.video_io import read_video_frame_sets

    root = Path(directory)
    qca = root / "calibration" / "Calib.qca.txt"
    if not qca.is_file() or not (root / "videos").is_dir():
        raise InputError(f"No Qualisys calibration in {root}: expected "
                         "calibration/Calib.qca.txt and videos/<camera>.mp4.")
    entries = {c.get("serial"): c for c in ElementTree.parse(qca).getroot().iter("camera")}
    frame_sets, names, _ = read_video_frame_sets(root / "videos", num_sets)
    cameras, cam_from_world = {}, {}
    for c, cam in enumerate(names):
        if cam not in entries:
            raise InputError(f"{qca}: no camera with serial {cam!r} for videos/{cam}.*")
        entry = entries[cam]
        window, intr, pose = (entry.find(k).attrib for k in ("fov_video", "intrinsic",
                                                             "transform"))
        window_w = float(window["right"]) - float(window["left"]) + 1
        window_h = float(window["bottom"]) - float(window["top"]) + 1
        height, width = frame_sets[0][c].shape[:2]
        scale = width / window_w
        offset_y = (height - window_h * scale) / 2  # the letterbox's rows above the image
        cx = float(intr["centerPointU"]) / 64 - float(window["left"]) + 0.5  # COLMAP px
        cy = float(intr["centerPointV"]) / 64 - float(window["top"]) + 0.5
        cameras[cam] = CameraIntrinsics("OPENCV", width, height, np.array([
            float(intr["focalLengthU"]) / 64 * scale, float(intr["focalLengthV"]) / 64 * scale,
            cx * scale, cy * scale + offset_y, float(intr["radialDistortion1"]),
            float(intr["radialDistortion2"]), float(intr["tangentalDistortion1"]),
            float(intr["tangentalDistortion2"])]))
        m = np.array([[float(pose[f"r{i}{j}"]) for j in (1, 2, 3)] for i in (1, 2, 3)])
        rotation = np.diag([1.0, -1.0, -1.0]) @ m
        centre_m = np.array([float(pose[k]) for k in "xyz"]) / 1000.0
        cam_from_world[cam] = _cam_from_world(rotation, centre=centre_m)
    return Scene(name=name or root.name, camera_names=names, frame_sets=frame_sets,
                 gt=rig_from_cam_from_world(cameras, cam_from_world),
                 gt_cam_from_world=cam_from_world, lens="pinhole",
                 notes="4-camera inward ring in a mocap lab (portrait, a person on a platform, "
                       "little texture); reference = a Qualisys wand calibration.")
