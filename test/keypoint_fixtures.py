"""An animal walking through a generated arena, its joints seen by the rig's true cameras, written
as pose tools write them: DeepLabCut CSV and .h5 (pandas, as DeepLabCut itself writes them),
SLEAP .slp (h5py, the layout sleap-io writes) and OpenPose JSON. Pixel noise, missed joints and
confident-looking mistakes with low likelihood, as a trained network gives them."""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from densecalib_ros.core.synthetic import RigSpec, SyntheticRig, generate_rig

JOINTS = ("snout", "left_ear", "right_ear", "neck", "spine", "hip", "tail_base", "tail_mid",
          "left_fore", "right_fore", "left_hind", "right_hind")
# Body-frame joint positions (m): x forward, y left, z up, a rat-sized animal on its four paws.
BODY_M = np.array([[0.12, 0, 0.06], [0.08, 0.025, 0.09], [0.08, -0.025, 0.09], [0.05, 0, 0.08],
                   [0.0, 0, 0.09], [-0.06, 0, 0.08], [-0.1, 0, 0.05], [-0.18, 0, 0.03],
                   [0.05, 0.03, 0.0], [0.05, -0.03, 0.0], [-0.05, 0.035, 0.0],
                   [-0.05, -0.035, 0.0]])
SCORER = "DLC_resnet50_arenaDec1shuffle1_100000"


@dataclass
class Arena:
    rig: SyntheticRig
    xy_px: np.ndarray  # (C, F, J, 2) OpenCV px, NaN where the tool found nothing
    likelihood: np.ndarray  # (C, F, J)


def arena(seed: int = 0, num_cameras: int = 3, gap_deg: float = 60.0, frames: int = 300,
          noise_px: float = 1.5, scale: float = 2.0, spec: RigSpec | None = None) -> Arena:
    """The rig (small images: only its cameras are used here; lenses of 55-75 deg, as arenas
    have) and its cameras' keypoints of an animal (scaled by `scale`: a dog-sized body reads
    better in 640 px images) that walks a smooth random path over the floor all cameras see,
    turning and rearing."""
    rig = generate_rig(spec or RigSpec(num_cameras=num_cameras, width=640, height=480, seed=seed,
                                       gap_deg=gap_deg, supersample=1, lenses="ideal"))
    rng = np.random.default_rng(seed + 100)
    t = np.linspace(0, 1, frames)
    phases = rng.uniform(0, 2 * np.pi, 4)
    centre, half = _shared_floor(rig)  # an arena's cameras are framed on its floor
    x = centre[0] + half[0] * (0.8 * np.sin(2 * np.pi * 1.3 * t + phases[0])
                               + 0.2 * np.sin(2 * np.pi * 4 * t))
    y = centre[1] + half[1] * np.sin(2 * np.pi * 0.9 * t + phases[1])
    heading = np.arctan2(np.gradient(y), np.gradient(x))
    rear = 0.25 * np.clip(np.sin(2 * np.pi * 3 * t + phases[2]), 0, None)  # rears up, m
    world = np.empty((frames, len(JOINTS), 3))
    for f in range(frames):
        c, s = np.cos(heading[f]), np.sin(heading[f])
        body = BODY_M * scale
        body = body + np.outer(np.clip(body[:, 0], 0, None) / body[:, 0].max(), [0, 0, rear[f]])
        world[f] = body @ np.array([[c, s, 0], [-s, c, 0], [0, 0, 1]]) + [x[f], y[f], 0.0]
    C = len(rig.names)
    xy = np.full((C, frames, len(JOINTS), 2), np.nan)
    likelihood = np.zeros((C, frames, len(JOINTS)))
    for cam in range(C):
        proj, valid = rig.project(cam, world.reshape(-1, 3))
        proj = proj.reshape(frames, len(JOINTS), 2) - 0.5  # COLMAP -> OpenCV pixels
        valid = valid.reshape(frames, len(JOINTS))
        noisy = proj + rng.normal(0, noise_px, proj.shape)
        score = rng.uniform(0.85, 1.0, valid.shape)
        wrong = rng.random(valid.shape) < 0.05  # a confident-looking mistake, scored low
        noisy[wrong] += rng.normal(0, 40, (int(wrong.sum()), 2))
        score[wrong] = rng.uniform(0.05, 0.5, int(wrong.sum()))
        missed = ~valid | (rng.random(valid.shape) < 0.05)
        noisy[missed], score[missed] = np.nan, rng.uniform(0, 0.1, int(missed.sum()))
        xy[cam], likelihood[cam] = noisy, score
    return Arena(rig, xy, likelihood)


def _shared_floor(rig: SyntheticRig) -> tuple[np.ndarray, np.ndarray]:
    """(centre, half extents) m of the floor all cameras see, within 10 % of their images'
    borders: where the animal walks."""
    scene = rig.scenes[0]
    gx, gy = np.meshgrid(np.linspace(scene.room_min[0], scene.room_max[0], 60),
                         np.linspace(scene.room_min[1], scene.room_max[1], 60))
    floor = np.column_stack([gx.ravel(), gy.ravel(), np.full(gx.size, 0.1)])
    seen = np.ones(len(floor), bool)
    for c, cam in enumerate(rig.cameras):
        xy, valid = rig.project(c, floor)
        with np.errstate(invalid="ignore"):
            seen &= valid & (np.abs(xy[:, 0] / cam.width - 0.5) < 0.4) & \
                (np.abs(xy[:, 1] / cam.height - 0.5) < 0.4)
    lo, hi = np.percentile(floor[seen, :2], [10, 90], axis=0)
    return (lo + hi) / 2, (hi - lo) / 2


