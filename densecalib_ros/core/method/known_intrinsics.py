"""Intrinsics the user already knows, read from the files other tools write, for an
extrinsics-only calibration (PipelineConfig.cameras.known_intrinsics).

A field rig is often made of cameras calibrated one by one in the lab (ROS camera_calibration's
camera_info YAML) and then mounted where no target can be shown to all of them; or of cameras
whose lenses were not touched since the last calibration while the mounts were bumped. Their
intrinsics are then better known than a self-calibration from the scene can give them, and
holding them leaves only the poses to estimate.

Sources (one spec each: PATH, or NAME=PATH to say which camera a single-camera file is for,
NAME1,NAME2=PATH for the two cameras of an OpenCV stereo file):
- a ROS camera_info YAML (camera_calibration, camera_info_manager, our own `<camera>.yaml`):
  distortion_model plumb_bob (k1 k2 p1 p2 [k3]) -> OPENCV or FULL_OPENCV, rational_polynomial
  -> FULL_OPENCV, equidistant (also "fisheye", "kannala_brandt") -> OPENCV_FISHEYE, no
  distortion -> PINHOLE; the camera is the file's camera_name (its last path component) or,
  failing that, the file stem;
- a densecalib calibration (calibration.json, its folder, or a node output_dir): every camera in
  it; a folder of camera_info YAMLs: every YAML in it;
- an anipose / aniposelib `calibration.toml` (animal-pose arenas: each `[cam_i]`'s name, size,
  matrix, distortions, fisheye) and a Kalibr camchain YAML (each `camN` with a pinhole camera
  model, radtan or equidistant; the camera named from its rostopic as `--bag` names it), as
  core/products/interchange.py writes them: every camera in them;
- an OpenCV FileStorage file (YAML `%YAML:1.0` with `!!opencv-matrix`, XML or JSON), as OpenCV's
  calibration sample and tutorial write it (`camera_matrix`, `distortion_coefficients`,
  `image_width`, `image_height`, `fisheye_model`): the camera is the file stem or NAME=; or a
  stereo file (`K1`/`M1`, `D1`, `K2`/`M2`, `D2`, as stereoCalibrate's samples write it), whose
  two cameras are named in order with NAME1,NAME2=PATH (or by its `left_camera`, `right_camera`,
  as `densecalib export --format opencv-stereo` writes them). A file without image size is for the
  size of its camera's images (check_known_intrinsics fills it in and checks that the principal
  point lies near their centre). The lens: `fisheye_model` when the file has it, else 4
  coefficients are cv::fisheye's k1..k4 (cv::calibrateCamera writes 5, 8, 12 or 14).

Pixel conventions: camera_info has the top-left pixel centre at (0, 0), COLMAP at (0.5, 0.5):
cx_colmap = cx_ros + 0.5 (as core/io/export.py writes them).
"""
from __future__ import annotations

from pathlib import Path
from typing import Optional, Sequence

import numpy as np
import yaml

from ..config import lens_of_model
from ..errors import InputError
from ..io.export import calibration_folder, read_calibration
from ..named_values import split_named
from ..types import CameraIntrinsics
from .plausibility import intrinsics_problem

# Width and height of intrinsics read from a file without image size (OpenCV stereo files):
# the size of the camera's images (check_known_intrinsics).
UNKNOWN_SIZE = (0, 0)

# A file without image size is refused for images whose centre is farther than this fraction
# of their width (height) from its principal point: a lens is centred within a few percent,
# and intrinsics calibrated at twice or half the resolution put it at the edge or a quarter.
MAX_PRINCIPAL_POINT_OFFSET = 0.2

# camera_info distortion_model names (sensor_msgs/distortion_models and what drivers write)
_FISHEYE_NAMES = ("equidistant", "fisheye", "kannala_brandt", "kannala_brandt4", "kb4")
_PLUMB_BOB_NAMES = ("plumb_bob", "radtan", "")
_RATIONAL_NAMES = ("rational_polynomial",)


