"""Given intrinsics (lab camera_info YAML, a previous calibration): read in every form a user has
them, checked against the images, and held exactly while the extrinsics are calibrated."""
import json
import logging
import os
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np
import pytest
from opencv_reference import opencv_pixels

from densecalib_ros.cli import main
from densecalib_ros.core.config import make_config
from densecalib_ros.core.errors import InputError
from densecalib_ros.core.io.camera_info import camera_info_yaml
from densecalib_ros.core.io.export import read_calibration
from densecalib_ros.core.method.known_intrinsics import (check_known_intrinsics,
                                                         intrinsics_from_camera_info,
                                                         read_known_intrinsics)
from densecalib_ros.core.method.plausibility import UNLIKE_LENS_PREFIX
from densecalib_ros.core.metrics import evaluate_calibration
from densecalib_ros.core import run_calibration
from densecalib_ros.core.synthetic import RigSpec, generate_rig, write_rig
from densecalib_ros.core.types import CameraIntrinsics

# A camera_info YAML as ROS camera_calibration writes it (plumb_bob with 4 coefficients, a
# namespaced camera_name), cf. image_pipeline's calibration data.
LAB_YAML = """image_width: 800
image_height: 503
camera_name: narrow_stereo/left
camera_matrix:
  rows: 3
  cols: 3
  data: [290.738946, 0.000000, 399.936425, 0.000000, 290.825658, 273.618354, 0.0, 0.0, 1.0]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 4
  data: [-0.054041, 0.008165, -0.007240, 0.001573]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]
"""


def _rays(n=200, seed=0, max_angle_deg=40.0):
    rng = np.random.default_rng(seed)
    xy = rng.uniform(-1, 1, (n, 2)) * np.tan(np.radians(max_angle_deg))
    return np.column_stack([xy, np.ones(n)])


@pytest.mark.parametrize("model, params", [
    ("PINHOLE", [500.0, 505.0, 320.5, 240.5]),
    ("RADIAL", [500.0, 322.0, 238.0, -0.12, 0.03]),
    ("OPENCV", [500.0, 498.0, 322.0, 238.0, -0.12, 0.03, 0.001, -0.002]),
    ("FULL_OPENCV", [500.0, 498.0, 322.0, 238.0, -0.1, 0.02, 0.001, -0.002, 0.004, 0.01, 0.0,
                     0.002]),
    ("OPENCV_FISHEYE", [200.0, 201.0, 321.0, 239.0, 0.05, -0.01, 0.002, -0.0005])])
def test_camera_info_we_write_reads_back_to_the_same_projection(model, params):
    """Our own <camera>.yaml (ROS pixel convention) reads back to a model projecting every ray
    to the same COLMAP pixel (RADIAL comes back as OPENCV, its general form)."""
    import yaml

    cam = CameraIntrinsics(model, 640, 480, np.array(params))
    back = intrinsics_from_camera_info(yaml.safe_load(camera_info_yaml("c", cam)))
    assert (back.width, back.height) == (640, 480)
    rays = _rays(max_angle_deg=60.0 if "FISHEYE" in model else 35.0)
    np.testing.assert_allclose(back.to_pycolmap().img_from_cam(rays),
                               cam.to_pycolmap().img_from_cam(rays), atol=1e-9)


