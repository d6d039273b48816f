"""Calibration files: ROS conventions of camera_info, calibration.json round trip, atomic
replace."""
import json

import numpy as np
import pytest
import yaml

from densecalib_ros.core.errors import InputError
from densecalib_ros.core.io.camera_info import camera_info_yaml, ros_camera_info
from densecalib_ros.core.io.export import (calibration_from_dict, calibration_to_dict,
                                           read_calibration, write_calibration_files)
from densecalib_ros.core.io.safe_write import replace_directory_atomic
from densecalib_ros.core.types import (CameraIntrinsics, CameraQuality, RigCalibration, RigCamera,
                                       RigQuality)


def _rig():
    a = CameraIntrinsics("RADIAL", 640, 480, np.array([500.0, 320.0, 240.0, -0.1, 0.02]))
    b = CameraIntrinsics("OPENCV_FISHEYE", 800, 600,
                         np.array([300.0, 301.0, 400.5, 299.5, 0.01, -0.02, 0.003, -0.001]))
    t = np.eye(4)
    t[:3, 3] = [0.5, 0.0, 0.1]
    return RigCalibration("a", {
        "a": RigCamera("a", a, np.eye(4), CameraQuality(0.4, 1000, 0.8, 600)),
        "b": RigCamera("b", b, t, None)}, quality=RigQuality(reprojection_rms_px=np.float64(0.5),
                                                             extra={"hand_written": [1, 2]}))


def test_pinhole_camera_info_uses_ros_pixel_convention_and_plumb_bob():
    info = ros_camera_info("a", _rig().cameras["a"].intrinsics)
    k = info["camera_matrix"]["data"]
    assert k[0] == 500.0 and k[4] == 500.0
    assert k[2] == pytest.approx(319.5) and k[5] == pytest.approx(239.5)  # COLMAP centre - 0.5
    assert info["distortion_model"] == "plumb_bob"
    assert info["distortion_coefficients"]["data"] == [-0.1, 0.02, 0.0, 0.0, 0.0]
    assert info["projection_matrix"]["data"][2] == pytest.approx(319.5)


def test_fisheye_camera_info_is_equidistant_with_four_coefficients():
    info = ros_camera_info("b", _rig().cameras["b"].intrinsics)
    assert info["distortion_model"] == "equidistant"
    assert info["distortion_coefficients"]["data"] == [0.01, -0.02, 0.003, -0.001]
    assert info["camera_matrix"]["data"][2] == pytest.approx(400.0)


def test_camera_info_yaml_parses_back():
    data = yaml.safe_load(camera_info_yaml("b", _rig().cameras["b"].intrinsics))
    assert data["image_width"] == 800 and data["camera_name"] == "b"
    assert data["camera_matrix"]["data"][4] == pytest.approx(301.0)
    assert len(data["distortion_coefficients"]["data"]) == 4


# camera_calibration_parsers' camera_info keys, in the order it writes them, and their shapes
CAMERA_INFO_KEYS = ["image_width", "image_height", "camera_name", "camera_matrix",
                    "distortion_model", "distortion_coefficients", "rectification_matrix",
                    "projection_matrix"]
MATRIX_SHAPES = {"camera_matrix": (3, 3), "rectification_matrix": (3, 3),
                 "projection_matrix": (3, 4)}


def test_camera_info_yaml_reads_back_as_ros_and_opencv_read_it(tmp_path):
    """Written by PyYAML: the keys and types camera_calibration_parsers reads, in its order; a
    coefficient as small as 1e-05 is a number to PyYAML (as text "-1e-05" it was a string: YAML
    1.1 floats need a dot) and to OpenCV's own YAML reader; a camera named 0003 keeps its name."""
    import cv2

    lens = CameraIntrinsics("OPENCV_FISHEYE", 800, 600,
                            np.array([300.25, 301.5, 400.5, 299.5, 0.01, -0.02, 1.5e-05, -1e-05]))
    path = tmp_path / "0003.yaml"
    path.write_text(camera_info_yaml("0003", lens))
    data = yaml.safe_load(path.read_text())
    assert list(data) == CAMERA_INFO_KEYS
    assert data["image_width"] == 800 and data["image_height"] == 600
    assert data["camera_name"] == "0003" and data["distortion_model"] == "equidistant"
    for key, value in data.items():
        if isinstance(value, dict):
            assert list(value) == ["rows", "cols", "data"]
            assert len(value["data"]) == value["rows"] * value["cols"]
            assert all(type(v) is float for v in value["data"]), key
            assert (value["rows"], value["cols"]) == MATRIX_SHAPES.get(key, (1, 4))
    assert data["distortion_coefficients"]["data"] == [0.01, -0.02, 1.5e-05, -1e-05]
    assert data["camera_matrix"]["data"] == [300.25, 0.0, 400.0, 0.0, 301.5, 299.0, 0.0, 0.0, 1.0]
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    node = fs.getNode("distortion_coefficients").getNode("data")
    assert [node.at(i).real() for i in range(node.size())] == [0.01, -0.02, 1.5e-05, -1e-05]
    assert fs.getNode("camera_name").string() == "0003"
    assert int(fs.getNode("image_width").real()) == 800
    fs.release()


def test_unsupported_model_is_refused_with_choices():
    with pytest.raises(InputError, match="RADIAL"):
        ros_camera_info("x", CameraIntrinsics("FOV", 10, 10, np.array([1.0, 1, 5, 5, 0.1])))


