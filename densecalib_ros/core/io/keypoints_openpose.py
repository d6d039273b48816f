"""OpenPose's per-frame JSON, as OpenPose, RTMPose (rtmlib, MMPose's OpenPose output) and Pose2Sim
write it: a folder per camera of files "<video>_000000000042_keypoints.json" (the frame is the
file name's last number), each {"people": [{"person_id": [-1], "pose_keypoints_2d": [x0, y0, c0,
x1, ...]}, ...]}. A joint not found is (0, 0, 0). The joints are known by position (BODY_25,
COCO, HALPE_26: the same model for every camera).

People are listed in the order the detector found them, which differs from camera to camera: a
person is one individual across cameras only by a person_id other than -1 (Pose2Sim's tracked
output), or by being the only person in the frame. Frames with several people and no ids are
left out (their count is in the warning).
"""
from __future__ import annotations

import json
import logging
import re
from pathlib import Path

import numpy as np

from ..errors import InputError
from .keypoints_types import CameraKeypoints

log = logging.getLogger(__name__)

KEY = "pose_keypoints_2d"


def read_openpose_folder(folder: Path) -> CameraKeypoints:
    files = sorted(p for p in Path(folder).glob("*.json") if p.is_file())
    people_by_frame: dict[int, dict[str, np.ndarray]] = {}
    crowded, joints = 0, None
    for path in files:
        frame = _frame_of(path)
        if frame in people_by_frame:
            raise InputError(f"{folder}: two files are of frame {frame} ({path.name} and "
                             "another): give one camera's files per folder.")
        people = _people(path)
        if joints is None and people:
            joints = len(next(iter(people.values())))
        if any(len(p) != joints for p in people.values()):
            raise InputError(f"{path}: {max(len(p) for p in people.values())} joints where "
                             f"earlier files had {joints}: one pose model per camera.")
        if people is _CROWDED:
            crowded += 1
            continue
        people_by_frame[frame] = people
    if joints is None:
        raise InputError(f"{folder}: no person in any of its {len(files)} JSON files "
                         f"({KEY}).")
    if crowded:
        log.warning("%s: %d frame(s) with several people and no person_id left out (which is "
                    "which in another camera is not known)", folder, crowded)
    frames = np.array(sorted(people_by_frame), np.int64)
    individuals = tuple(sorted({k for people in people_by_frame.values() for k in people}))
    xy = np.full((len(frames), len(individuals), joints, 2), np.nan)
    likelihood = np.full(xy.shape[:3], np.nan)
    for row, frame in enumerate(frames):
        for name, values in people_by_frame[int(frame)].items():
            i = individuals.index(name)
            seen = values[:, 2] > 0  # (0, 0, 0): not found
            xy[row, i, seen], likelihood[row, i, seen] = values[seen, :2], values[seen, 2]
    return CameraKeypoints(str(folder), "OpenPose", frames, individuals,
                           tuple(str(j) for j in range(joints)), xy, likelihood)


_CROWDED: dict = {}  # several people without ids in one frame


def _frame_of(path: Path) -> int:
    numbers = re.findall(r"\d+", path.stem.replace("keypoints", ""))
    if not numbers:
        raise InputError(f"{path}: its name holds no frame number (OpenPose writes "
                         "<video>_000000000042_keypoints.json).")
    return int(numbers[-1])


def _people(path: Path) -> dict[str, np.ndarray]:
    """{individual: (J, 3) x, y, confidence} of one frame's file: by person_id, or the one person
    as ""; _CROWDED for several people without ids."""
    try:
        people = json.loads(path.read_text()).get("people", [])
        found = [(_person_id(p), np.asarray(p[KEY], np.float64).reshape(-1, 3))
                 for p in people if p.get(KEY)]
    except (OSError, ValueError, AttributeError, KeyError, TypeError) as exc:
        raise InputError(f"{path}: not OpenPose JSON with people[].{KEY} as x, y, "
                         f"confidence triplets ({exc}).") from exc
    if len(found) == 1 and found[0][0] is None:
        return {"": found[0][1]}
    if any(pid is None for pid, _ in found):
        return _CROWDED
    return {pid: values for pid, values in found}


def _person_id(person: dict):
    pid = person.get("person_id", -1)
    pid = pid[0] if isinstance(pid, list) and pid else pid
    return None if pid in (-1, None, []) else str(pid)