def test_lab_camera_info_files_folders_and_calibrations_are_read(tmp_path):
    import yaml

    (tmp_path / "left.yaml").write_text(LAB_YAML)
    known = read_known_intrinsics([str(tmp_path / "left.yaml")])
    cam = known["left"]  # the last component of camera_name
    assert cam.model == "OPENCV" and (cam.width, cam.height) == (800, 503)
    np.testing.assert_allclose(cam.params, [290.738946, 290.825658, 400.436425, 274.118354,
                                            -0.054041, 0.008165, -0.007240, 0.001573])
    assert list(read_known_intrinsics([f"cam2={tmp_path / 'left.yaml'}"])) == ["cam2"]
    fisheye = tmp_path / "fish" / "right.yaml"
    fisheye.parent.mkdir()
    fisheye.write_text(LAB_YAML.replace("plumb_bob", "equidistant").replace(
        "narrow_stereo/left", ""))
    folder = read_known_intrinsics([str(fisheye.parent)])
    assert folder["right"].model == "OPENCV_FISHEYE"  # no camera_name: the file stem
    (fisheye.parent / "again.yaml").write_text(fisheye.read_text().replace(
        "camera_name: \n", "camera_name: right\n").replace("cols: 4", "cols: 5").replace(
        "0.001573]", "0.001573, 0.0]"))  # a fifth, zero coefficient: accepted
    assert read_known_intrinsics([str(fisheye.parent / "again.yaml")])["right"].params[-1] \
        == 0.001573
    with pytest.raises(InputError, match="Two files in .* are for camera 'right'"):
        read_known_intrinsics([str(fisheye.parent)])
    k3 = tmp_path / "k3.yaml"  # plumb_bob with k3: FULL_OPENCV, written back as plumb_bob
    k3.write_text(LAB_YAML.replace("cols: 4", "cols: 5").replace("0.001573]", "0.001573, 0.02]"))
    with_k3 = read_known_intrinsics([str(k3)])["left"]
    assert with_k3.model == "FULL_OPENCV" and with_k3.params[8] == 0.02
    written = yaml.safe_load(camera_info_yaml("left", with_k3))
    assert written["distortion_model"] == "plumb_bob"
    assert written["distortion_coefficients"]["data"] == [-0.054041, 0.008165, -0.00724,
                                                          0.001573, 0.02]
    none = tmp_path / "none.yaml"
    none.write_text(LAB_YAML.replace("[-0.054041, 0.008165, -0.007240, 0.001573]", "[]"))
    assert read_known_intrinsics([str(none)])["left"].model == "PINHOLE"
    # A densecalib calibration (file or folder): every camera in it.
    calib = {"reference_camera": "a", "cameras": {
        n: {"model": "RADIAL", "params": [500.0, 320.0, 240.0, 0.01, 0.0], "width": 640,
            "height": 480, "cam_from_rig": np.eye(4).ravel().tolist()} for n in ("a", "b")}}
    (tmp_path / "calib").mkdir()
    (tmp_path / "calib" / "calibration.json").write_text(json.dumps(calib))
    assert sorted(read_known_intrinsics([str(tmp_path / "calib")])) == ["a", "b"]
    assert read_known_intrinsics([str(tmp_path / "calib" / "calibration.json")])["b"].model \
        == "RADIAL"
    # A previous calibration of more cameras than the rig has now: the rig's cameras only.
    assert list(read_known_intrinsics([str(tmp_path / "calib")], ["b", "c"])) == ["b"]
    with pytest.raises(InputError, match="none of the cameras c, d: name each file's camera"):
        read_known_intrinsics([str(tmp_path / "calib")], ["c", "d"])


@pytest.mark.parametrize("text, specs, message", [
    (LAB_YAML.replace("plumb_bob", "tele"), ["{f}"], "distortion_model 'tele' is not supported"),
    (LAB_YAML.replace("image_width: 800\n", ""), ["{f}"], "not a camera_info YAML"),
    (LAB_YAML.replace("290.738946", "0.0"), ["{f}"], "must be positive"),
    (LAB_YAML, ["{f}", "{f}"], "given twice"),
    (LAB_YAML, ["{d}/nope.yaml"], "does not exist"),
    (LAB_YAML, ["x={d}/calib"], "NAME= applies to a single-camera file"),
    ("%YAML:1.0\n---\nimage_width: 640\n", ["{f}"], "has no 3x3 camera matrix"),
    ("%YAML:1.0\n---\ncamera_matrix: [ 1, 2\n", ["{f}"], "Cannot read OpenCV calibration")])
def test_unusable_intrinsics_files_are_refused_with_what_to_do(tmp_path, text, specs, message):
    f = tmp_path / "cam.yaml"
    f.write_text(text)
    (tmp_path / "calib").mkdir()
    (tmp_path / "calib" / "a.yaml").write_text(LAB_YAML)
    (tmp_path / "calib" / "b.yaml").write_text(LAB_YAML.replace("narrow_stereo/left", "right"))
    with pytest.raises(InputError, match=message):
        read_known_intrinsics([s.format(f=f, d=tmp_path) for s in specs])