def test_calibration_round_trip(tmp_path):
    rig = _rig()
    write_calibration_files(rig, tmp_path)
    back = read_calibration(tmp_path)
    assert back.reference_camera == "a"
    np.testing.assert_allclose(back.cameras["b"].cam_from_rig, rig.cameras["b"].cam_from_rig)
    np.testing.assert_allclose(back.cameras["b"].intrinsics.params, rig.cameras["b"].intrinsics.params)
    assert back.cameras["a"].quality.num_observations == 1000
    assert back.cameras["a"].quality.num_multiview_observations == 600
    assert back.cameras["a"].quality.rotation_std_deg is None
    rig.cameras["a"].quality.rotation_std_deg = 0.05
    write_calibration_files(rig, tmp_path)
    assert read_calibration(tmp_path).cameras["a"].quality.rotation_std_deg == 0.05
    # Files written before the multi-view count was recorded still load.
    data = json.loads((tmp_path / "calibration.json").read_text())
    del data["cameras"]["a"]["quality"]["num_multiview_observations"]
    assert calibration_from_dict(data).cameras["a"].quality.num_multiview_observations is None
    assert (tmp_path / "a.yaml").exists() and (tmp_path / "b.yaml").exists()
    # The quality record: numpy values written as numbers, keys this version does not know (a
    # newer or hand-edited file) kept through a read and a write.
    assert data["quality"] == {"reprojection_rms_px": 0.5, "hand_written": [1, 2]}
    assert back.quality.reprojection_rms_px == 0.5 and back.quality.warnings == []
    assert calibration_to_dict(back)["quality"] == data["quality"]
    with pytest.raises(AttributeError):  # a misspelt field is an error, not a value never saved
        back.quality.reprojection_rms = 0.4
    back.quality.extra["reprojection_rms_px"] = 9.0  # a field's own value wins over extra's
    assert back.quality.to_dict()["reprojection_rms_px"] == 0.5
    # The file says how to read it, and the YAML beside it is what that says: cx 0.5 smaller.
    assert "(0.5, 0.5)" in data["conventions"]["params"]
    assert yaml.safe_load((tmp_path / "a.yaml").read_text())["camera_matrix"]["data"][2] == \
        pytest.approx(data["cameras"]["a"]["params"][1] - 0.5)
    del data["conventions"]  # files written before it still load
    assert calibration_from_dict(data).reference_camera == "a"


def test_a_node_output_dir_reads_as_its_latest_calibration(tmp_path):
    stamped = tmp_path / "20261123T000000Z"
    write_calibration_files(_rig(), stamped)
    (tmp_path / "latest").symlink_to(stamped.name)
    assert read_calibration(tmp_path).reference_camera == "a"


def test_bad_calibration_file_gives_input_error(tmp_path):
    (tmp_path / "calibration.json").write_text('{"cameras": {}}')
    with pytest.raises(InputError, match="reference_camera"):
        read_calibration(tmp_path)
    with pytest.raises(InputError):
        calibration_from_dict({"reference_camera": "a", "cameras": {"a": {"model": "RADIAL"}}})


def test_failed_build_leaves_existing_directory_untouched(tmp_path):
    out = tmp_path / "out"
    replace_directory_atomic(lambda d: write_calibration_files(_rig(), d), out)
    before = (out / "calibration.json").read_text()

    def failing(d):
        (d / "calibration.json").write_text("partial")
        raise RuntimeError("calibration failed")

    with pytest.raises(RuntimeError):
        replace_directory_atomic(failing, out)
    assert (out / "calibration.json").read_text() == before
    assert [p.name for p in tmp_path.iterdir()] == ["out"]  # no temporary left behind
    d = calibration_to_dict(_rig())
    d["reference_camera"] = "b"
    replace_directory_atomic(lambda p: (p / "calibration.json").write_text(json.dumps(d)), out)
    assert read_calibration(out).reference_camera == "b"


@pytest.mark.parametrize("model, params", [
    ("RADIAL", [800.0, 515.0, 380.0, -0.1, 0.02]),
    ("OPENCV", [800.0, 805.0, 515.0, 380.0, -0.1, 0.02, 0.001, -0.002]),
    ("OPENCV_FISHEYE", [400.0, 401.0, 641.0, 478.0, 0.05, -0.02, 0.004, -0.0007])])
def test_opencv_intrinsics_project_as_the_calibration_does(model, params):
    """The library's way to OpenCV: K, D (and which projectPoints) give the pixels that
    core.products.triangulation.project gives from the COLMAP model."""
    import cv2

    from densecalib_ros.core.io.camera_info import opencv_intrinsics
    from densecalib_ros.core.products.triangulation import project

    lens = CameraIntrinsics(model, 1280, 960, np.array(params))
    rig = RigCalibration("a", {"a": RigCamera("a", lens, np.eye(4))})
    xyz = np.random.default_rng(0).uniform([-1, -0.8, 2], [1, 0.8, 4], (20, 3))
    K, D, fisheye = opencv_intrinsics(lens)
    assert fisheye == (model == "OPENCV_FISHEYE")
    if fisheye:
        px = cv2.fisheye.projectPoints(xyz[:, None], np.zeros(3), np.zeros(3), K, D)[0]
    else:
        px = cv2.projectPoints(xyz, np.zeros(3), np.zeros(3), K, D)[0]
    np.testing.assert_allclose(px.reshape(-1, 2), project(rig, "a", xyz), atol=1e-6)
