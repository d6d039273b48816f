"""Exports for other tools (core.products.interchange, `densecalib export`): each file, read back as
those tools read it and projected with OpenCV as they project, gives the pixels COLMAP gives for our
calibration; lens models a format cannot hold are refused."""
import copy
import json
import logging
import tomllib

import cv2
import numpy as np
import pytest
import yaml
from opencv_reference import opencv_pixels
from sfm_fixtures import pose as _pose

from densecalib_ros.cli import main
from densecalib_ros.core.errors import InputError
from densecalib_ros.core.io.export import calibration_to_dict
from densecalib_ros.core.products.interchange import anipose_toml, kalibr_camchain_yaml
from densecalib_ros.core.types import CameraIntrinsics, RigCalibration, RigCamera, RigQuality


@pytest.fixture
def rig():
    cams = {
        "left": RigCamera("left", CameraIntrinsics("RADIAL", 1024, 768,
                                                   np.array([810.0, 515.3, 380.2, -0.12, 0.03])),
                          np.eye(4)),
        "top": RigCamera("top", CameraIntrinsics("OPENCV_FISHEYE", 1280, 960, np.array(
            [402.0, 403.5, 641.0, 478.5, 0.05, -0.02, 0.004, -0.0007])),
            _pose([3, -40, 5], [0.9, 0.05, 0.3])),
        "right": RigCamera("right", CameraIntrinsics("RADIAL", 1024, 768,
                                                     np.array([795.0, 509.9, 385.0, 0.04, -0.01])),
                           _pose([-2, 25, -4], [-0.6, 0.02, 0.1])),
    }
    return RigCalibration("left", cams, quality=RigQuality(reprojection_rms_px=0.8),
                          metric_scale=True)


def _points_seen_by_all(rig, n=200, seed=0):
    """Rig-frame points in front of every camera, within 40 deg of each optical axis."""
    rng = np.random.default_rng(seed)
    pts = rng.uniform([-1, -1, 2], [1, 1, 5], (20 * n, 3))
    ok = np.ones(len(pts), bool)
    for cam in rig.cameras.values():
        x = pts @ cam.cam_from_rig[:3, :3].T + cam.cam_from_rig[:3, 3]
        ok &= np.arccos(x[:, 2] / np.linalg.norm(x, axis=1)) < np.deg2rad(40)
    assert ok.sum() >= n
    return pts[ok][:n]


def _colmap_pixels(cam, pts_rig):
    x = pts_rig @ cam.cam_from_rig[:3, :3].T + cam.cam_from_rig[:3, 3]
    return cam.intrinsics.to_pycolmap().img_from_cam(x) - 0.5  # COLMAP -> OpenCV pixel centres


def test_anipose_toml_projects_like_our_cameras(rig):
    data = tomllib.loads(anipose_toml(rig))
    pts = _points_seen_by_all(rig)
    sections = [data[f"cam_{i}"] for i in range(3)]
    assert [s["name"] for s in sections] == ["left", "top", "right"]
    for section in sections:
        cam = rig.cameras[section["name"]]
        assert section["size"] == [cam.intrinsics.width, cam.intrinsics.height]
        fisheye = section.get("fisheye", False)
        assert fisheye == (cam.intrinsics.model == "OPENCV_FISHEYE")
        assert len(section["distortions"]) == (4 if fisheye else 5)
        got = opencv_pixels(pts, np.array(section["matrix"]), np.array(section["distortions"]),
                            fisheye, np.array(section["rotation"]),
                            np.array(section["translation"]))
        assert np.abs(got - _colmap_pixels(cam, pts)).max() < 1e-6
    assert data["metadata"]["error"] == 0.8


def test_kalibr_camchain_chains_back_to_the_rig(rig):
    data = yaml.safe_load(kalibr_camchain_yaml(rig, "/arena/{name}/image_raw"))
    assert list(data) == ["cam0", "cam1", "cam2"]  # reference first, then the rig's order
    pts = _points_seen_by_all(rig)
    cam_from_rig = np.eye(4)
    for n, name in enumerate(["left", "top", "right"]):
        entry = data[f"cam{n}"]
        cam = rig.cameras[name]
        assert entry["rostopic"] == f"/arena/{name}/image_raw"
        assert entry["resolution"] == [cam.intrinsics.width, cam.intrinsics.height]
        if n:
            cam_from_rig = np.array(entry["T_cn_cnm1"]) @ cam_from_rig
        else:
            assert "T_cn_cnm1" not in entry
        fu, fv, pu, pv = entry["intrinsics"]
        k = np.array([[fu, 0, pu], [0, fv, pv], [0, 0, 1]])
        fisheye = entry["distortion_model"] == "equidistant"
        assert fisheye == (cam.intrinsics.model == "OPENCV_FISHEYE")
        got = opencv_pixels(pts, k, np.array(entry["distortion_coeffs"]), fisheye,
                            cv2.Rodrigues(cam_from_rig[:3, :3])[0], cam_from_rig[:3, 3])
        assert np.abs(got - _colmap_pixels(cam, pts)).max() < 1e-6