def test_intrinsics_must_fit_the_cameras_and_their_images():
    cam = CameraIntrinsics("OPENCV", 800, 503, np.array([290.0, 290.0, 400.0, 270.0, -0.05, 0.0,
                                                         0.0, 0.0]))
    check_known_intrinsics({"left": cam}, ["left", "right"], [(800, 503), (800, 503)])
    with pytest.raises(InputError, match="unknown camera"):
        check_known_intrinsics({"middle": cam}, ["left", "right"], [(800, 503), (800, 503)])
    with pytest.raises(InputError, match="are for 800x503 images, its images are 640x400"):
        check_known_intrinsics({"left": cam}, ["left", "right"], [(640, 400), (800, 503)])
    folding = CameraIntrinsics("RADIAL", 800, 503, np.array([290.0, 400.0, 270.0, -0.6, 0.0]))
    with pytest.raises(InputError, match="not usable"):
        check_known_intrinsics({"left": folding}, ["left", "right"], [(800, 503), (800, 503)])


@pytest.fixture(scope="module")
def rig():
    return generate_rig(RigSpec(lenses="ideal", num_cameras=4, camera_model="RADIAL", width=640, height=480,
                                seed=0))


@pytest.mark.parametrize("pipeline", ["incremental", "global"])
def test_given_intrinsics_are_held_exactly_and_the_rest_is_calibrated(rig, pipeline):
    """Every camera given: the result has exactly those intrinsics and the right poses. One
    camera given: it is held, the others are self-calibrated around it."""
    gt = rig.ground_truth()
    for given in (rig.names, rig.names[1:2]):
        known = {n: gt.cameras[n].intrinsics for n in given}
        config = make_config("regular", pipeline, matcher="sift", sfm__num_threads=1,
                             consensus_runs=1, cameras__known_intrinsics=known)
        messages = []
        result = run_calibration([rig.images[0]], rig.names, config, progress=messages.append)
        # every camera given: the multi-start explores first pairs instead of focals
        assert any("given, first pair cam" in m for m in messages) == (len(given) == 4)
        for n in given:
            cam = result.rig.cameras[n]
            assert cam.intrinsics.model == known[n].model
            np.testing.assert_array_equal(cam.intrinsics.params, known[n].params)
            assert cam.quality.focal_std_px is None  # nothing estimated
        assert result.rig.quality.given_intrinsics == {n: "RADIAL" for n in sorted(given)}
        metrics = evaluate_calibration(result.rig, gt)
        assert metrics["num_registered"] == 4 and metrics["auc3"] >= 80.0
        assert metrics["median_focal_err"] <= 0.02
        free = [n for n in rig.names if n not in given]
        assert all(result.rig.cameras[n].quality.focal_std_px > 0 for n in free)
        # the right intrinsics fit the scene: judged, and no warning
        assert set(result.rig.quality.given_intrinsics_fit) == set(given)
        assert not result.rig.quality.warnings


def test_given_intrinsics_the_scene_contradicts_are_named(rig):
    """Two cameras' files 10 % off in focal: still held (the user's choice), but the calibration
    warns, naming them, since freed they fit the scene clearly better."""
    gt = rig.ground_truth()
    known = {}
    for n in rig.names[:2]:
        cam = gt.cameras[n].intrinsics
        params = cam.params.copy()
        params[0] *= 0.9
        known[n] = CameraIntrinsics(cam.model, cam.width, cam.height, params)
    config = make_config("regular", matcher="sift", sfm__num_threads=1, consensus_runs=1,
                         cameras__known_intrinsics=known)
    result = run_calibration([rig.images[0]], rig.names, config)
    np.testing.assert_array_equal(result.rig.cameras["cam0"].intrinsics.params,
                                  known["cam0"].params)
    fit = result.rig.quality.given_intrinsics_fit
    assert all(fit[n]["median_px"] > 1.3 * fit[n]["median_px_refined"] for n in known)
    assert all(fit[n]["focal_change_pct"] > 5.0 for n in known)
    warning, *others = result.rig.quality.warnings
    assert warning.startswith("The given intrinsics do not fit the scene") and \
        "cam0 from" in warning and "cam1 from" in warning
    # The self-calibrated cameras absorb what the wrong files contradict: one that ends with
    # intrinsics no real lens has is named too (cam3 here: principal point 10-13 % off-centre),
    # and so is its rotation, left that loose (sigma 5.3 deg).
    named = [w.split(" (relative to")[0] for w in others]  # cam0 is the rig's reference
    assert len(others) <= 2 and all(
        w.startswith((UNLIKE_LENS_PREFIX, "cameras placed loosely")) and "cam0" not in w
        and "cam1" not in w for w in named)