def intrinsics_from_camera_info(info: dict, source: str = "camera_info", *,
                                size_from_images: bool = False) -> CameraIntrinsics:
    """CameraIntrinsics (COLMAP model and pixel convention) of a camera_info dict (the YAML's
    content). InputError with the file named when a field is missing or the model unknown.
    size_from_images: the source has no image size; the result is 0x0 (UNKNOWN_SIZE) until
    check_known_intrinsics gives it its images' size."""
    try:
        width, height = int(info["image_width"]), int(info["image_height"])
        K = np.asarray(info["camera_matrix"]["data"], dtype=np.float64).reshape(3, 3)
        model = str(info.get("distortion_model") or "").strip().lower()
        raw = info.get("distortion_coefficients") or {}
        D = [float(v) for v in (raw.get("data", []) if isinstance(raw, dict) else raw)]
    except (KeyError, TypeError, ValueError) as exc:
        raise InputError(f"{source} is not a camera_info YAML ({exc!r}): it needs image_width, "
                         "image_height, camera_matrix.data (9 values), distortion_model and "
                         "distortion_coefficients.data.") from exc
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2] + 0.5, K[1, 2] + 0.5
    sized = not (size_from_images and (width, height) == UNKNOWN_SIZE)
    if not (((width > 0 and height > 0) or not sized) and fx > 0 and fy > 0):
        raise InputError(f"{source}: image size {width}x{height} and focal lengths {fx}, {fy} "
                         "must be positive (is it an uncalibrated camera_info?).")
    if model in _FISHEYE_NAMES:
        if len(D) > 5 or (len(D) == 5 and D[4] != 0.0):  # a fifth, zero, is written by some
            raise InputError(f"{source}: an equidistant model has 4 coefficients (k1..k4), "
                             f"got {len(D)}.")
        k = D[:4] + [0.0] * (4 - len(D[:4]))
        return CameraIntrinsics("OPENCV_FISHEYE", width, height, np.array([fx, fy, cx, cy, *k]))
    if model in _PLUMB_BOB_NAMES + _RATIONAL_NAMES:
        if len(D) > 8 or (model in _PLUMB_BOB_NAMES and len(D) > 5):
            raise InputError(f"{source}: {model or 'plumb_bob'} takes at most "
                             f"{8 if model in _RATIONAL_NAMES else 5} coefficients, got {len(D)}.")
        if not any(D):
            return CameraIntrinsics("PINHOLE", width, height, np.array([fx, fy, cx, cy]))
        k = D + [0.0] * (8 - len(D))  # k1 k2 p1 p2 k3 k4 k5 k6
        if not any(k[4:]):
            return CameraIntrinsics("OPENCV", width, height, np.array([fx, fy, cx, cy, *k[:4]]))
        return CameraIntrinsics("FULL_OPENCV", width, height, np.array([fx, fy, cx, cy, *k]))
    raise InputError(f"{source}: distortion_model {model!r} is not supported: use plumb_bob, "
                     "rational_polynomial or equidistant.")


def _yaml_file(path: Path, name: Optional[str]) -> dict[str, CameraIntrinsics]:
    """The camera of a camera_info YAML, or the cameras of a Kalibr camchain."""
    try:
        info = yaml.safe_load(path.read_text())
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise InputError(f"Cannot read camera_info YAML {path}: {exc}") from exc
    if not isinstance(info, dict):
        raise InputError(f"{path} is not a camera_info YAML (no mapping at the top).")
    if "camera_matrix" not in info and any(isinstance(v, dict) and "intrinsics" in v
                                           for v in info.values()):
        return _kalibr_camchain(info, path)
    stated = info.get("camera_name")
    # a name YAML read as a number (`camera_name: 0003`, written so by earlier versions) lost
    # its text: the file's stem is the better guess
    stated = (stated.strip().strip("/").split("/")[-1] if isinstance(stated, str) else "")
    return {name or stated or path.stem: intrinsics_from_camera_info(info, str(path))}


def _is_opencv_storage(path: Path) -> bool:
    """Whether the file is an OpenCV FileStorage: its YAML dialect is not the YAML 1.1 that
    PyYAML reads (a `%YAML:1.0` header, `!!opencv-matrix` tags); its XML and JSON forms name
    their matrices' type_id opencv-matrix too."""
    try:
        head = path.read_bytes()[:4096].decode("utf-8", "replace")
    except OSError:
        return False
    return (head.lstrip().startswith("%YAML:") or "opencv-matrix" in head
            or "<opencv_storage>" in head)


