"""Given intrinsics (lab camera_info YAML, a previous calibration): read in every form a user has
them, checked against the images, and held exactly while the extrinsics are calibrated."""
import json
import logging
import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np
import pytest

from densecalib_ros.cli import main
from densecalib_ros.core.config import make_config
from densecalib_ros.core.errors import InputError
from densecalib_ros.core.export import camera_info_yaml, read_calibration
from densecalib_ros.core.known_intrinsics import (check_known_intrinsics,
                                                  intrinsics_from_camera_info,
                                                  read_known_intrinsics)
from densecalib_ros.core.metrics import evaluate_calibration
from densecalib_ros.core.pipeline import run_calibration
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
    (LAB_YAML, ["x={d}/calib"], "NAME= applies to a single-camera file")])
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
    return generate_rig(RigSpec(num_cameras=4, camera_model="RADIAL", width=640, height=480,
                                seed=0))


@pytest.mark.parametrize("pipeline", ["incremental", "global"])
def test_given_intrinsics_are_held_exactly_and_the_rest_is_calibrated(rig, pipeline):
    """Every camera given: the result has exactly those intrinsics and the right poses. One
    camera given: it is held, the others are self-calibrated around it."""
    gt = rig.ground_truth()
    for given in (rig.names, rig.names[1:2]):
        known = {n: gt.cameras[n].intrinsics for n in given}
        config = make_config("regular", pipeline, matcher="sift", sfm__num_threads=1,
                             consensus_runs=1, known_intrinsics=known)
        messages = []
        result = run_calibration([rig.images[0]], rig.names, config, progress=messages.append)
        # every camera given: the multi-start explores first pairs instead of focals
        assert any("given, first pair cam" in m for m in messages) == (len(given) == 4)
        for n in given:
            cam = result.rig.cameras[n]
            assert cam.intrinsics.model == known[n].model
            np.testing.assert_array_equal(cam.intrinsics.params, known[n].params)
            assert cam.quality.focal_std_px is None  # nothing estimated
        assert result.rig.quality["given_intrinsics"] == {n: "RADIAL" for n in sorted(given)}
        metrics = evaluate_calibration(result.rig, gt)
        assert metrics["num_registered"] == 4 and metrics["auc3"] >= 80.0
        assert metrics["median_focal_err"] <= 0.02
        free = [n for n in rig.names if n not in given]
        assert all(result.rig.cameras[n].quality.focal_std_px > 0 for n in free)
        # the right intrinsics fit the scene: judged, and no warning
        assert set(result.rig.quality["given_intrinsics_fit"]) == set(given)
        assert not result.rig.quality.get("warnings")


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
                         known_intrinsics=known)
    result = run_calibration([rig.images[0]], rig.names, config)
    np.testing.assert_array_equal(result.rig.cameras["cam0"].intrinsics.params,
                                  known["cam0"].params)
    fit = result.rig.quality["given_intrinsics_fit"]
    assert all(fit[n]["median_px"] > 1.3 * fit[n]["median_px_refined"] for n in known)
    assert all(fit[n]["focal_change_pct"] > 5.0 for n in known)
    [warning] = result.rig.quality["warnings"]
    assert warning.startswith("The given intrinsics do not fit the scene") and \
        "cam0 from" in warning and "cam1 from" in warning


def test_a_given_fisheye_camera_makes_a_rig_mixing_lenses():
    """A fisheye camera's intrinsics given under the regular preset: its lens follows from the
    model (no --lens needed), it is held, the pinhole cameras are calibrated as RADIAL."""
    models = ("RADIAL", "OPENCV_FISHEYE", "RADIAL", "RADIAL")
    rig = generate_rig(RigSpec(num_cameras=4, camera_models=models, width=640, height=480,
                               seed=0))
    gt = rig.ground_truth()
    known = {"cam1": gt.cameras["cam1"].intrinsics}
    config = make_config("regular", matcher="sift", sfm__num_threads=1, consensus_runs=1,
                         known_intrinsics=known)
    result = run_calibration([rig.images[0]], rig.names, config)
    assert [result.rig.cameras[n].intrinsics.model for n in rig.names] == list(models)
    np.testing.assert_array_equal(result.rig.cameras["cam1"].intrinsics.params,
                                  known["cam1"].params)
    metrics = evaluate_calibration(result.rig, gt)
    assert metrics["num_registered"] == 4 and metrics["auc3"] >= 80.0
    with pytest.raises(InputError, match="another lens than --lens says"):
        run_calibration([rig.images[0]], rig.names,
                        make_config("regular", known_intrinsics=known,
                                    camera_lens={"cam1": "pinhole"}))


def test_calibrate_command_keeps_the_lab_intrinsics_it_is_given(tmp_path, capsys, caplog):
    rig = generate_rig(RigSpec(num_cameras=3, camera_model="RADIAL", width=640, height=480,
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
    assert calib.cameras["cam1"].intrinsics.model == "RADIAL"
    assert evaluate_calibration(calib, gt)["auc3"] >= 80.0
    table = capsys.readouterr().out.splitlines()
    rows = {line.split()[0]: line for line in table}
    assert "given" in rows["cam0"] and "given" in rows["cam2"] and "given" not in rows["cam1"]
    rms = {n: float(rows[n].split()[9]) for n in ("cam0", "cam1", "cam2")}
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
    from densecalib_ros.core.bag import read_camera_infos, write_image_bag
    from densecalib_ros.core.export import ros_camera_info

    rig = generate_rig(RigSpec(num_cameras=3, camera_model="RADIAL", width=640, height=480,
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
    assert sorted(calib.quality["given_intrinsics"]) == ["rig_cam0", "rig_cam1", "rig_cam2"]
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
    from densecalib_ros.core.bench import perturbed_calibration
    from densecalib_ros.core.recalibration import recalibrate

    gt = rig.ground_truth()
    previous = perturbed_calibration(gt, 2.0, 0.05)
    known = {n: c.intrinsics for n, c in previous.cameras.items()}
    config = make_config("regular", matcher="sift", sfm__num_threads=1, known_intrinsics=known)
    result = recalibrate([rig.images[0]], rig.names, config, previous)
    assert result.rig.quality["init"] == "previous calibration"
    for n in rig.names:
        np.testing.assert_array_equal(result.rig.cameras[n].intrinsics.params, known[n].params)
    metrics = evaluate_calibration(result.rig, gt)
    assert metrics["num_registered"] == 4 and metrics["auc3"] >= 80.0


def test_keep_intrinsics_recalibrates_the_extrinsics_from_the_previous_calibration(tmp_path,
                                                                                    caplog):
    rig = generate_rig(RigSpec(num_cameras=3, camera_model="RADIAL", width=640, height=480,
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
    assert new.quality["init"] == "previous calibration"
    assert evaluate_calibration(new, rig.ground_truth())["auc3"] >= 80.0
    with caplog.at_level(logging.ERROR):
        rc = main(base + ["--out", str(tmp_path / "o"), "--keep-intrinsics"])
    assert rc == 2 and "give --previous OLD_OUT" in caplog.text


def test_anipose_and_kalibr_files_give_every_camera_they_hold(tmp_path):
    """An arena's anipose calibration.toml or a Kalibr camchain (as `densecalib export` writes
    them) read back to each camera's projection; camera names as the files and topics give
    them."""
    from densecalib_ros.core.interchange import anipose_toml, kalibr_camchain_yaml
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