def test_a_given_fisheye_camera_makes_a_rig_mixing_lenses():
    """A fisheye camera's intrinsics given under the regular preset: its lens follows from the
    model (no --lens needed), it is held, the pinhole cameras are calibrated with the perspective
    model (OPENCV: the refinement on the images frees their pixel aspect)."""
    models = ("RADIAL", "OPENCV_FISHEYE", "RADIAL", "RADIAL")
    rig = generate_rig(RigSpec(lenses="ideal", num_cameras=4, camera_models=models, width=640, height=480,
                               seed=0))
    gt = rig.ground_truth()
    known = {"cam1": gt.cameras["cam1"].intrinsics}
    config = make_config("regular", matcher="sift", sfm__num_threads=1, consensus_runs=1,
                         cameras__known_intrinsics=known)
    result = run_calibration([rig.images[0]], rig.names, config)
    assert [result.rig.cameras[n].intrinsics.model for n in rig.names] == [
        "OPENCV", "OPENCV_FISHEYE", "OPENCV", "OPENCV"]
    np.testing.assert_array_equal(result.rig.cameras["cam1"].intrinsics.params,
                                  known["cam1"].params)
    metrics = evaluate_calibration(result.rig, gt)
    assert metrics["num_registered"] == 4 and metrics["auc3"] >= 80.0
    with pytest.raises(InputError, match="another lens than --lens says"):
        run_calibration([rig.images[0]], rig.names,
                        make_config("regular", cameras__known_intrinsics=known,
                                    cameras__lens={"cam1": "pinhole"}))


def test_calibrate_command_keeps_the_lab_intrinsics_it_is_given(tmp_path, capsys, caplog):
    rig = generate_rig(RigSpec(lenses="ideal", num_cameras=3, camera_model="RADIAL", width=640, height=480,
                               seed=3))
    write_rig(rig, tmp_path / "rig")
    gt = rig.ground_truth()
    # The lab files: camera_info YAMLs as ROS writes them (camera_name = the camera).
    for n in ("cam0", "cam2"):
        (tmp_path / f"{n}.yaml").write_text(camera_info_yaml(n, gt.cameras[n].intrinsics))
    out = tmp_path / "out"
    rc = main(["calibrate", "--images", str(tmp_path / "rig"), "--out", str(out), "--threads",
               "1", "--consensus-runs", "1", "--intrinsics", str(tmp_path / "cam0.yaml"),
               f"cam2={tmp_path / 'cam2.yaml'}"])
    assert rc == 0
    calib = read_calibration(out)
    rays = _rays()
    for n in ("cam0", "cam2"):  # RADIAL -> camera_info -> OPENCV: the same projection
        assert calib.cameras[n].intrinsics.model == "OPENCV"
        np.testing.assert_allclose(calib.cameras[n].intrinsics.to_pycolmap().img_from_cam(rays),
                                   gt.cameras[n].intrinsics.to_pycolmap().img_from_cam(rays),
                                   atol=1e-9)
    assert calib.cameras["cam1"].intrinsics.model == "OPENCV"  # fx, fy of the image refinement
    assert evaluate_calibration(calib, gt)["auc3"] >= 80.0
    rows = {}  # camera -> its lines: the camera table's intrinsics row, then its fit row
    for line in capsys.readouterr().out.splitlines():
        rows.setdefault(line.split()[0] if line.strip() else "", []).append(line.split())
    intrinsics = {n: dict(zip(rows["camera"][-2], rows[n][-2])) for n in ("cam0", "cam1", "cam2")}
    fit = {n: dict(zip(rows["camera"][-1], rows[n][-1])) for n in ("cam0", "cam1", "cam2")}
    assert intrinsics["cam0"]["f_std"] == intrinsics["cam2"]["pp_from"] == "given"
    assert "given" not in intrinsics["cam1"].values()
    rms = {n: float(fit[n]["rms_px"]) for n in ("cam0", "cam1", "cam2")}
    assert rms == {n: round(calib.cameras[n].quality.reprojection_rms_px, 2) for n in rms}
    # Intrinsics of another resolution: refused before matching, nothing written.
    small = gt.cameras["cam0"].intrinsics
    (tmp_path / "small.yaml").write_text(camera_info_yaml("cam0", CameraIntrinsics(
        small.model, 320, 240, small.params / 2)))
    with caplog.at_level(logging.ERROR):
        rc = main(["calibrate", "--images", str(tmp_path / "rig"), "--out", str(tmp_path / "o"),
                   "--intrinsics", str(tmp_path / "small.yaml")])
    assert rc == 2 and "are for 320x240 images, its images are 640x480" in caplog.text
    assert not (tmp_path / "o").exists()


