"""How well a calibration explains a real set's person keypoints: per camera, the median and 90th
percentile reprojection residual (px) of every (frame, joint) the keypoints give in three or more
cameras at likelihood >= 0.6, triangulated (DLT on undistorted rays) with that calibration alone.
Run with no calibration, it judges the set's own reference; a reference that fits the videos'
keypoints clearly worse than a calibration fitted to them (a few dozen pose parameters against
thousands of observations) does not describe these videos to that level.

    python scripts/reference_fit.py caliscope|pose2sim KP_DIR [CALIBRATION_DIR ...]
        [--data-dir ../shared/data]

KP_DIR: `densecalib keypoints` of the set's videos, every frame (--max-frame-sets 57 / 100).
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import cv2
import numpy as np

import densecalib_ros  # noqa: F401  (cv2 before pycolmap)
from densecalib_ros.core import read_calibration
from densecalib_ros.core.io.keypoints import keypoint_sources, read_keypoints
from densecalib_ros.eval.datasets import load_caliscope, load_qualisys_videos

SETS = {"caliscope": ("caliscope_4webcams", load_caliscope),
        "pose2sim": ("pose2sim_4cam_ring", load_qualisys_videos)}
MIN_LIKELIHOOD = 0.6  # as calibrate --keypoints' default


def _rays(intrinsics, xy_opencv: np.ndarray) -> np.ndarray:
    """(N, 2) normalised undistorted coordinates of OpenCV pixels (COLMAP's camera model)."""
    camera = intrinsics.to_pycolmap()
    return np.asarray(camera.cam_from_img(np.asarray(xy_opencv, float) + 0.5))


def residuals(rig, names: list, kps: dict) -> dict:
    """{camera: residuals px} of every (frame, joint) seen in >= 3 cameras."""
    xy = np.stack([kps[n].xy_px[:, 0] for n in names])  # (C, F, J, 2)
    seen = np.stack([kps[n].likelihood[:, 0] >= MIN_LIKELIHOOD for n in names])
    seen &= np.isfinite(xy).all(-1)
    C, F, J = seen.shape
    rays = np.stack([_rays(rig.cameras[n].intrinsics, xy[c].reshape(-1, 2)).reshape(F, J, 2)
                     for c, n in enumerate(names)])
    poses = [np.asarray(rig.cameras[n].cam_from_rig, float)[:3] for n in names]
    focal = [float(rig.cameras[n].intrinsics.to_pycolmap().mean_focal_length()) for n in names]
    out = {n: [] for n in names}
    for f, j in zip(*np.nonzero(seen.sum(0) >= 3)):
        cams = np.flatnonzero(seen[:, f, j])
        rows = [r for c in cams for r in (rays[c, f, j, 0] * poses[c][2] - poses[c][0],
                                          rays[c, f, j, 1] * poses[c][2] - poses[c][1])]
        point = np.linalg.svd(np.array(rows))[2][-1]
        point = point[:3] / point[3]
        for c in cams:
            p = poses[c][:, :3] @ point + poses[c][:, 3]
            out[names[c]].append(np.linalg.norm(p[:2] / p[2] - rays[c, f, j]) * focal[c])
    return {n: np.array(v) for n, v in out.items()}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("set", choices=list(SETS))
    parser.add_argument("keypoints", type=Path)
    parser.add_argument("calibrations", type=Path, nargs="*")
    parser.add_argument("--data-dir", type=Path, default=Path("../shared/data"))
    args = parser.parse_args(argv)
    folder, loader = SETS[args.set]
    reference = loader(args.data_dir / folder, num_sets=1)
    names = list(reference.camera_names)
    kps = {n: read_keypoints(p) for n, p in keypoint_sources([str(args.keypoints)],
                                                             names).items()}
    rigs = [("reference", reference.gt)] + [(str(p), read_calibration(p))
                                            for p in args.calibrations]
    for label, rig in rigs:
        res = residuals(rig, names, kps)
        print(label + ": " + ", ".join(
            f"{n} median {np.median(r):.1f} px (p90 {np.percentile(r, 90):.0f}, {len(r)} obs)"
            for n, r in res.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
