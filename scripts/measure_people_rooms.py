"""Issue 81: the two real rooms with a person in ../shared/data (caliscope's 4 webcams,
Pose2Sim's 4-camera ring) calibrated by the command as a user runs it, with and without the
person's keypoints, against their references (ChArUco bundle adjustment, Qualisys wand).

    python scripts/measure_people_rooms.py [--data-dir ../shared/data] [--work DIR]
        [--sets caliscope pose2sim] [--frame-sets 8]
        [--variants images keypoints keypoints-alone]
        [--reference-intrinsics] [--extra ARG ...]

`keypoints` (and `keypoints-alone`: no images, `--image-size` from the reference) first runs
`densecalib keypoints` on every frame of the videos (BlazePose, cached in
WORK/kp_<set>), then `densecalib calibrate --videos ... --keypoints WORK/kp_<set>`. Each row:
AUC@3/@30 of the pair rotations and translations, median and largest pair rotation error (deg),
median focal error (%), |error| / the calibration's own sigma per camera (z: focal length, principal
point, rotation; core.method.uncertainty.error_sigma_ratios, as `densecalib bench` checks it), the
warnings and the seconds. --reference-intrinsics gives every camera
the reference's own intrinsics (`--intrinsics`, written to WORK/reference): the extrinsics alone
are calibrated, which separates the focal lengths' share of the error from the rest.
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

import densecalib_ros  # noqa: F401  (cv2 before pycolmap)
from densecalib_ros.core import read_calibration
from densecalib_ros.core.io.export import write_calibration_files
from densecalib_ros.core.method.uncertainty import error_sigma_ratios
from densecalib_ros.core.metrics import evaluate_calibration
from densecalib_ros.eval.datasets import load_caliscope, load_qualisys_videos

SETS = {  # name: (folder, videos under it, loader of the reference, frames in the videos)
    "caliscope": ("caliscope_4webcams", "calibration/extrinsic", load_caliscope, 57),
    "pose2sim": ("pose2sim_4cam_ring", "videos", load_qualisys_videos, 100),
}


def densecalib(*args: str) -> subprocess.CompletedProcess:
    command = [str(Path(sys.executable).with_name("densecalib")), *args]
    return subprocess.run(command, capture_output=True, text=True)


def measure(name: str, data_dir: Path, work: Path, variant: str, frame_sets: int,
            extra: list[str], reference_intrinsics: bool = False) -> dict:
    folder, videos, loader, num_frames = SETS[name]
    videos_dir = data_dir / folder / videos
    reference = loader(data_dir / folder, num_sets=1).gt
    args = ["calibrate", "--videos", str(videos_dir), "--max-frame-sets", str(frame_sets)]
    if variant == "keypoints-alone":  # no images: each camera's size from the reference
        args = ["calibrate", "--image-size", *(f"{n}={c.intrinsics.width}x{c.intrinsics.height}"
                                               for n, c in reference.cameras.items())]
    if reference_intrinsics:
        write_calibration_files(reference, work / f"reference_{name}")
        args += ["--intrinsics", str(work / f"reference_{name}")]
    if variant.startswith("keypoints"):
        kp = work / f"kp_{name}"
        if not (kp / "keypoints_source.yaml").is_file():
            done = densecalib("keypoints", "--videos", str(videos_dir), "--max-frame-sets",
                              str(num_frames), "--out", str(kp))
            if done.returncode:
                return dict(set=name, variant=variant, failed=done.stderr[-300:])
        args += ["--keypoints", str(kp)]
    out = work / f"out_{name}_{variant}{'_given' if reference_intrinsics else ''}"
    start = time.perf_counter()
    done = densecalib(*args, *extra, "--out", str(out))
    row = dict(set=name, variant=variant, frame_sets=frame_sets, extra=" ".join(extra),
               reference_intrinsics=reference_intrinsics,
               seconds=round(time.perf_counter() - start, 1), exit=done.returncode)
    if done.returncode:
        return {**row, "failed": done.stderr.strip().splitlines()[-1:]}
    rig = read_calibration(out / "calibration.json")
    ev = evaluate_calibration(rig, reference)
    focal = {n: round(100 * c["focal_err"], 1) for n, c in ev["cameras"].items()
             if c["registered"]}
    return {**row, "auc3": round(ev["auc3"], 1), "auc30": round(ev["auc30"], 1),
            "registered": ev["num_registered"],
            "median_rot_deg": round(ev["median_rot_err_deg"], 2),
            "max_rot_deg": round(max(p["rot_err_deg"] for p in ev["pairs"]), 2),
            "focal_pct": focal,
            "z": {part: [round(float(z), 2) for z in values]
                  for part, values in error_sigma_ratios(rig, reference).items()
                  if part in ("focal", "principal_point", "rotation")},
            "warnings": list(rig.quality.warnings or [])}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data-dir", type=Path, default=Path("../shared/data"))
    parser.add_argument("--work", type=Path, default=Path("/tmp/people_rooms"))
    parser.add_argument("--sets", nargs="+", default=list(SETS), choices=list(SETS))
    parser.add_argument("--frame-sets", type=int, default=8)
    parser.add_argument("--variants", nargs="+", default=["images", "keypoints"],
                        choices=["images", "keypoints", "keypoints-alone"])
    parser.add_argument("--reference-intrinsics", action="store_true")
    parser.add_argument("--extra", nargs=argparse.REMAINDER, default=[],
                        help="further arguments for densecalib calibrate")
    args = parser.parse_args(argv)
    args.work.mkdir(parents=True, exist_ok=True)
    for name in args.sets:
        for variant in args.variants:
            print(json.dumps(measure(name, args.data_dir, args.work, variant, args.frame_sets,
                                     args.extra, args.reference_intrinsics)), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