def test_bag_camera_info_topics_give_the_intrinsics(tmp_path, caplog):
    """--bag-camera-info: the first CameraInfo of <image ns>/camera_info per camera is kept."""
    from densecalib_ros.core.io.bag import read_camera_infos, write_image_bag
    from densecalib_ros.core.io.camera_info import ros_camera_info

    rig = generate_rig(RigSpec(lenses="ideal", num_cameras=3, camera_model="RADIAL", width=640, height=480,
                               seed=3))
    gt = rig.ground_truth()
    topics = [f"/rig/{n}/image_raw" for n in rig.names]
    infos = [ros_camera_info(n, gt.cameras[n].intrinsics) for n in rig.names]
    write_image_bag(tmp_path / "bag", rig.images, topics, [1_000_000_000], camera_infos=infos)
    back = read_camera_infos(tmp_path / "bag", topics)
    assert [b["distortion_model"] for b in back] == ["plumb_bob"] * 3
    np.testing.assert_allclose(back[1]["camera_matrix"]["data"], infos[1]["camera_matrix"]["data"])
    out = tmp_path / "out"
    assert main(["calibrate", "--bag", str(tmp_path / "bag"), "--topics", *topics, "--out",
                 str(out), "--threads", "1", "--consensus-runs", "1",
                 "--bag-camera-info"]) == 0
    calib = read_calibration(out)
    rays = _rays()
    for n in rig.names:  # camera names from the topics: /rig/cam0/image_raw -> rig_cam0
        np.testing.assert_allclose(calib.cameras[f"rig_{n}"].intrinsics.to_pycolmap().img_from_cam(
            rays),
                                   gt.cameras[n].intrinsics.to_pycolmap().img_from_cam(rays),
                                   atol=1e-9)
    assert sorted(calib.quality.given_intrinsics) == ["rig_cam0", "rig_cam1", "rig_cam2"]
    with caplog.at_level(logging.INFO):  # check reads the topics the calibration recorded
        assert main(["check", str(out), "--bag", str(tmp_path / "bag")]) == 0
    assert "image topics as the calibration recorded them: /rig/cam0/image_raw" in caplog.text
    write_image_bag(tmp_path / "plain", rig.images, topics, [1_000_000_000])
    with caplog.at_level(logging.ERROR):
        rc = main(["calibrate", "--bag", str(tmp_path / "plain"), "--topics", *topics, "--out",
                   str(tmp_path / "o"), "--bag-camera-info"])
    assert rc == 2 and "has no CameraInfo topic /rig/cam0/camera_info" in caplog.text
    with caplog.at_level(logging.ERROR):
        rc = main(["calibrate", "--images", str(tmp_path), "--out", str(tmp_path / "o"),
                   "--bag-camera-info"])
    assert rc == 2 and "use it with --bag" in caplog.text


def test_recalibration_of_a_bumped_rig_can_keep_the_previous_intrinsics(rig):
    """Mounts bumped, lenses untouched: --previous OLD --intrinsics OLD recalibrates the poses
    from the previous calibration and keeps its intrinsics exactly."""
    from densecalib_ros.eval.bench import perturbed_calibration
    from densecalib_ros.core.recalibration import recalibrate

    gt = rig.ground_truth()
    previous = perturbed_calibration(gt, 2.0, 0.05)
    known = {n: c.intrinsics for n, c in previous.cameras.items()}
    config = make_config("regular", matcher="sift", sfm__num_threads=1,
                         cameras__known_intrinsics=known)
    result = recalibrate([rig.images[0]], rig.names, config, previous)
    assert result.rig.quality.init == "previous calibration"
    for n in rig.names:
        np.testing.assert_array_equal(result.rig.cameras[n].intrinsics.params, known[n].params)
    metrics = evaluate_calibration(result.rig, gt)
    assert metrics["num_registered"] == 4 and metrics["auc3"] >= 80.0