def _numbers(node) -> Optional[list[float]]:
    """The values of an OpenCV FileNode: an opencv-matrix, a sequence or a number; None when
    the node is absent."""
    if node.empty() or node.isNone():
        return None
    if node.isMap():
        mat = node.mat()
        return None if mat is None else [float(v) for v in np.asarray(mat).ravel()]
    if node.isSeq():
        return [node.at(i).real() for i in range(node.size())]
    return [node.real()]


def _opencv_camera(fs, matrix_keys: Sequence[str], dist_keys: Sequence[str], source: str,
                   fisheye_flag: Optional[bool]) -> CameraIntrinsics:
    def first(keys):
        for key in keys:
            values = _numbers(fs.getNode(key))
            if values is not None:
                return values
        return None

    K, D = first(matrix_keys), first(dist_keys)
    if K is None or len(K) != 9:
        raise InputError(f"{source} has no 3x3 camera matrix ({' or '.join(matrix_keys)}).")
    D = D or []
    while len(D) > 8 and D[-1] == 0.0:  # thin-prism and tilt terms (12, 14), when unused
        D = D[:-1]
    width = _numbers(fs.getNode("image_width")) or [0]
    height = _numbers(fs.getNode("image_height")) or [0]
    fisheye = fisheye_flag if fisheye_flag is not None else len(D) == 4
    return intrinsics_from_camera_info(
        {"image_width": int(width[0]), "image_height": int(height[0]),
         "camera_matrix": {"data": K},
         "distortion_model": "equidistant" if fisheye else "rational_polynomial",
         "distortion_coefficients": {"data": D}}, source, size_from_images=True)


def _opencv_file(path: Path, names: Sequence[str]) -> dict[str, CameraIntrinsics]:
    """The camera of an OpenCV calibration file (named NAME= or by the file stem), or the two
    cameras of an OpenCV stereo file (named in order by NAME1,NAME2=)."""
    import cv2

    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
        opened = fs.isOpened()
    except (cv2.error, SystemError) as exc:
        raise InputError(f"Cannot read OpenCV calibration {path}: {exc}") from exc
    if not opened:
        raise InputError(f"Cannot open OpenCV calibration {path}.")
    try:
        flag = _numbers(fs.getNode("fisheye_model"))
        fisheye = None if flag is None else bool(flag[0])
        stereo = [i for i in (1, 2) if _numbers(fs.getNode(f"D{i}")) is not None]
        if stereo != [1, 2]:
            cam = _opencv_camera(fs, ("camera_matrix", "cameraMatrix", "K", "M"),
                                 ("distortion_coefficients", "distCoeffs", "dist_coeffs", "D"),
                                 str(path), fisheye)
            if len(names) > 1:
                raise InputError(f"{path} holds one camera (an OpenCV calibration), but "
                                 f"{len(names)} names were given for it.")
            return {names[0] if names else path.stem: cam}
        if not names:  # densecalib's own stereo export names its cameras
            names = [fs.getNode(k).string() if fs.getNode(k).isString() else ""
                     for k in ("left_camera", "right_camera")]
            names = names if all(names) else []
        if len(names) != 2:
            raise InputError(f"{path} is an OpenCV stereo calibration of two cameras (K1/D1, "
                             f"K2/D2): name them in order, e.g. left,right={path}.")
        return {names[i - 1]: _opencv_camera(fs, (f"K{i}", f"M{i}", f"cameraMatrix{i}"),
                                             (f"D{i}", f"distCoeffs{i}"),
                                             f"{path} (camera {i})", fisheye)
                for i in (1, 2)}
    except cv2.error as exc:  # a node of another type than its key's
        raise InputError(f"Cannot read OpenCV calibration {path}: {exc}") from exc
    finally:
        fs.release()


