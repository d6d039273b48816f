"""Where a real room's calibration fails, taken apart against its reference (issue 81): how many
of each camera pair's keypoint matches the reference's epipolar geometry bears out, and the
calibration with parts of the reference given.

    python scripts/real_rooms_apart.py caliscope|pose2sim [--data-dir ../shared/data]
        [--sets 8] [--matchers sift asift] [--given intrinsics radial radial-centred]

Matches: per pair and matcher, the matches over all frame sets and those within 2, 5 and 40 px
(Sampson distance at the pair's mean focal length) of the reference cameras' epipolar geometry.
Given: `intrinsics`, the reference's own (the extrinsics alone, asift's matches); `radial`, a
RADIAL lens fitted to the reference's (its focal length and principal point, k1 and k2 by least
squares over the image): whether two radial terms hold the lenses; `radial-centred`, the same
with the principal point at the image centre, as the SfM holds it: what the held point costs.
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

import densecalib_ros  # noqa: F401  (cv2 before pycolmap)
from densecalib_ros.core import calibrate_rig, make_config
from densecalib_ros.core.colmap_logging import quiet_colmap
from densecalib_ros.core.errors import CalibrationError
from densecalib_ros.core.metrics import evaluate_calibration
from densecalib_ros.core.stages.matching import match_frame_sets
from densecalib_ros.core.types import CameraIntrinsics
from densecalib_ros.eval.datasets import load_caliscope, load_qualisys_videos

SETS = {"caliscope": ("caliscope_4webcams", load_caliscope),
        "pose2sim": ("pose2sim_4cam_ring", load_qualisys_videos)}
TOLERANCES_PX = (2.0, 5.0, 40.0)  # a right match; the reference's own error; a coarse one


def epipolar_px(gt, names, i: int, j: int, xy_i: np.ndarray, xy_j: np.ndarray) -> np.ndarray:
    """Sampson distance (px at the pair's mean focal) of matches under the reference cameras."""
    cams = [gt.cameras[names[k]] for k in (i, j)]
    pose_i, pose_j = (c.cam_from_rig for c in cams)
    rotation = pose_j[:3, :3] @ pose_i[:3, :3].T
    t = pose_j[:3, 3] - rotation @ pose_i[:3, 3]
    essential = np.array([[0, -t[2], t[1]], [t[2], 0, -t[0]], [-t[1], t[0], 0]]) @ rotation
    a, b = (np.c_[np.asarray(c.intrinsics.to_pycolmap().cam_from_img(xy)), np.ones(len(xy))]
            for c, xy in zip(cams, (xy_i, xy_j)))
    ea, eb = a @ essential.T, b @ essential
    sampson = np.abs(np.sum(b * ea, 1)) / np.sqrt(ea[:, 0] ** 2 + ea[:, 1] ** 2
                                                  + eb[:, 0] ** 2 + eb[:, 1] ** 2)
    focal = np.mean([c.intrinsics.to_pycolmap().mean_focal_length() for c in cams])
    return sampson * focal


def matches_against_reference(scene, matcher: str) -> None:
    names = scene.camera_names
    sets = match_frame_sets(scene.frame_sets, make_config("regular", "incremental",
                                                          matcher=matcher), camera_names=names)
    for i in range(len(names)):
        for j in range(i + 1, len(names)):
            errors = []
            for match_set in sets:
                pair = match_set.pairs.get((i, j))
                rows = np.flatnonzero(pair.target >= 0) if pair is not None else []
                if len(rows):
                    errors.append(epipolar_px(scene.gt, names, i, j, match_set.sites[i][rows],
                                              match_set.sites[j][pair.target[rows]]))
            errors = np.concatenate(errors) if errors else np.zeros(0)
            within = ", ".join(f"{int((errors < t).sum())} within {t:g} px" for t in TOLERANCES_PX)
            print(f"  {matcher} {names[i]}/{names[j]}: {len(errors)} matches, {within}")


def radial_fit(camera: CameraIntrinsics, centred: bool) -> CameraIntrinsics:
    """A RADIAL lens with the camera's mean focal length and principal point (the image centre
    where `centred`), k1 and k2 fitted by least squares to its pixels' rays over the image."""
    cam = camera.to_pycolmap()
    xs, ys = np.meshgrid(np.linspace(0, cam.width, 64), np.linspace(0, cam.height, 36))
    pixels = np.c_[xs.ravel(), ys.ravel()]
    rays = np.asarray(cam.cam_from_img(pixels))
    f = cam.mean_focal_length()
    centre = (np.array([cam.width, cam.height]) / 2 if centred
              else np.array([cam.principal_point_x, cam.principal_point_y]))
    r2 = (rays ** 2).sum(1)[:, None]
    design = np.r_[f * rays[:, :1] * np.c_[r2, r2 ** 2], f * rays[:, 1:] * np.c_[r2, r2 ** 2]]
    target = (pixels - centre - f * rays).T.ravel()
    k = np.linalg.lstsq(design, target, rcond=None)[0]
    return CameraIntrinsics("RADIAL", cam.width, cam.height, np.r_[f, centre, k])


def calibrated_with(scene, given: str) -> None:
    cameras = {n: c.intrinsics for n, c in scene.gt.cameras.items()}
    if given != "intrinsics":
        cameras = {n: radial_fit(c, given == "radial-centred") for n, c in cameras.items()}
    config = make_config("regular", "incremental", matcher="asift", second_matcher=None,
                         cameras__known_intrinsics=cameras)
    started = time.perf_counter()
    try:
        with quiet_colmap(min_level=2):
            rig = calibrate_rig(scene.frame_sets, scene.camera_names, config)
    except CalibrationError as exc:
        print(f"  given {given}: refused or failed ({type(exc).__name__}: {str(exc)[:160]})")
        return
    m = evaluate_calibration(rig, scene.gt)
    pairs = ", ".join(f"{p['i']}/{p['j']} {p['rot_err_deg']:.2f}" for p in m["pairs"])
    print(f"  given {given}: AUC@3 {m['auc3']:.1f} (AUC@30 {m['auc30']:.1f}), median rotation "
          f"{m['median_rot_err_deg']:.2f} deg ({pairs}), {time.perf_counter() - started:.0f} s")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("set", choices=sorted(SETS))
    parser.add_argument("--data-dir", type=Path, default=Path("../shared/data"))
    parser.add_argument("--sets", type=int, default=8, help="frame sets (as the bench: 8)")
    parser.add_argument("--matchers", nargs="*", default=["sift", "asift"])
    parser.add_argument("--given", nargs="*", default=["intrinsics", "radial", "radial-centred"],
                        choices=["intrinsics", "radial", "radial-centred"])
    args = parser.parse_args()
    folder, load = SETS[args.set]
    scene = load(args.data_dir / folder, num_sets=args.sets)
    for matcher in args.matchers:
        matches_against_reference(scene, matcher)
    for given in args.given:
        calibrated_with(scene, given)


if __name__ == "__main__":
    main()
