"""The arena path end to end (issue 81): an animal's keypoints as DeepLabCut and SLEAP write them,
`densecalib calibrate --keypoints` in a real process, `densecalib export --format anipose`, and
the file read by aniposelib itself (installed without its declared dependencies,
requirements-nodeps.txt: it imports with our OpenCV, and needs neither jax nor opencv-contrib to
load a calibration and project; 0.8.0's triangulate imports jax, so its DLT is written out here),
its cameras held against the generated rig's truth. Then plain arena walls, where image matching
finds nothing and the keypoints carry the calibration."""
import subprocess
import sys

import cv2
import numpy as np
from aniposelib.cameras import CameraGroup

from densecalib_ros.core.io.export import read_calibration
from keypoint_fixtures import arena, write_dlc, write_slp

# What the cameras must come out within: 1.5 px keypoint noise on 640 px images, 3 cameras 65-90
# deg apart, 300 frames; measured on 4 such rigs 0.39-0.89 deg and 1.4-1.9 % (their focal
# lengths 1.2-2.3 % loose at 1 sigma, which the calibration warns of); a calibration that went
# wrong is degrees off (an animal crossing only the middle of the images: 9 deg, 33 %).
MAX_ROTATION_DEG = 1.5
MAX_FOCAL_ERROR = 0.04


def _cli(*args):
    return subprocess.run([sys.executable, "-m", "densecalib_ros.cli", *map(str, args)],
                          capture_output=True, text=True, timeout=900)


def _errors(group: CameraGroup, walk) -> tuple[float, float]:
    """(largest pair rotation error deg, largest focal error as a fraction) of aniposelib's
    cameras against the truth."""
    truth = walk.rig.ground_truth().cameras
    cams = {cam.get_name(): cam for cam in group.cameras}
    assert sorted(cams) == sorted(truth)
    rot = {n: cv2.Rodrigues(np.asarray(c.get_rotation(), float))[0] for n, c in cams.items()}
    worst_deg = 0.0
    for a in cams:
        for b in cams:
            if a < b:
                est = rot[b] @ rot[a].T
                true = truth[b].cam_from_rig[:3, :3] @ truth[a].cam_from_rig[:3, :3].T
                cos = (np.trace(est @ true.T) - 1) / 2
                worst_deg = max(worst_deg, np.degrees(np.arccos(np.clip(cos, -1, 1))))
    focal = max(abs(cams[n].get_camera_matrix()[0, 0] / truth[n].intrinsics.params[0] - 1)
                for n in cams)
    return worst_deg, focal


def _anipose(out, tmp_path):
    done = _cli("export", out, "--format", "anipose", "--out", tmp_path / "calibration.toml")
    assert done.returncode == 0, done.stderr[-3000:]
    return CameraGroup.load(str(tmp_path / "calibration.toml"))


def test_deeplabcut_keypoints_alone_calibrate_an_arena_that_aniposelib_reads(tmp_path):
    walk = arena(seed=11, num_cameras=3, gap_deg=65, frames=300)
    write_dlc(walk, tmp_path / "pose-2d", "h5")
    out = tmp_path / "calib"
    done = _cli("calibrate", "--keypoints", tmp_path / "pose-2d", "--image-size", "640x480",
                "--out", out)
    assert done.returncode == 0, done.stderr[-3000:]
    rig = read_calibration(out)
    assert rig.quality.input["source"] == "keypoints"
    assert rig.quality.input["keypoints"]["tool"] == ["DeepLabCut"]
    group = _anipose(out, tmp_path)
    worst_deg, focal = _errors(group, walk)
    assert worst_deg < MAX_ROTATION_DEG and focal < MAX_FOCAL_ERROR, (worst_deg, focal)
    # anipose's own triangulation of the keypoints reprojects within their noise
    names = [cam.get_name() for cam in group.cameras]
    order = [walk.rig.names.index(n) for n in names]
    points_2d = walk.xy_px[order].reshape(len(order), -1, 2)
    confident = (walk.likelihood[order] >= 0.6).reshape(len(order), -1)
    points_2d = np.where(confident[..., None], points_2d, np.nan)
    seen_by_all = np.isfinite(points_2d[..., 0]).all(axis=0)
    p3d = _triangulate(group, points_2d[:, seen_by_all])
    errors = np.linalg.norm(group.project(p3d) - points_2d[:, seen_by_all], axis=-1)
    assert np.median(errors) < 3.0, np.median(errors)