def test_kalibr_camchain_keeps_kalibrs_keys_and_numbers(rig):
    """Written by PyYAML: Kalibr's keys and value types (it reads the file with PyYAML), a
    coefficient as small as 1e-05 a number, not the string "1e-05"; T_cn_cnm1 a 4x4 list; the
    header comment names the camera of each camN."""
    rig.cameras["top"].intrinsics.params[6:8] = [1e-05, -2e-06]
    text = kalibr_camchain_yaml(rig)
    assert text.splitlines()[0].endswith("cam0 = left, cam1 = top, cam2 = right")
    data = yaml.safe_load(text)
    for n, entry in enumerate(data.values()):
        assert list(entry) == ["camera_model", "intrinsics", "distortion_model",
                               "distortion_coeffs", "resolution", "rostopic"] + \
            (["T_cn_cnm1"] if n else [])
        assert entry["camera_model"] == "pinhole" and isinstance(entry["rostopic"], str)
        assert all(type(v) is float for v in entry["intrinsics"] + entry["distortion_coeffs"])
        assert all(type(v) is int for v in entry["resolution"])
        if n:
            assert np.array(entry["T_cn_cnm1"], dtype=float).shape == (4, 4)
    assert data["cam1"]["distortion_coeffs"][2:] == [1e-05, -2e-06]


def test_kalibr_topics_must_be_ros_names(rig):
    """Cameras named by numbers (Strecha's 0003) or with spaces would give Kalibr topics no ROS
    bag can have: refused with the way out."""
    numbered = copy.deepcopy(rig)
    numbered.cameras = {f"{i:04d}": c for i, c in enumerate(rig.cameras.values())}
    numbered.reference_camera = "0000"
    with pytest.raises(InputError, match="'/0000/image_raw'.*--topic-pattern"):
        kalibr_camchain_yaml(numbered)
    assert "/cam_0001/image_raw" in kalibr_camchain_yaml(numbered, "/cam_{name}/image_raw")
    with pytest.raises(InputError, match="left: '/my cams/left'"):
        kalibr_camchain_yaml(rig, "/my cams/{name}")
    with pytest.raises(InputError, match="gives several cameras the topic '/cam/image_raw'"):
        kalibr_camchain_yaml(rig, "/cam/image_raw")  # no {name}: one topic for every camera


def test_models_a_format_cannot_hold_are_refused(rig):
    rig.cameras["top"].intrinsics = CameraIntrinsics("FULL_OPENCV", 640, 480,
                                                     np.r_[500.0, 500, 320, 240, np.full(8, 0.01)])
    with pytest.raises(InputError, match="top .*FULL_OPENCV.*anipose cannot hold"):
        anipose_toml(rig)
    with pytest.raises(InputError, match="kalibr cannot hold"):
        kalibr_camchain_yaml(rig)


def test_export_command(rig, tmp_path, capsys, caplog):
    calib = tmp_path / "calibration.json"
    calib.write_text(json.dumps(calibration_to_dict(rig)))
    out = tmp_path / "arena" / "calibration.toml"
    assert main(["export", str(calib), "--format", "anipose", "--out", str(out)]) == 0
    assert tomllib.loads(out.read_text())["cam_2"]["name"] == "right"
    assert "wrote" in capsys.readouterr().out
    with caplog.at_level(logging.ERROR):
        assert main(["export", str(tmp_path / "none"), "--format", "kalibr",
                     "--out", str(tmp_path / "c.yaml")]) == 2
    assert not (tmp_path / "c.yaml").exists()