def _kalibr_camchain(chain: dict, path: Path) -> dict[str, CameraIntrinsics]:
    from ..io.bag import camera_names_from_topics

    cams = {k: v for k, v in chain.items() if isinstance(v, dict) and "intrinsics" in v}
    out = []
    for key, cam in cams.items():
        try:
            fu, fv, pu, pv = (float(v) for v in cam["intrinsics"])
            w, h = (int(v) for v in cam["resolution"])
            model = str(cam.get("distortion_model", "none"))
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"{path}: {key} is not a Kalibr camera ({exc!r}): it needs "
                             "intrinsics [fu, fv, pu, pv] and resolution [w, h].") from exc
        if cam.get("camera_model", "pinhole") != "pinhole" or \
                model not in ("radtan", "equidistant", "none"):
            raise InputError(f"{path}: {key} is a {cam.get('camera_model')} camera with "
                             f"{model} distortion; only pinhole with radtan or equidistant "
                             "distortion can be read.")
        out.append((str(cam.get("rostopic") or f"/{key}/image_raw"), intrinsics_from_camera_info(
            {"image_width": w, "image_height": h,
             "camera_matrix": {"data": [fu, 0.0, pu, 0.0, fv, pv, 0.0, 0.0, 1.0]},
             "distortion_model": "equidistant" if model == "equidistant" else "plumb_bob",
             "distortion_coefficients": {"data": list(cam.get("distortion_coeffs") or [])}},
            f"{path} ({key})")))
    names = camera_names_from_topics([topic for topic, _ in out])
    return {n: cam for n, (_, cam) in zip(names, out)}


def _anipose_toml(path: Path) -> dict[str, CameraIntrinsics]:
    import tomllib

    try:
        data = tomllib.loads(path.read_text())
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise InputError(f"Cannot read anipose calibration {path}: {exc}") from exc
    out = {}
    for key, cam in data.items():
        if not (key.startswith("cam_") and isinstance(cam, dict)):
            continue
        try:
            name, (w, h) = str(cam["name"]), cam["size"]
            info = {"image_width": w, "image_height": h,
                    "camera_matrix": {"data": np.asarray(cam["matrix"], float).ravel().tolist()},
                    "distortion_model": "equidistant" if cam.get("fisheye") else "plumb_bob",
                    "distortion_coefficients": {"data": list(cam.get("distortions") or [])}}
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"{path}: [{key}] is not an anipose camera ({exc!r}): it needs name, "
                             "size and matrix.") from exc
        out[name] = intrinsics_from_camera_info(info, f"{path} [{key}]")
    if not out:
        raise InputError(f"{path} holds no [cam_N] camera tables (an anipose calibration.toml).")
    return out


def read_known_intrinsics(specs: Sequence[str], camera_names: Optional[Sequence[str]] = None
                          ) -> dict[str, CameraIntrinsics]:
    """Camera name -> CameraIntrinsics from specs (module docstring: PATH or NAME=PATH).
    camera_names: the rig's cameras, when known: a source of several cameras (a calibration or a
    folder) then gives those of the rig only (a previous calibration may have had more
    cameras), and InputError when it names none of them. InputError on unreadable files, a
    camera named twice, or NAME= on a file of several cameras."""
    out: dict[str, CameraIntrinsics] = {}
    origin: dict[str, str] = {}
    for spec in specs:
        name, sep, path_text = split_named(str(spec), camera_names)
        names = [n.strip() for n in name.split(",")]
        if not sep or "/" in name or not all(names):
            names, path_text = [], str(spec)
        name = names[0] if len(names) == 1 else None
        path = Path(path_text).expanduser()
        if not path.exists():
            raise InputError(f"Intrinsics file {path} does not exist (give a camera_info YAML, a "
                             "calibration.json or its folder, optionally as NAME=PATH).")
        found: dict[str, CameraIntrinsics] = {}
        if path.is_file() and _is_opencv_storage(path):
            found = _opencv_file(path, names)
        elif len(names) > 1:
            raise InputError(f"{spec}: NAME1,NAME2= names the two cameras of an OpenCV stereo "
                             f"file; {path} is not one (name a single-camera file with "
                             "NAME=PATH).")
        elif path.is_dir() and (calibration_folder(path) / "calibration.json").exists():
            found = _from_calibration(path)
        elif path.suffix == ".json":
            found = _from_calibration(path)
        elif path.suffix == ".toml":
            found = _anipose_toml(path)
        elif path.is_dir() and (path / "calibration.toml").is_file():  # an anipose project
            found = _anipose_toml(path / "calibration.toml")
        elif path.is_dir():
            for f in sorted(list(path.glob("*.yaml")) + list(path.glob("*.yml"))):
                for n, cam in (_opencv_file(f, []) if _is_opencv_storage(f)
                               else _yaml_file(f, None)).items():
                    if n in found:
                        raise InputError(f"Two files in {path} are for camera {n!r}: give the "
                                         "files one by one as NAME=PATH.")
                    found[n] = cam
            if not found:
                raise InputError(f"{path} holds no calibration.json and no camera_info YAML.")
        else:
            found = _yaml_file(path, name)
        if name is not None and len(found) > 1:
            raise InputError(f"{spec}: NAME= applies to a single-camera file, but {path} holds "
                             f"{len(found)} cameras ({', '.join(found)}).")
        if camera_names is not None and len(found) > 1:
            ours = {n: cam for n, cam in found.items() if n in camera_names}
            if not ours:
                raise InputError(f"{path} has intrinsics of {', '.join(sorted(found))}, none of "
                                 f"the cameras {', '.join(camera_names)}: name each file's "
                                 "camera with NAME=PATH.")
            found = ours
        for n, cam in found.items():
            if n in out:
                raise InputError(f"Intrinsics of camera {n!r} given twice ({origin[n]} and "
                                 f"{path}): give each camera once.")
            out[n], origin[n] = cam, str(path)
    return out


