"""DeepLabCut's keypoint files: the CSV (header rows scorer, [individuals,] bodyparts, coords) and
the .h5 (a pandas HDFStore, as DeepLabCut and anipose write and read it: pandas with PyTables).
Pixel indices of the frames as OpenCV decoded them: (0, 0) is the top-left pixel's centre."""
from __future__ import annotations

import csv
import re
from pathlib import Path
from typing import Sequence

import numpy as np

from ..errors import InputError
from .keypoints_types import CameraKeypoints


def read_dlc_csv(path: Path) -> CameraKeypoints:
    """A DeepLabCut CSV: header rows scorer, (individuals,) bodyparts, coords, each naming every
    column; then one row per frame, the frame index (or a labelled image's path) first."""
    try:
        with open(path, newline="") as f:
            rows = list(csv.reader(f))
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read it as a DeepLabCut CSV ({exc}).") from exc
    heads = next((k for k, row in enumerate(rows[:6]) if row and row[0] == "coords"), None)
    if heads is None or rows[0][:1] != ["scorer"]:
        raise InputError(f"{path}: not a DeepLabCut CSV (its header rows start with scorer, "
                         "bodyparts and coords): give the file DeepLabCut wrote for this "
                         "camera's video.")
    coords = rows[heads]
    first = next((k for k, c in enumerate(coords) if c in ("x", "y", "likelihood")), len(coords))
    levels = {row[0]: row[first:] for row in rows[:heads + 1]}
    body = [row for row in rows[heads + 1:] if row]
    labels = ["/".join(row[:first]) for row in body]
    try:
        values = np.array([[float(v) if v not in ("", "nan", "NaN") else np.nan
                            for v in row[first:]] for row in body], dtype=np.float64)
    except ValueError as exc:
        raise InputError(f"{path}: a value is not a number ({exc}): the file is damaged or "
                         "not DeepLabCut's.") from exc
    return dlc_table(path, levels, labels, values.reshape(len(body), len(coords) - first))


def read_dlc_h5(path: Path) -> CameraKeypoints:
    """A DeepLabCut .h5 (a pandas HDFStore, as DeepLabCut and anipose write and read it: pandas
    with PyTables)."""
    import pandas as pd

    try:
        frame = pd.read_hdf(path)
    except (OSError, ValueError, KeyError, TypeError, ImportError) as exc:
        raise InputError(f"{path}: cannot read it as a DeepLabCut .h5 ({exc}): give the file "
                         "DeepLabCut wrote for this camera's video, or its CSV.") from exc
    columns = frame.columns
    names = list(columns.names) if columns.nlevels > 1 else []
    if "coords" not in names or "bodyparts" not in names:
        raise InputError(f"{path}: not a DeepLabCut table (its columns are not scorer / "
                         "bodyparts / coords): give the file DeepLabCut wrote.")
    levels = {name: [str(v) for v in columns.get_level_values(name)] for name in names}
    labels = ["/".join(map(str, i)) if isinstance(i, tuple) else str(i) for i in frame.index]
    return dlc_table(path, levels, labels, frame.to_numpy(dtype=np.float64))


def dlc_table(path: Path, levels: dict, labels: Sequence[str], values: np.ndarray
              ) -> CameraKeypoints:
    """CameraKeypoints from DeepLabCut's table: levels {"bodyparts": [per column], "coords":
    [...], maybe "individuals"}, one row label per frame (its index, or a labelled image whose
    last number is the frame), values (rows, columns)."""
    coords, parts = levels["coords"], levels.get("bodyparts", [])
    individuals = levels.get("individuals", [""] * len(coords))
    if len(parts) != len(coords) or len(individuals) != len(coords) or \
            values.shape[1:] != (len(coords),):
        raise InputError(f"{path}: its header rows and values do not line up column by column: "
                         "the file is damaged or not DeepLabCut's.")
    inds = tuple(dict.fromkeys(individuals))
    joints = tuple(dict.fromkeys(parts))  # maDLC's unique parts: the individual "single"
    F = len(labels)
    xy = np.full((F, len(inds), len(joints), 2), np.nan)
    likelihood = np.full((F, len(inds), len(joints)), np.nan)
    has_likelihood = "likelihood" in coords
    for k, (ind, part, coord) in enumerate(zip(individuals, parts, coords)):
        i, j = inds.index(ind), joints.index(part)
        if coord in ("x", "y"):
            xy[:, i, j, int(coord == "y")] = values[:, k]
        elif coord == "likelihood":
            likelihood[:, i, j] = values[:, k]
    if not has_likelihood:  # labelled data (CollectedData): a person placed every point
        likelihood = np.where(np.isfinite(xy).all(axis=-1), 1.0, np.nan)
    frames = frame_numbers(path, labels)
    order = np.argsort(frames, kind="stable")
    return CameraKeypoints(str(path), "DeepLabCut", frames[order], inds, joints, xy[order],
                           likelihood[order])


def frame_numbers(path: Path, labels: Sequence[str]) -> np.ndarray:
    """int64 frame index per row label: the label itself, or the last number in it (a labelled
    image "labeled-data/cam0/img0042.png" is frame 42). InputError naming the file for a label
    without a number, or a frame given twice."""
    out = np.empty(len(labels), np.int64)
    for k, label in enumerate(labels):
        numbers = re.findall(r"\d+", Path(label).stem if "/" in label or "." in label
                             else label)
        if not numbers:
            raise InputError(f"{path}: row {k + 1} ({label!r}) names no frame number: the rows "
                             "must be the video's frames (0, 1, ...) or images numbered by "
                             "frame.")
        out[k] = int(numbers[-1])
    values, counts = np.unique(out, return_counts=True)
    if len(values) < len(out):
        raise InputError(f"{path}: frame {int(values[counts > 1][0])} has more than one row: "
                         "give the keypoints of one video per file.")
    return out
