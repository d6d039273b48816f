"""Issue 81: a few-camera arena calibrated from its images alone and with the walking animal's
keypoints beside them, against the generated truth (AUC@3, pair rotation error, focal error).

    python scripts/measure_arena_keypoints.py [--seeds 1 2] [--cameras 3 4] [--gap 80]
        [--frames 40] [--frame-sets 10] [--size 640x480] [--noise-px 1.5] [--json OUT.json]
    python scripts/measure_arena_keypoints.py --few   # bench --few's rooms, with keypoints

The rig: core.synthetic's plain room with an animal walking a loop (room="plain",
walker="animal"), cameras gap_deg apart, `frames` time steps of which `frame_sets` evenly
spaced ones are the images calibrated on (a video's keypoints are of every frame; its frame sets
a few). Its keypoints: the animal's body points (feet, leg tops, body, neck, head) at every time
step, projected with the true cameras, with pixel noise, 5 % missed and 5 % wrong ones scored
low (as a trained network's). Both calibrations run the default pipeline (run_job, as
`densecalib calibrate` does) on the same images.
"""
from __future__ import annotations

import argparse
import json
import sys
import time
from typing import Optional

import numpy as np

import densecalib_ros  # noqa: F401  (cv2 before pycolmap)
from densecalib_ros.core import CalibrationRequest, make_config, run_job
from densecalib_ros.core.errors import CalibrationError
from densecalib_ros.core.metrics import evaluate_calibration
from densecalib_ros.core.method.identity_tracks import IdentityTracks, identity_tracks
from densecalib_ros.core.io.keypoints import CameraKeypoints
from densecalib_ros.core.synthetic import RigSpec, generate_rig
from densecalib_ros.core.synthetic.scene import Box, Cylinder, Sphere


def body_points(scene, num_parts: int) -> np.ndarray:
    """(J, 3) world points of the walker (the scene's last num_parts objects): each leg's foot and
    top, each box's centre, the head's centre."""
    out = []
    for part in scene.objects[-num_parts:]:
        if isinstance(part, Cylinder):
            out += [part.center, part.center + [0, 0, part.height]]
        elif isinstance(part, (Box, Sphere)):
            out.append(part.center)
    return np.array(out, float)


def walker_keypoints(rig, noise_px: float, seed: int) -> dict:
    """{camera: CameraKeypoints} of the walker at every frame set (OpenCV pixels)."""
    moving = [i for i, (a, b) in enumerate(zip(rig.scenes[0].objects, rig.scenes[1].objects))
              if not np.allclose(a.center, b.center)]  # the walker's parts come last
    num_parts = len(rig.scenes[0].objects) - min(moving)
    world = np.stack([body_points(s, num_parts) for s in rig.scenes])  # (T, J, 3)
    rng = np.random.default_rng(seed)
    T, J = world.shape[:2]
    out = {}
    for c, name in enumerate(rig.names):
        xy, valid = rig.project(c, world.reshape(-1, 3))
        xy = xy.reshape(T, J, 2) - 0.5 + rng.normal(0, noise_px, (T, J, 2))
        score = rng.uniform(0.85, 1.0, (T, J))
        wrong = rng.random((T, J)) < 0.05
        xy[wrong] += rng.normal(0, 40, (int(wrong.sum()), 2))
        score[wrong] = rng.uniform(0.05, 0.5, int(wrong.sum()))
        missed = ~valid.reshape(T, J) | (rng.random((T, J)) < 0.05)
        xy[missed], score[missed] = np.nan, 0.0
        out[name] = CameraKeypoints(f"walker/{name}", "generated", np.arange(T), ("",),
                                    tuple(str(j) for j in range(J)), xy[:, None],
                                    score[:, None])
    return out


def measure(seed: int, cameras: int, gap: float, frames: int, frame_sets: int, size: tuple,
            noise_px: float) -> list[dict]:
    spec = RigSpec(num_cameras=cameras, width=size[0], height=size[1], num_time_steps=frames,
                   seed=seed, gap_deg=gap, room="plain", walker="animal", supersample=1)
    return measure_rig(generate_rig(spec), dict(seed=seed, cameras=cameras, gap_deg=gap),
                       frames, frame_sets, noise_px, seed, (False, True), "regular")


