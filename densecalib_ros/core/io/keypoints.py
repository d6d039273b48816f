"""2D keypoints that pose tools wrote (DeepLabCut, SLEAP, OpenPose / RTMPose / Pose2Sim), read as
one CameraKeypoints per camera: per frame, individual and joint, (x, y) and the tool's likelihood.

The same joint of the same individual at the same instant is one point in space, whatever the
viewpoint: across cameras these are correspondences by identity (core.method.identity_tracks
makes them tracks). Every tool here writes OpenCV's pixel convention (the top-left pixel's centre
at (0, 0)): DeepLabCut and OpenPose give pixel indices of the frames they decoded with OpenCV,
SLEAP says so of its format (files before format 1.1 put (0, 0) at the pixel's corner: moved by
half a pixel as sleap-io does). CameraKeypoints keeps that convention; the tracks are COLMAP's.

Which file is which camera (keypoint_sources): NAME=PATH, else the file or folder name, as
`--images` names cameras: a DeepLabCut file is named after its video followed by the network
("cam0DLC_resnet50_arenaJan1shuffle1_100000.h5": camera cam0), a SLEAP file may end in
".predictions" or ".analysis", an OpenPose / Pose2Sim camera is a folder of per-frame JSON files
("cam0" or "cam0_json").
"""
from __future__ import annotations

import re
from pathlib import Path
from typing import Optional, Sequence

from ..errors import InputError
from ..named_values import split_named
from .keypoints_dlc import read_dlc_csv, read_dlc_h5
from .keypoints_openpose import read_openpose_folder
from .keypoints_sleap import is_sleap_analysis, read_sleap_analysis, read_slp
from .keypoints_types import CameraKeypoints

# What each tool writes: a file per camera, or (OpenPose, Pose2Sim) a folder of per-frame JSON.
KEYPOINT_SUFFIXES = (".h5", ".csv", ".slp", ".json")
# Name parts the tools add after the video's (camera's) name: DeepLabCut's scorer, SLEAP's
# exports, Pose2Sim's JSON folders.
_TOOL_SUFFIXES = re.compile(r"(DLC_.*|\.predictions|\.analysis|_json)$")


def camera_of(path: Path) -> str:
    """The camera a keypoint file or folder is of, from its name (module docstring)."""
    stem = path.name if path.is_dir() else path.stem
    return _TOOL_SUFFIXES.sub("", stem) or stem


def keypoint_sources(values: Sequence[str], names: Optional[Sequence[str]] = None
                     ) -> dict[str, Path]:
    """{camera: file or JSON folder} from --keypoints values: NAME=PATH, a file, a camera's JSON
    folder, or a folder holding one file or sub-folder per camera. Where one camera has a
    DeepLabCut .h5 and .csv of the same name (DLC writes both), the .h5. InputError naming the
    path for what does not exist or holds no keypoints, and a camera given twice."""
    out: dict[str, Path] = {}
    for value in values:
        name, sep, rest = split_named(value, names)
        if sep and not Path(value).exists():
            found = {name: Path(rest)}
            if not found[name].exists():
                raise InputError(f"--keypoints {value}: there is no {rest}: give the keypoint "
                                 f"file (or OpenPose JSON folder) of camera {name}.")
        else:
            found = _sources_in(Path(value))
        twice = sorted(set(found) & set(out))
        if twice:
            raise InputError(f"Keypoints of camera(s) {', '.join(twice)} given twice "
                             f"({', '.join(str(out[n]) for n in twice)} and "
                             f"{', '.join(str(found[n]) for n in twice)}): give each camera "
                             "once, NAME=PATH where the file names do not say the camera.")
        out.update(found)
    return out


def _sources_in(path: Path) -> dict[str, Path]:
    if not path.exists():
        raise InputError(f"--keypoints {path}: no such file or folder.")
    if path.is_file():
        return {camera_of(path): path}
    if _json_files(path):
        return {camera_of(path): path}  # one camera's per-frame OpenPose files
    found: dict[str, list[Path]] = {}
    for child in sorted(path.iterdir()):
        if (child.is_file() and child.suffix in KEYPOINT_SUFFIXES) or \
                (child.is_dir() and _json_files(child)):
            found.setdefault(camera_of(child), []).append(child)
    if not found:
        raise InputError(f"--keypoints {path}: no keypoint files in it (DeepLabCut .h5/.csv, "
                         "SLEAP .slp/.analysis.h5, or a folder of OpenPose JSON per camera).")
    out = {}
    for camera, paths in found.items():
        if len(paths) == 2 and {p.suffix for p in paths} == {".h5", ".csv"} and \
                paths[0].stem == paths[1].stem:
            paths = [p for p in paths if p.suffix == ".h5"]
        if len(paths) > 1:
            raise InputError(f"--keypoints {path}: {len(paths)} files are of camera {camera} "
                             f"({', '.join(p.name for p in paths)}): give one per camera, e.g. "
                             f"{camera}={paths[0]}.")
        out[camera] = paths[0]
    return out


def _json_files(folder: Path) -> list[Path]:
    return sorted(p for p in folder.glob("*.json") if p.is_file())


def read_keypoints(path: Path) -> CameraKeypoints:
    """A camera's keypoints from `path` (its suffix, or a folder of JSON, says the tool).
    InputError naming the file for what is not such a file."""
    path = Path(path)
    if path.is_dir():
        return read_openpose_folder(path)
    if path.suffix == ".csv":
        return read_dlc_csv(path)
    if path.suffix == ".slp":
        return read_slp(path)
    if path.suffix == ".h5":
        return read_sleap_analysis(path) if is_sleap_analysis(path) else read_dlc_h5(path)
    raise InputError(f"{path}: not a keypoint file this reads (DeepLabCut .h5/.csv, SLEAP "
                     ".slp/.analysis.h5, a folder of OpenPose JSON).")


__all__ = ["CameraKeypoints", "camera_of", "keypoint_sources", "read_keypoints"]