def test_keep_intrinsics_recalibrates_the_extrinsics_from_the_previous_calibration(tmp_path,
                                                                                    caplog):
    rig = generate_rig(RigSpec(lenses="ideal", num_cameras=3, camera_model="RADIAL", width=640, height=480,
                               seed=3))
    write_rig(rig, tmp_path / "rig")
    base = ["calibrate", "--images", str(tmp_path / "rig"), "--threads", "1",
            "--consensus-runs", "1"]
    assert main(base + ["--out", str(tmp_path / "old")]) == 0
    assert main(base + ["--out", str(tmp_path / "new"), "--previous", str(tmp_path / "old"),
                        "--keep-intrinsics"]) == 0
    old, new = read_calibration(tmp_path / "old"), read_calibration(tmp_path / "new")
    for n in rig.names:
        np.testing.assert_array_equal(new.cameras[n].intrinsics.params,
                                      old.cameras[n].intrinsics.params)
    assert new.quality.init == "previous calibration"
    assert evaluate_calibration(new, rig.ground_truth())["auc3"] >= 80.0
    with caplog.at_level(logging.ERROR):
        rc = main(base + ["--out", str(tmp_path / "o"), "--keep-intrinsics"])
    assert rc == 2 and "give --previous OLD_OUT" in caplog.text


def test_anipose_and_kalibr_files_give_every_camera_they_hold(tmp_path):
    """An arena's anipose calibration.toml or a Kalibr camchain (as `densecalib export` writes
    them) read back to each camera's projection; camera names as the files and topics give
    them."""
    from densecalib_ros.core.products.interchange import anipose_toml, kalibr_camchain_yaml
    from densecalib_ros.core.types import RigCalibration, RigCamera

    cams = {"left_cam": CameraIntrinsics("OPENCV", 640, 480, np.array(
                [500.0, 498.0, 322.0, 238.0, -0.12, 0.03, 0.001, -0.002])),
            "top": CameraIntrinsics("OPENCV_FISHEYE", 800, 600, np.array(
                [300.0, 301.0, 401.0, 299.0, 0.05, -0.01, 0.002, -0.0005]))}
    rig = RigCalibration("left_cam", {n: RigCamera(n, c, np.eye(4)) for n, c in cams.items()})
    (tmp_path / "calibration.toml").write_text(anipose_toml(rig))
    (tmp_path / "camchain.yaml").write_text(kalibr_camchain_yaml(rig))
    for f in ("calibration.toml", "camchain.yaml"):
        known = read_known_intrinsics([str(tmp_path / f)])
        assert sorted(known) == ["left_cam", "top"], f
        for n, cam in cams.items():
            rays = _rays(max_angle_deg=60.0 if "FISHEYE" in cam.model else 35.0)
            assert known[n].model == cam.model
            np.testing.assert_allclose(known[n].to_pycolmap().img_from_cam(rays),
                                       cam.to_pycolmap().img_from_cam(rays), atol=1e-9)
    assert sorted(read_known_intrinsics([str(tmp_path)])) == ["left_cam", "top"]  # the folder
    (tmp_path / "omni.yaml").write_text("cam0:\n  camera_model: omni\n  intrinsics: [1, 2, 3, 4]"
                                        "\n  resolution: [640, 480]\n")
    with pytest.raises(InputError, match="only pinhole with radtan or equidistant"):
        read_known_intrinsics([str(tmp_path / "omni.yaml")])


