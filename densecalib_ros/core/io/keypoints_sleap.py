"""SLEAP's files read with h5py as SLEAP lays them out (sleap-io's io/slp.py reads the same
datasets; sleap-io itself would bring pynwb, skia-python and more for this): a labels file
(.slp) and the analysis export (.analysis.h5). One video per file, the camera's.

.slp: `metadata` attributes `format_id` and `json` (the skeletons: node names), `videos_json`,
`tracks_json` (each ["spawned_on", name]: the individuals), `frames` (frame_idx and the range of
its instances), `instances` (type 0 a person's, 1 predicted; track, point range) and `points` /
`pred_points` (x, y, visible, complete[, score]). A person's instance replaces the prediction of
the same individual in its frame. Instances on no track are one individual only where a frame
holds one of them: several untracked animals in a frame cannot be told apart.
.analysis.h5: `tracks` (individuals, 2, nodes, frames), `point_scores` (individuals, nodes,
frames), `node_names`, `track_names`.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..errors import InputError
from .keypoints_types import CameraKeypoints

USER, PREDICTED = 0, 1  # instances' instance_type
# Files before this format put (0, 0) at the top-left pixel's corner (sleap-io: "legacy
# coordinate system"), later ones at its centre, as OpenCV.
PIXEL_CENTRE_FORMAT = 1.1


def is_sleap_analysis(path: Path) -> bool:
    """Whether the .h5 at `path` is SLEAP's analysis export (else: DeepLabCut's)."""
    import h5py

    try:
        with h5py.File(path, "r") as f:
            return "tracks" in f and "node_names" in f
    except OSError:
        return False


def read_sleap_analysis(path: Path) -> CameraKeypoints:
    import h5py

    with h5py.File(path, "r") as f:
        tracks = np.asarray(f["tracks"], np.float64)  # (individuals, 2, nodes, frames)
        scores = np.asarray(f["point_scores"], np.float64) if "point_scores" in f else None
        joints = tuple(_text(n) for n in f["node_names"])
        names = tuple(_text(n) for n in f["track_names"]) if "track_names" in f else ()
    if tracks.ndim != 4 or tracks.shape[1] != 2 or tracks.shape[2] != len(joints):
        raise InputError(f"{path}: its `tracks` is {tracks.shape}, not (individuals, 2, "
                         f"{len(joints)} nodes, frames): export it again from SLEAP.")
    xy = tracks.transpose(3, 0, 2, 1)
    likelihood = np.where(np.isfinite(xy).all(-1), 1.0, np.nan) if scores is None \
        else scores.transpose(2, 0, 1)
    individuals = names if len(names) == tracks.shape[0] else \
        tuple(str(i) for i in range(tracks.shape[0])) if tracks.shape[0] > 1 else ("",)
    return CameraKeypoints(str(path), "SLEAP", np.arange(xy.shape[0], dtype=np.int64),
                           individuals, joints, xy, likelihood)


def read_slp(path: Path) -> CameraKeypoints:
    """A SLEAP labels file (module docstring)."""
    import h5py

    try:
        with h5py.File(path, "r") as f:
            meta = f["metadata"].attrs
            format_id = float(meta["format_id"]) if "format_id" in meta else 1.0
            skeletons = json.loads(_text(meta["json"]))
            videos = [json.loads(_text(v)) for v in f["videos_json"]]
            track_names = [json.loads(_text(t))[1] for t in f["tracks_json"]] \
                if "tracks_json" in f else []
            frames, instances = f["frames"][:], f["instances"][:]
            points = f["points"][:] if "points" in f else None
            pred = f["pred_points"][:] if "pred_points" in f else None
    except (OSError, KeyError, ValueError, IndexError) as exc:
        raise InputError(f"{path}: cannot read it as a SLEAP labels file ({exc}): save it "
                         "again from SLEAP, or export the analysis .h5.") from exc
    if len(videos) > 1:
        raise InputError(f"{path}: holds {len(videos)} videos; this reads one camera's: save "
                         "each camera's video's labels in a file of its own (camera = file "
                         "name), or give NAME=PATH per camera.")
    joints = _node_names(path, skeletons)
    table = _instances_table(frames, instances, points, pred, track_names, len(joints))
    frame_ids = np.array(sorted({row[0] for row in table}), np.int64)
    named = sorted({row[1] for row in table if row[1] is not None})
    individuals = tuple(named) if named else ("",)
    xy = np.full((len(frame_ids), len(individuals), len(joints), 2), np.nan)
    likelihood = np.full(xy.shape[:3], np.nan)
    for frame, track, pts in table:
        f_row = int(np.searchsorted(frame_ids, frame))
        i = individuals.index(track) if track is not None else 0
        xy[f_row, i], likelihood[f_row, i] = pts[:, :2], pts[:, 2]
    if format_id < PIXEL_CENTRE_FORMAT:
        xy -= 0.5
    return CameraKeypoints(str(path), "SLEAP", frame_ids, individuals, joints, xy, likelihood,
                           _video_size(videos[0]) if videos else None)


def _node_names(path: Path, metadata: dict) -> tuple:
    """The first skeleton's node names in its own order (a file of one animal model)."""
    nodes = [n["name"] for n in metadata.get("nodes", [])]
    skeletons = metadata.get("skeletons", [])
    if not skeletons or not nodes:
        raise InputError(f"{path}: its metadata has no skeleton: save it again from SLEAP.")
    graph = skeletons[0].get("nx_graph", skeletons[0])
    try:
        return tuple(nodes[int(n["id"])] for n in graph["nodes"])
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise InputError(f"{path}: its skeleton's nodes are not SLEAP's node indices ({exc}): "
                         "save it again from SLEAP, or export the analysis .h5.") from exc