def _from_calibration(path: Path) -> dict[str, CameraIntrinsics]:
    rig = read_calibration(path)
    return {n: cam.intrinsics for n, cam in rig.cameras.items()}


def check_known_intrinsics(known: dict, camera_names: Sequence[str],
                           image_sizes: Sequence[tuple[int, int]]) -> dict:
    """`known` with the intrinsics of files without image size (UNKNOWN_SIZE) given their
    images' size. InputError when given intrinsics name an unknown camera, were calibrated at
    another image size than the camera's images, or are physically implausible
    (plausibility.py); for files without image size, when the principal point is not near the
    images' centre (the file is for another resolution)."""
    unknown = sorted(set(known) - set(camera_names))
    if unknown:
        raise InputError(f"Intrinsics given for unknown camera(s) {', '.join(unknown)}: the "
                         f"cameras are {', '.join(camera_names)} (name a single-camera file "
                         "with NAME=PATH).")
    known = dict(known)
    for name, (w, h) in zip(camera_names, image_sizes):
        cam = known.get(name)
        if cam is None:
            continue
        if (int(cam.width), int(cam.height)) == UNKNOWN_SIZE:
            cam = known[name] = CameraIntrinsics(cam.model, int(w), int(h), cam.params.copy())
            pp_px = np.asarray(cam.params[2:4])  # the file's models: fx fy cx cy first
            off = np.abs(pp_px / [w, h] - 0.5)
            if np.any(off > MAX_PRINCIPAL_POINT_OFFSET):
                raise InputError(
                    f"The intrinsics given for {name} have no image size, and their principal "
                    f"point ({pp_px[0]:.0f}, {pp_px[1]:.0f}) px is far from the centre of its "
                    f"{w}x{h} images: they are for another resolution. Give intrinsics "
                    "calibrated at this resolution.")
        if (int(cam.width), int(cam.height)) != (int(w), int(h)):
            raise InputError(
                f"The intrinsics given for {name} are for {cam.width}x{cam.height} images, its "
                f"images are {w}x{h}: give intrinsics calibrated at this resolution (a resized or "
                "cropped stream needs its own).")
        problem = intrinsics_problem(cam)
        if problem is not None and lens_of_model(cam.model) == "pinhole":
            # A fisheye's polynomial is only judged over what it images (not known here).
            raise InputError(f"The intrinsics given for {name} are not usable: {problem}. If "
                             "it is a fisheye lens, its file should say distortion_model: "
                             "equidistant; else calibrate its intrinsics again (or leave them "
                             "out to self-calibrate them).")
    return known


def with_previous_intrinsics(known: dict, previous, camera_names: Sequence[str]) -> dict:
    """`known` plus the intrinsics of a previous RigCalibration for the rig's other cameras
    (keep the intrinsics on recalibration; the ones given explicitly win)."""
    return {**{n: c.intrinsics for n, c in previous.cameras.items() if n in camera_names},
            **known}