def test_opencv_files_load_in_opencv_and_read_back_as_given_intrinsics(rig, tmp_path, capsys):
    """`densecalib export --format opencv`: each <camera>.yml, loaded with cv2.FileStorage as
    OpenCV programs load it and projected with its R, T by OpenCV, gives our pixels; the folder
    reads back as given intrinsics (--intrinsics DIR) with the same projections."""
    from densecalib_ros.core.method.known_intrinsics import read_known_intrinsics

    calib = tmp_path / "calibration.json"
    calib.write_text(json.dumps(calibration_to_dict(rig)))
    out = tmp_path / "opencv"
    assert main(["export", str(calib), "--format", "opencv", "--out", str(out)]) == 0
    assert "left.yml, top.yml, right.yml" in capsys.readouterr().out
    pts = _points_seen_by_all(rig)
    for name, cam in rig.cameras.items():
        fs = cv2.FileStorage(str(out / f"{name}.yml"), cv2.FILE_STORAGE_READ)
        size = (int(fs.getNode("image_width").real()), int(fs.getNode("image_height").real()))
        fisheye = bool(int(fs.getNode("fisheye_model").real()))
        got = opencv_pixels(pts, fs.getNode("camera_matrix").mat(),
                            fs.getNode("distortion_coefficients").mat(), fisheye,
                            cv2.Rodrigues(fs.getNode("R").mat())[0], fs.getNode("T").mat())
        fs.release()
        assert size == (cam.intrinsics.width, cam.intrinsics.height)
        assert fisheye == (cam.intrinsics.model == "OPENCV_FISHEYE")
        assert np.abs(got - _colmap_pixels(cam, pts)).max() < 1e-6
    known = read_known_intrinsics([str(out)])
    assert sorted(known) == ["left", "right", "top"]
    for name, cam in rig.cameras.items():
        x = pts @ cam.cam_from_rig[:3, :3].T + cam.cam_from_rig[:3, 3]
        np.testing.assert_allclose(known[name].to_pycolmap().img_from_cam(x),
                                   cam.intrinsics.to_pycolmap().img_from_cam(x), atol=1e-6)
    (tmp_path / "f.yml").write_text("x")
    assert main(["export", str(calib), "--format", "opencv", "--out",
                 str(tmp_path / "f.yml")]) == 2


def test_export_into_a_folder_names_files_of_an_earlier_export(rig, tmp_path, caplog):
    """A camera dropped since the last export leaves its file behind: the export says so (a tool
    loading every .yml would take it for a camera) and deletes nothing."""
    calib = tmp_path / "calibration.json"
    calib.write_text(json.dumps(calibration_to_dict(rig)))
    out = tmp_path / "opencv"
    out.mkdir()
    (out / "old_cam.yml").write_text("%YAML:1.0\n")
    (out / "notes.txt").write_text("mine")
    with caplog.at_level(logging.WARNING):
        assert main(["export", str(calib), "--format", "opencv", "--out", str(out)]) == 0
    assert "also holds old_cam.yml" in caplog.text and "notes.txt" not in caplog.text
    assert sorted(p.name for p in out.iterdir()) == ["left.yml", "notes.txt", "old_cam.yml",
                                                     "right.yml", "top.yml"]
    caplog.clear()
    (out / "old_cam.yml").unlink()
    with caplog.at_level(logging.WARNING):
        assert main(["export", str(calib), "--format", "opencv", "--out", str(out)]) == 0
    assert "also holds" not in caplog.text


def _matlab_pixels(pts_world, params):
    """MATLAB's worldToImage with its cameraParameters (what DANNCE reimplements): row vectors
    x_cam = X r + t, then MATLAB's radial-tangential distortion, then [x y 1] K; 1-based."""
    x_cam = pts_world @ params["r"] + params["t"]
    x, y = x_cam[:, 0] / x_cam[:, 2], x_cam[:, 1] / x_cam[:, 2]
    k = np.zeros(3)
    k[:params["RDistort"].size] = params["RDistort"].ravel()
    p1, p2 = params["TDistort"].ravel()
    r2 = x * x + y * y
    radial = 1 + k[0] * r2 + k[1] * r2 ** 2 + k[2] * r2 ** 3
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return (np.column_stack([xd, yd, np.ones_like(xd)]) @ params["K"])[:, :2]


def _export_pinholes_on_a_floor(rig, tmp_path, fmt):
    """The rig without its fisheye camera, given a floor, exported as fmt: (calibration.json,
    the export folder, rig-frame points all cameras see, those points in the floor frame in mm)."""
    del rig.cameras["top"]
    floor_from_rig = _pose([-100, 10, 0], [0.2, -1.5, 0.1])
    rig.quality.floor = {"floor_from_rig": floor_from_rig.ravel().tolist(), "num_points": 1,
                            "rms": 0.0, "camera_heights": {}}
    calib = tmp_path / "calibration.json"
    calib.write_text(json.dumps(calibration_to_dict(rig)))
    out = tmp_path / fmt
    assert main(["export", str(calib), "--format", fmt, "--out", str(out)]) == 0
    pts_rig = _points_seen_by_all(rig)
    return (calib, out, pts_rig,
            1000.0 * (pts_rig @ floor_from_rig[:3, :3].T + floor_from_rig[:3, 3]))