def dlc_frame(xy: np.ndarray, likelihood: np.ndarray, individuals=None):
    """A pandas DataFrame as DeepLabCut's analyze_videos makes it: columns (scorer,
    [individuals,] bodyparts, coords), one row per frame. xy (F, [I,] J, 2)."""
    import pandas as pd

    if individuals is None:
        xy, likelihood = xy[:, None], likelihood[:, None]
    F, I, J = likelihood.shape
    values = np.concatenate([xy, likelihood[..., None]], axis=-1).reshape(F, I * J * 3)
    levels = [[SCORER], list(individuals or ["-"]), list(JOINTS[:J]), ["x", "y", "likelihood"]]
    names = ["scorer", "individuals", "bodyparts", "coords"]
    if individuals is None:
        levels.pop(1), names.pop(1)
    columns = pd.MultiIndex.from_product(levels, names=names)
    return pd.DataFrame(values, columns=columns, index=np.arange(F))


def write_dlc(arena_: Arena, folder: Path, fmt: str = "csv") -> list[Path]:
    """One file per camera named as DeepLabCut names it: <video><scorer>.csv / .h5."""
    folder.mkdir(parents=True, exist_ok=True)
    out = []
    for c, name in enumerate(arena_.rig.names):
        frame = dlc_frame(arena_.xy_px[c], arena_.likelihood[c])
        path = folder / f"{name}{SCORER}.{fmt}"
        if fmt == "csv":
            frame.to_csv(path)
        else:
            frame.to_hdf(path, key="df_with_missing", format="table", mode="w")
        out.append(path)
    return out


def write_slp(path: Path, xy: np.ndarray, likelihood: np.ndarray, video: str,
              size: tuple[int, int], track_names: tuple = ()) -> None:
    """A SLEAP labels file of predictions in sleap-io's layout (format 1.4). xy (F, I, J, 2)
    OpenCV px; likelihood (F, I, J); an individual per track name (none: one untracked)."""
    import h5py

    F, I, J = likelihood.shape
    nodes = [{"name": n, "weight": 1.0} for n in JOINTS[:J]]
    skeleton = {"directed": True, "graph": {"name": "rat", "num_edges_inserted": 0},
                "links": [], "multigraph": True, "nodes": [{"id": j} for j in range(J)]}
    frames, instances, points = [], [], []
    for f in range(F):
        start = len(instances)
        for i in range(I):
            seen = np.isfinite(xy[f, i, :, 0])
            if not seen.any():
                continue
            p0 = len(points)
            for j in range(J):
                x, y = xy[f, i, j] if seen[j] else (np.nan, np.nan)
                points.append((x, y, bool(seen[j]), False, float(likelihood[f, i, j])))
            instances.append((len(instances), 1, len(frames), 0, i if track_names else -1, -1,
                              0.9, p0, len(points), 0.0))
        frames.append((len(frames), 0, f, start, len(instances)))
    with h5py.File(path, "w") as h5:
        meta = h5.create_group("metadata")
        meta.attrs["format_id"] = 1.4
        meta.attrs["json"] = np.bytes_(json.dumps({"version": "2.0.0", "skeletons": [skeleton],
                                                   "nodes": nodes, "videos": [], "tracks": []}))
        video_json = {"filename": video, "backend": {"shape": [F, size[1], size[0], 3]}}
        h5.create_dataset("videos_json", data=[np.bytes_(json.dumps(video_json))])
        h5.create_dataset("tracks_json", data=[np.bytes_(json.dumps([0, n]))
                                               for n in track_names] or np.zeros(0, "S1"))
        h5.create_dataset("frames", data=np.array(frames, dtype=[
            ("frame_id", "u8"), ("video", "u4"), ("frame_idx", "u8"),
            ("instance_id_start", "u8"), ("instance_id_end", "u8")]))
        h5.create_dataset("instances", data=np.array(instances, dtype=[
            ("instance_id", "i8"), ("instance_type", "u1"), ("frame_id", "u8"),
            ("skeleton", "u4"), ("track", "i4"), ("from_predicted", "i8"), ("score", "f4"),
            ("point_id_start", "u8"), ("point_id_end", "u8"), ("tracking_score", "f4")]))
        h5.create_dataset("points", data=np.zeros(0, dtype=[
            ("x", "f8"), ("y", "f8"), ("visible", "?"), ("complete", "?")]))
        h5.create_dataset("pred_points", data=np.array(points, dtype=[
            ("x", "f8"), ("y", "f8"), ("visible", "?"), ("complete", "?"), ("score", "f8")]))


def write_openpose(folder: Path, xy: np.ndarray, likelihood: np.ndarray, video: str) -> None:
    """OpenPose's per-frame JSON: xy (F, J, 2), one person per frame, (0, 0, 0) where missed."""
    folder.mkdir(parents=True, exist_ok=True)
    for f in range(len(xy)):
        flat = np.column_stack([np.nan_to_num(xy[f]), np.where(np.isfinite(xy[f, :, 0]),
                                                               likelihood[f], 0.0)])
        people = [{"person_id": [-1], "pose_keypoints_2d": flat.ravel().tolist()}]
        (folder / f"{video}_{f:012d}_keypoints.json").write_text(
            json.dumps({"version": 1.3, "people": people}))