def _instances_table(frames, instances, points, pred, track_names: list, num_joints: int
                     ) -> list:
    """[(frame index, track name or None, (J, 3) x y likelihood)]: per frame and individual the
    person's instance where there is one, else the prediction; untracked ones only where alone
    in their frame (module docstring)."""
    out = []
    for frame in frames:
        chosen: dict = {}
        untracked = []
        for inst in instances[int(frame["instance_id_start"]):int(frame["instance_id_end"])]:
            kind, track = int(inst["instance_type"]), int(inst["track"])
            start, end = int(inst["point_id_start"]), int(inst["point_id_end"])
            if kind == USER and points is not None:
                rows = points[start:end]
                score = np.where(rows["visible"], 1.0, np.nan)
            elif kind == PREDICTED and pred is not None:
                rows = pred[start:end]
                score = np.where(rows["visible"], rows["score"], np.nan)
            else:
                continue
            if len(rows) != num_joints:
                continue  # another skeleton's instance
            pts = np.column_stack([rows["x"], rows["y"], score]).astype(np.float64)
            pts[~np.isfinite(score), :2] = np.nan
            if track < 0 or track >= len(track_names):
                untracked.append((kind, pts))
            elif track not in chosen or kind == USER:
                chosen[track] = pts
        people = [p for k, p in untracked if k == USER] or [p for _, p in untracked]
        if not chosen and len(people) == 1:
            out.append((int(frame["frame_idx"]), None, people[0]))
        out.extend((int(frame["frame_idx"]), track_names[t], p) for t, p in chosen.items())
    return out


def _video_size(video: dict):
    shape = video.get("backend", {}).get("shape")
    if shape and len(shape) >= 3 and int(shape[1]) > 0 and int(shape[2]) > 0:
        return int(shape[2]), int(shape[1])  # (frames, height, width, channels)
    return None


def _text(value) -> str:
    if isinstance(value, np.ndarray):
        value = value.tobytes() if value.dtype.kind in "uiV" else value.item()
    return value.decode() if isinstance(value, (bytes, np.bytes_)) else str(value)