def measure_few(noise_px: float, only: Optional[list] = None) -> list[dict]:
    """bench --few's rooms (eval/few_rigs.py), built as the bench builds them, with the walker's
    keypoints at each of their frame sets beside the images."""
    from densecalib_ros.eval.bench import synthetic_rig_spec
    from densecalib_ros.eval.few_rigs import few_scenes

    rows = []
    for spec in [s for s in few_scenes() if not only or any(o in s.name for o in only)]:
        rig = generate_rig(synthetic_rig_spec(spec))
        frames = len(rig.images)
        preset = "fisheye" if spec.camera_model == "OPENCV_FISHEYE" else "regular"  # as the bench
        rows += measure_rig(rig, dict(scene=spec.name), frames, frames, noise_px, spec.seed,
                            (True,), preset)
    return rows


def measure_rig(rig, label: dict, frames: int, frame_sets: int, noise_px: float, seed: int,
                variants: tuple, preset: str) -> list[dict]:
    """One row per variant (with the keypoints or not) of the rig calibrated on `frame_sets`
    evenly spaced of its `frames` time steps."""
    sizes = [(cam.width, cam.height) for cam in rig.cameras]
    found: IdentityTracks = identity_tracks(walker_keypoints(rig, noise_px, seed), rig.names,
                                            sizes)
    images = [rig.images[t] for t in np.round(np.linspace(0, frames - 1, frame_sets)).astype(int)]
    rows = []
    for with_keypoints in variants:
        start = time.perf_counter()
        row = dict(**label, frames=frames, frame_sets=frame_sets, keypoints=with_keypoints,
                   keypoint_tracks=found.tracks.num_tracks if with_keypoints else 0)
        try:
            job = run_job(CalibrationRequest(
                images, list(rig.names), make_config(preset), {"source": "generated"},
                keypoints=found if with_keypoints else None))
            ev = evaluate_calibration(job.rig, rig.ground_truth())
            row.update(auc3=round(ev["auc3"], 1), auc30=round(ev["auc30"], 1),
                       registered=ev["num_registered"],
                       median_rot_deg=round(ev["median_rot_err_deg"], 2),
                       max_rot_deg=round(max(p["rot_err_deg"] for p in ev["pairs"]), 2),
                       median_focal_pct=round(100 * ev["median_focal_err"], 2),
                       warnings=list(job.rig.quality.warnings or []))
        except CalibrationError as exc:
            row.update(auc3=0.0, failed=str(exc)[:200])
        row["seconds"] = round(time.perf_counter() - start, 1)
        print(json.dumps(row), flush=True)
        rows.append(row)
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=[1, 2])
    parser.add_argument("--cameras", type=int, nargs="+", default=[3, 4])
    parser.add_argument("--gap", type=float, default=80.0)
    parser.add_argument("--frames", type=int, default=40)
    parser.add_argument("--frame-sets", type=int, default=10)
    parser.add_argument("--size", default="640x480")
    parser.add_argument("--noise-px", type=float, default=1.5)
    parser.add_argument("--json", default=None)
    parser.add_argument("--few", nargs="*", default=None, metavar="PATTERN",
                        help="bench --few's 7 rooms (or those whose name contains a PATTERN) "
                             "with the walker's keypoints instead")
    args = parser.parse_args(argv)
    size = tuple(int(v) for v in args.size.split("x"))
    rows = measure_few(args.noise_px, args.few) if args.few is not None else [
        r for seed in args.seeds for n in args.cameras
        for r in measure(seed, n, args.gap, args.frames, args.frame_sets, size, args.noise_px)]
    if args.json:
        with open(args.json, "w") as f:
            json.dump(rows, f, indent=1)
    for flag in (False, True):
        sel = [r for r in rows if r["keypoints"] == flag]
        if not sel:
            continue
        print(f"{'with' if flag else 'without'} keypoints: mean AUC@3 "
              f"{np.mean([r['auc3'] for r in sel]):.1f} over {len(sel)} rigs", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