# An OpenCV stereo file as stereoCalibrate's samples write it (OpenCV 3/4 header, plain
# sequences for the distortion, no image size), cut down from the image_pipeline fisheye data.
STEREO_YML = """%YAML:1.0
---
K1: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 2.8688726950603882e+02, 0., 3.9595246153268397e+02, 0.,
       2.8699658002140251e+02, 2.7128814725595669e+02, 0., 0., 1. ]
K2: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 2.9061975245351334e+02, 0., 4.0124860319383106e+02, 0.,
       2.9033957900883007e+02, 2.7039299202312253e+02, 0., 0., 1. ]
D1: [ -2.3670549365179198e-02, -2.8102292297192123e-02,
    1.3429146781797114e-02, -2.9185133621709137e-03 ]
D2: [ -4.5677439473878714e-02, -7.9639894165110144e-03,
    5.2092995286682044e-03, -1.6389276670477719e-03 ]
T: [ -1.1703102538044161e-01, -5.8735929934837467e-05, -2.2387324441349573e-03 ]
"""


@pytest.mark.parametrize("ext", ["yml", "xml", "json"])
@pytest.mark.parametrize("fisheye", [False, True])
def test_opencv_calibration_files_read_back_to_opencvs_projection(tmp_path, ext, fisheye):
    """A file as OpenCV's calibration sample writes it (FileStorage YAML, XML or JSON: image size,
    fisheye_model, camera_matrix, distortion_coefficients) gives a camera projecting every ray
    where OpenCV does; the camera is the file stem or NAME=."""
    import cv2

    K = np.array([[500.0, 0.0, 321.3], [0.0, 502.0, 238.7], [0.0, 0.0, 1.0]])
    D = np.array([[0.05, -0.01, 0.002, -0.0005]]) if fisheye else \
        np.array([[-0.12, 0.03, 0.001, -0.002, 0.01]])
    path = tmp_path / f"lab_cam.{ext}"
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    for key, value in (("image_width", 640), ("image_height", 480), ("flags", 0),
                       ("fisheye_model", int(fisheye)), ("camera_matrix", K),
                       ("distortion_coefficients", D), ("avg_reprojection_error", 0.3)):
        fs.write(key, value)
    fs.release()
    [(name, cam)] = read_known_intrinsics([str(path)]).items()
    assert name == "lab_cam" and (cam.width, cam.height) == (640, 480)
    assert cam.model == ("OPENCV_FISHEYE" if fisheye else "FULL_OPENCV")
    rays = _rays(max_angle_deg=60.0 if fisheye else 30.0)
    np.testing.assert_allclose(cam.to_pycolmap().img_from_cam(rays),
                               opencv_pixels(rays, K, D, fisheye) + 0.5, atol=1e-6)
    assert list(read_known_intrinsics([f"cam3={path}"])) == ["cam3"]


def test_opencv_stereo_files_name_their_cameras_in_order_and_take_the_images_size(tmp_path):
    """K1/D1, K2/D2 of a stereo file: named with NAME1,NAME2=PATH; 4 coefficients are
    cv::fisheye's; without an image size in the file, the cameras take their images' size, and
    a principal point far from those images' centre (another resolution) is refused."""
    path = tmp_path / "cam_stereo.yml"
    path.write_text(STEREO_YML)
    known = read_known_intrinsics([f"left,right={path}"], ["left", "right", "top"])
    assert sorted(known) == ["left", "right"]
    assert all(cam.model == "OPENCV_FISHEYE" and (cam.width, cam.height) == (0, 0)
               for cam in known.values())
    np.testing.assert_allclose(known["right"].params, [
        290.61975245351334, 290.33957900883007, 401.74860319383106, 270.89299202312253,
        -4.5677439473878714e-02, -7.9639894165110144e-03, 5.2092995286682044e-03,
        -1.6389276670477719e-03])
    sized = check_known_intrinsics(known, ["left", "right", "top"], [(800, 503)] * 3)
    assert [(c.width, c.height) for c in sized.values()] == [(800, 503)] * 2
    assert (known["left"].width, known["left"].height) == (0, 0)  # the input is not changed
    with pytest.raises(InputError, match=r"principal point \(396, 272\) px is far from the "
                                         "centre of its 1600x1006 images"):
        check_known_intrinsics(known, ["left", "right"], [(1600, 1006), (800, 503)])
    with pytest.raises(InputError, match="stereo calibration of two cameras .* name them in "
                                         "order, e.g. left,right="):
        read_known_intrinsics([str(path)])
    (tmp_path / "cam.yaml").write_text(LAB_YAML)
    with pytest.raises(InputError, match="NAME1,NAME2= names the two cameras of an OpenCV "
                                         "stereo file"):
        read_known_intrinsics([f"a,b={tmp_path / 'cam.yaml'}"])