def test_dannce_files_project_like_our_cameras_in_matlab_convention(rig, tmp_path, capsys,
                                                                    caplog):
    """Each camera's hires_cam<i>_params.mat, read back with scipy and projected with MATLAB's
    model (independently of ours), lands where our camera puts the point, +1 px (MATLAB's
    pixels are 1-based); t is in mm; the world is the floor frame when there is one; a fisheye
    camera is refused with what to do."""
    from scipy.io import loadmat

    from densecalib_ros.core.products.interchange import dannce_files

    with pytest.raises(InputError, match="top has a fisheye lens.*undistort"):
        dannce_files(rig)
    calib, out, pts_rig, pts_floor_mm = _export_pinholes_on_a_floor(rig, tmp_path, "dannce")
    assert "hires_cam1_params.mat, hires_cam2_params.mat" in capsys.readouterr().out
    assert "hires_cam2_params.mat = Camera2 = right" in (out / "cameras.txt").read_text()
    for i, name in enumerate(["left", "right"], start=1):
        params = loadmat(out / f"hires_cam{i}_params.mat")
        assert params["t"].shape == (1, 3) and params["TDistort"].shape == (1, 2)
        got = _matlab_pixels(pts_floor_mm, params)
        assert np.abs(got - (_colmap_pixels(rig.cameras[name], pts_rig) + 1.0)).max() < 1e-6

    rig.metric_scale = False
    calib.write_text(json.dumps(calibration_to_dict(rig)))
    with caplog.at_level(logging.WARNING):
        assert main(["export", str(calib), "--format", "dannce", "--out", str(out)]) == 0
    assert "no metric scale" in caplog.text


def _jarvis_pixels(pts_world, calib_file):
    """JARVIS's reprojection (jarvis/utils/reprojection.py, re-derived here): its files read with
    cv2.FileStorage, cameraMatrix = [R; T'] intrinsicMatrix on row vectors, then radial k1, k2 on
    the pixel offsets from the principal point scaled by the focal lengths; 0-based pixels."""
    fs = cv2.FileStorage(str(calib_file), cv2.FILE_STORAGE_READ)
    r, t = fs.getNode("R").mat(), fs.getNode("T").mat().reshape(1, 3)
    k, dist = fs.getNode("intrinsicMatrix").mat(), fs.getNode("distortionCoefficients").mat()
    fs.release()
    homogeneous = np.column_stack([pts_world, np.ones(len(pts_world))]) @ np.vstack([r, t]) @ k
    dx = homogeneous[:, 0] / homogeneous[:, 2] - k[2, 0]
    dy = homogeneous[:, 1] / homogeneous[:, 2] - k[2, 1]
    r2 = (dx / k[0, 0]) ** 2 + (dy / k[1, 1]) ** 2
    distort = 1 + (dist[0, 0] + dist[0, 1] * r2) * r2
    return np.column_stack([dx * distort + k[2, 0], dy * distort + k[2, 1]])


def test_jarvis_files_project_like_our_cameras(rig, tmp_path, capsys, caplog):
    """Each camera's <camera>.yaml, projected as JARVIS does (k1, k2 only), lands where our
    camera puts the point (RADIAL cameras: exactly); T is in mm in the floor frame; a fisheye is
    refused; distortion JARVIS leaves out is named."""
    from densecalib_ros.core.products.interchange import jarvis_files

    with pytest.raises(InputError, match="top has a fisheye lens, which JARVIS's"):
        jarvis_files(rig)
    calib, out, pts_rig, pts_floor_mm = _export_pinholes_on_a_floor(rig, tmp_path, "jarvis")
    assert "left.yaml, right.yaml" in capsys.readouterr().out
    for name in ("left", "right"):
        got = _jarvis_pixels(pts_floor_mm, out / f"{name}.yaml")
        assert np.abs(got - _colmap_pixels(rig.cameras[name], pts_rig)).max() < 1e-6
    # an OPENCV camera with tangential distortion: written, and the loss named
    rig.cameras["right"].intrinsics = CameraIntrinsics(
        "OPENCV", 1024, 768, np.array([795.0, 797.0, 509.9, 385.0, 0.04, -0.01, 1e-3, -2e-3]))
    calib.write_text(json.dumps(calibration_to_dict(rig)))
    with caplog.at_level(logging.WARNING):
        assert main(["export", str(calib), "--format", "jarvis", "--out", str(out)]) == 0
    assert "distortion of right are left out" in caplog.text