def describe(known: dict) -> dict:
    """The given intrinsics as recorded in a calibration's quality: name -> model."""
    return {n: cam.model for n, cam in sorted(known.items())}



def given_intrinsics_fit(state, camera_names: Sequence[str], num_threads: int = -1) -> dict:
    """How well the given intrinsics fit the scene: per registered camera with given intrinsics
    and at least MIN_CHECK_MULTIVIEW_OBSERVATIONS observations of points that >= 3 cameras see,
    its median reprojection error [px] as calibrated (intrinsics held) and after one more bundle
    adjustment with every camera's focal and distortion free (a diagnostic: the calibration
    keeps the given values), and how far that moves its mean focal [%]. A camera whose file is
    wrong (another resolution's, a mislabelled lens model, a refocused lens) fits clearly better
    freed (given_intrinsics_warnings). Cameras seen with fewer multi-view points are not judged:
    two views alone do not pin a focal down, and freed they fit what the right files leave. A
    stereo pair's files are not judged either: judged on all their observations, real pairs with
    right files warned and real pairs with a wrong file did not (docs/design-notes.md, Checking
    given intrinsics).

    Freeing one camera at a time instead would name the wrong camera alone, but shows less: with
    two cameras wrong, each freed alone gains a fraction of what both freed gain, and the
    neighbour of a wrong camera gains by bending towards it (same section)."""
    from .reconstruction import BAStage, bundle_adjust, camera_quality, reprojection_errors

    before = reprojection_errors(state)
    given = [c for c in state.registered() if state.intrinsics_fixed(c) and
             (camera_quality(state, c, before).num_multiview_observations or 0)
             >= MIN_CHECK_MULTIVIEW_OBSERVATIONS]
    if not given:
        return {}
    free = state.copy()
    free.fixed_blocks = frozenset()
    bundle_adjust(free, camera_names, BAStage(100, refine_focal=True, refine_extra=True),
                  num_threads)
    after = reprojection_errors(free)
    out = {}
    for c in given:
        rows = np.isfinite(before[:, c]) & np.isfinite(after[:, c])
        f0 = float(state.camera(c).to_pycolmap().mean_focal_length())
        f1 = float(free.camera(c).to_pycolmap().mean_focal_length())
        out[camera_names[c]] = {
            "median_px": float(np.median(before[rows, c])),
            "median_px_refined": float(np.median(after[rows, c])),
            "focal_change_pct": 100.0 * (f1 - f0) / f0}
    return out


MIN_CHECK_MULTIVIEW_OBSERVATIONS = 30  # reconstruction.camera_quality's num_multiview_observations
# A camera's median reprojection error, given over freed, above which its intrinsics are suspect:
# right ones stay near 1, a focal or k1 clearly off gives several times that. A focal's move alone
# is no sign: correct focals of weak cameras move when freed, with no better fit
# (docs/design-notes.md, Checking given intrinsics).
SUSPECT_ERROR_RATIO = 1.3
MIN_ERROR_GAIN_PX = 0.05  # below this the ratio of two tiny errors says nothing


def given_intrinsics_warnings(fit: dict) -> list[str]:
    """A sentence naming the cameras whose given intrinsics the scene contradicts
    (given_intrinsics_fit), the largest drop in error first; [] when none."""
    suspect = sorted(((f["median_px"] / max(f["median_px_refined"], 1e-9), name, f)
                      for name, f in fit.items()
                      if f["median_px"] > SUSPECT_ERROR_RATIO * f["median_px_refined"]
                      and f["median_px"] - f["median_px_refined"] > MIN_ERROR_GAIN_PX),
                     key=lambda s: -s[0])
    if not suspect:
        return []
    named = "; ".join(f"{name} from {f['median_px']:.2f} to {f['median_px_refined']:.2f} px "
                      f"(focal {f['focal_change_pct']:+.1f} %)" for _, name, f in suspect)
    return [f"The given intrinsics do not fit the scene: freed, the median reprojection error of "
            f"{named}. Check the file of {suspect[0][1]} first (a wrong camera bends its "
            "neighbours' fit too): is it for this camera, resolution and lens model (refocused? "
            "zoomed?)? Or calibrate the camera without it: wrong intrinsics held fixed bend the "
            "extrinsics."]