def test_intrinsics_without_image_size_are_held_at_their_images_size(rig, tmp_path):
    """The pipeline gives size-less given intrinsics (an OpenCV stereo file) their images' size
    and holds them exactly."""
    gt = rig.ground_truth()
    lines = ["%YAML:1.0", "---"]
    for i, n in enumerate(rig.names[:2], start=1):
        f, cx, cy, k1, k2 = map(float, gt.cameras[n].intrinsics.params)  # RADIAL, COLMAP px
        lines += [f"M{i}: !!opencv-matrix", "   rows: 3", "   cols: 3", "   dt: d",
                  f"   data: [ {f!r}, 0., {cx - 0.5!r}, 0., {f!r}, {cy - 0.5!r}, 0., 0., 1. ]",
                  f"D{i}: [ {k1!r}, {k2!r}, 0., 0., 0. ]"]
    path = tmp_path / "intrinsics.yml"
    path.write_text("\n".join(lines) + "\n")
    known = read_known_intrinsics([f"{rig.names[0]},{rig.names[1]}={path}"], rig.names)
    config = make_config("regular", matcher="sift", sfm__num_threads=1, consensus_runs=1,
                         cameras__known_intrinsics=known)
    result = run_calibration([rig.images[0]], rig.names, config)
    rays = _rays()
    for n in rig.names[:2]:
        cam = result.rig.cameras[n].intrinsics
        assert cam.model == "OPENCV" and (cam.width, cam.height) == (640, 480)
        np.testing.assert_array_equal(cam.params, known[n].params)
        np.testing.assert_allclose(cam.to_pycolmap().img_from_cam(rays),
                                   gt.cameras[n].intrinsics.to_pycolmap().img_from_cam(rays),
                                   atol=1e-9)
    assert evaluate_calibration(result.rig, gt)["auc3"] >= 80.0


SHARED_DATA = Path(__file__).resolve().parents[2] / "shared" / "data"


@pytest.mark.data
def test_real_opencv_stereo_file_gives_the_intrinsics_of_the_real_fisheye_bag(tmp_path):
    """The target-based OpenCV stereo calibration of the real fisheye pair (cam_stereo.yml: no
    image size, 4 fisheye coefficients) kept for the bag's cameras: the right camera's rotation
    from the scene lies within 1 deg of the file's own stereo rotation R."""
    import cv2

    stereo = SHARED_DATA / "ros_fisheye_stereo_checkerboard" / "stereo" / "cam_stereo.yml"
    bag = SHARED_DATA / "ros2bag_fisheye_stereo_derived" / "fisheye_stereo_bag"
    if not (stereo.exists() and bag.exists()):
        pytest.skip(f"shared data absent: {stereo} or {bag}")
    out = tmp_path / "out"
    assert main(["calibrate", "--bag", str(bag), "--topics", "/stereo/left/image_raw",
                 "/stereo/right/image_raw", "--preset", "fisheye", "--intrinsics",
                 f"stereo_left,stereo_right={stereo}", "--max-frame-sets", "5",
                 "--consensus-runs", "1", "--out", str(out)]) == 0
    rig = read_calibration(out)
    fs = cv2.FileStorage(str(stereo), cv2.FILE_STORAGE_READ)
    K2, R_right_from_left = fs.getNode("K2").mat(), fs.getNode("R").mat()
    fs.release()
    right = rig.cameras["stereo_right"].intrinsics
    assert right.model == "OPENCV_FISHEYE" and (right.width, right.height) == (800, 503)
    np.testing.assert_allclose(right.params[:4], [K2[0, 0], K2[1, 1], K2[0, 2] + 0.5,
                                                  K2[1, 2] + 0.5])
    rot = rig.cameras["stereo_right"].cam_from_rig[:3, :3] @ R_right_from_left.T
    assert np.degrees(np.arccos(np.clip((np.trace(rot) - 1) / 2, -1, 1))) < 1.0