def _triangulate(group: CameraGroup, points_2d: np.ndarray) -> np.ndarray:
    """(N, 3) points from (C, N, 2) pixels as aniposelib's CameraGroup.triangulate does it
    (undistort_points, then triangulate_simple's DLT on get_extrinsics_mat), in numpy: 0.8.0
    runs that DLT in jax, which its loading and projecting do not need and we do not install."""
    rays = np.stack([cam.undistort_points(points_2d[c].astype(np.float64))
                     for c, cam in enumerate(group.cameras)])
    mats = np.stack([cam.get_extrinsics_mat() for cam in group.cameras])
    rows = rays[..., None] * mats[:, None, 2:3, :] - mats[:, None, 0:2, :]  # (C, N, 2, 4)
    A = rows.transpose(1, 0, 2, 3).reshape(points_2d.shape[1], -1, 4)
    p = np.linalg.svd(A)[2][:, -1]
    return p[:, :3] / p[:, 3:]


def test_plain_arena_walls_calibrate_from_sleap_keypoints_beside_the_images(tmp_path):
    walk = arena(seed=12, num_cameras=3, gap_deg=70, frames=300)
    images = tmp_path / "images"
    images.mkdir()
    rng = np.random.default_rng(0)
    for name in walk.rig.names:  # white walls: no texture for a matcher to find
        plain = np.full((480, 640, 3), 170, np.uint8) + rng.integers(0, 2, (480, 640, 3),
                                                                     dtype=np.uint8)
        cv2.imwrite(str(images / f"{name}.png"), plain)
    refused = _cli("calibrate", "--images", images, "--out", tmp_path / "without")
    assert refused.returncode == 1, refused.stderr[-2000:]  # the images alone give nothing

    (tmp_path / "sleap").mkdir()
    for c, name in enumerate(walk.rig.names):
        write_slp(tmp_path / "sleap" / f"{name}.predictions.slp", walk.xy_px[c][:, None],
                  walk.likelihood[c][:, None], f"{name}.mp4", (640, 480))
    out = tmp_path / "calib"
    done = _cli("calibrate", "--images", images, "--keypoints", tmp_path / "sleap", "--out", out)
    assert done.returncode == 0, done.stderr[-3000:]
    assert "the keypoints carry the run" in done.stderr
    worst_deg, focal = _errors(_anipose(out, tmp_path), walk)
    assert worst_deg < MAX_ROTATION_DEG and focal < MAX_FOCAL_ERROR, (worst_deg, focal)


def test_keypoints_of_a_camera_the_images_do_not_have_are_refused(tmp_path):
    walk = arena(seed=13, num_cameras=3, gap_deg=40, frames=20)
    write_dlc(walk, tmp_path / "pose")
    (tmp_path / "pose" / "cam1DLC_resnet50_arenaDec1shuffle1_100000.csv").rename(
        tmp_path / "pose" / "side.csv")
    done = _cli("calibrate", "--keypoints", tmp_path / "pose", "--out", tmp_path / "out")
    assert done.returncode == 2
    assert "image size" in done.stderr and "--image-size" in done.stderr
    done = _cli("calibrate", "--keypoints", tmp_path / "pose", "--image-size", "640x480",
                "--keypoint-frame-offset", "cam9=3", "--out", tmp_path / "out")
    assert done.returncode == 2 and "cam9" in done.stderr and "side" in done.stderr
    done = _cli("calibrate", "--keypoints", tmp_path / "pose", "--image-size", "640x480",
                "--time-offset", "cam0=1", "--out", tmp_path / "out")
    assert done.returncode == 2 and "--time-offset belong(s) to the images" in done.stderr
