"""`densecalib calibrate` on a generated rig written to disk: files written, failures leave an
existing output folder untouched and exit non-zero with a message."""
import json
import logging
import os

os.environ.setdefault("OMP_NUM_THREADS", "1")

import cv2
import numpy as np
import pycolmap
import pytest
from PIL import Image

from densecalib_ros.cli import main
from densecalib_ros.core.io.export import read_calibration
from densecalib_ros.core.metrics import evaluate_calibration
from densecalib_ros.core.products.scale import camera_distance
from densecalib_ros.core.synthetic import RigSpec, generate_rig, read_ground_truth, write_rig


@pytest.fixture(scope="module")
def rig_dir(tmp_path_factory):
    path = tmp_path_factory.mktemp("rig")
    write_rig(generate_rig(RigSpec(lenses="ideal", num_cameras=4, camera_model="RADIAL", width=640, height=480,
                                   seed=3)), path)
    return path


def test_calibrate_writes_calibration_files(rig_dir, tmp_path, capsys):
    out = tmp_path / "out"
    rc = main(["calibrate", "--images", str(rig_dir), "--out", str(out), "--matcher", "sift",
               "--threads", "1"])
    assert rc == 0
    data = json.loads((out / "calibration.json").read_text())
    names = ["cam0", "cam1", "cam2", "cam3"]
    assert data["reference_camera"] == "cam0" and sorted(data["cameras"]) == names
    # provenance: which files made each frame set, by which version, when
    source = data["quality"]["input"]
    assert source["source"] == "images" and source["path"] == str(rig_dir.resolve())
    assert source["frame_sets"] == [[f"{n}/0000.png" for n in names]]
    assert data["quality"]["densecalib_version"] and "T" in data["quality"]["calibrated_utc"]
    assert len(data["cameras"]["cam1"]["cam_from_rig"]) == 16
    assert data["cameras"]["cam1"]["model"] == "OPENCV"  # fx, fy: the image refinement (p1 = p2 = 0)
    assert data["cameras"]["cam1"]["params"][6:] == [0.0, 0.0]
    for name in names:  # standard deviations and what the images pinned down (image refinement)
        quality = data["cameras"][name]["quality"]
        assert quality["focal_std_px"] > 0 and quality["principal_point_std_px"] > 0
        assert quality["projection_std_px"] > 0
        assert {"f", "k1", "k2"} <= set(quality["estimated_intrinsics"])
    assert data["quality"]["principal_point_prior_std_fraction"] == 0.01
    assert data["quality"]["image_refinement_tracks"] > 500
    printed = capsys.readouterr().out
    assert "cam3" in printed  # the per-camera summary
    assert "principal point estimated from the images: " in printed or \
        "principal point resting on its prior" in printed
    for name in names:
        assert "camera_matrix:" in (out / f"{name}.yaml").read_text()
    assert {p.name for p in (out / "colmap").iterdir()} >= {"cameras.bin", "images.bin",
                                                            "points3D.bin"}
    rig = read_calibration(out)  # the saved model is in the rig's frame and units
    for image in pycolmap.Reconstruction(str(out / "colmap")).images.values():
        np.testing.assert_allclose(image.cam_from_world().matrix(),
                                   rig.cameras[image.name].cam_from_rig[:3], atol=1e-9)
    # each camera's view of the last frame set, for `check` (core.monitor.reference_views)
    assert sorted(p.name for p in (out / "reference_views").iterdir()) == [
        f"{n}.jpg" for n in names]
    gt, _ = read_ground_truth(rig_dir / "ground_truth.json")
    metrics = evaluate_calibration(read_calibration(out), gt)
    assert metrics["auc3"] >= 80.0 and metrics["median_focal_err"] <= 0.02
    # `densecalib report` of the result against the ground truth: the paper's metric, as above.
    assert main(["report", str(out), "--against", str(rig_dir / "ground_truth.json")]) == 0
    text = capsys.readouterr().out
    assert all(name in text for name in names) and "AUC@3" in text
    assert main(["report", str(out / "calibration.json"), "--json",
                 "--against", str(rig_dir / "ground_truth.json")]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["pose_agreement"]["auc3"] == pytest.approx(metrics["auc3"])
    # report --plot and export --format ply read the saved model: its points, in their colours
    assert main(["report", str(out), "--plot", str(tmp_path / "rig.png")]) == 0
    assert (tmp_path / "rig.png").stat().st_size > 1000
    capsys.readouterr()
    assert main(["export", str(out), "--format", "ply", "--out", str(tmp_path / "scene.ply")]) == 0
    ply = (tmp_path / "scene.ply").read_text().splitlines()
    num_points = len(pycolmap.Reconstruction(str(out / "colmap")).points3D)
    assert f"element vertex {5 * len(names) + num_points}" in ply
    point_rgb = np.array([row.split()[3:] for row in ply[ply.index("end_header") + 1:][
        5 * len(names):5 * len(names) + num_points]], int)
    assert point_rgb.std() > 10  # the scene's texture, not one grey
    for name in names:
        assert abs(report["change"][name]["focal_change_pct"]) == pytest.approx(
            100 * metrics["cameras"][name]["focal_err"])
        assert report["change"][name]["projection_change_px"] == pytest.approx(
            metrics["cameras"][name]["projection"]["mean_px"], rel=1e-6)
    # `densecalib overlay`: each camera's residuals drawn on its image, at the image's size
    assert main(["overlay", str(out), "--images", str(rig_dir), "--out", str(tmp_path / "ov")]) == 0
    assert "residual median" in capsys.readouterr().out
    for name in names:
        drawn = cv2.imread(str(tmp_path / "ov" / f"{name}.png"))
        assert drawn is not None and drawn.shape == (480, 640, 3)
    # calibrate's masks mean nothing to it: refused, not ignored (a mask file that did not exist
    # was taken in silence)
    assert main(["overlay", str(out), "--images", str(rig_dir), "--out", str(tmp_path / "ov2"),
                 "--mask", str(tmp_path / "no_such_mask.png")]) == 2
    assert not (tmp_path / "ov2").exists()


def test_report_of_a_missing_calibration_says_what_it_needs(tmp_path, caplog):
    with caplog.at_level(logging.ERROR):
        assert main(["report", str(tmp_path / "nothing")]) == 2
    assert "Cannot read calibration file" in caplog.text


def test_failed_run_keeps_existing_output(rig_dir, tmp_path, caplog):
    out = tmp_path / "out"
    out.mkdir()
    (out / "calibration.json").write_text("previous")
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "cam0.png").write_bytes((rig_dir / "cam0" / "0000.png").read_bytes())
    (bad / "cam1.png").write_bytes(b"truncated")
    with caplog.at_level(logging.ERROR):
        rc = main(["calibrate", "--images", str(bad), "--out", str(out)])
    assert rc == 2
    assert "cam1.png" in caplog.text
    assert (out / "calibration.json").read_text() == "previous"
    assert not any(p.name.startswith(".out.tmp") for p in tmp_path.iterdir())


def test_calibration_failure_exits_1_with_message(tmp_path, caplog):
    rng = np.random.default_rng(0)
    for name in ("a", "b"):
        cv2.imwrite(str(tmp_path / f"{name}.png"), rng.integers(0, 255, (240, 320), np.uint8))
    with caplog.at_level(logging.ERROR):
        rc = main(["calibrate", "--images", str(tmp_path), "--out", str(tmp_path / "out")])
    assert rc == 1
    assert "Calibration failed" in caplog.text and "overlap" in caplog.text
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize("option, value, message", [
    ("--focal-px", "wide", "expected a number of pixels"),
    ("--focal-px", "cam9=800", "unknown camera(s) cam9"),
    ("--lens", "cam1=tele", "expected NAME=LENS with LENS pinhole or fisheye"),
    ("--lens", "fisheye", "expected NAME=LENS"),
    ("--lens", "cam9=fisheye", "unknown camera(s) cam9"),
    ("--known-baseline", "cam0 cam0 0.5", "expected two different cameras of cam0, cam1"),
    ("--known-baseline", "cam0 cam9 0.5", "expected two different cameras"),
    ("--known-baseline", "cam0 cam1 -2", "their distance in metres (1e-06 to 1e+06)"),
    ("--known-baseline", "cam0 cam1 inf", "their distance in metres (1e-06 to 1e+06)"),
    ("--keypoint-min-likelihood", "0.9", "--keypoint-min-likelihood belong(s) to --keypoints"),
    ("--time-offset", "cam1=3", "--time-offset belongs to --videos, --bag or"),
    ("--align", "name --time-offset cam1=3", "--time-offset belongs to"),
    ("--align", "time", "no EXIF capture time"),
    ("--max-frame-sets", "0", "--max-frame-sets 0: give at least 1"),
    ("--slop", "0.05", "--slop belongs to --bag"),
    ("--max-time-gap", "5", "--max-time-gap belongs to --images with --align time"),
    ("--align", "time --max-time-gap -1", "--max-time-gap -1: give a time"),
    ("--mask", "cam9=strip.png", "there is no camera 'cam9' (the cameras are cam0")])
def test_options_are_checked_before_matching(rig_dir, tmp_path, caplog, option, value, message):
    with caplog.at_level(logging.ERROR):
        rc = main(["calibrate", "--images", str(rig_dir), "--out", str(tmp_path / "o"),
                   option, *value.split(), "--consensus-runs", "1"])
    assert rc == 2 and message in caplog.text
    assert not (tmp_path / "o").exists()


def test_the_folder_the_user_is_in_is_not_replaced(rig_dir, tmp_path, caplog, monkeypatch):
    """--out . replaces the folder the shell is in: the shell would be left in a deleted folder."""
    (tmp_path / "o").mkdir()
    monkeypatch.chdir(tmp_path / "o")
    with caplog.at_level(logging.ERROR):
        assert main(["calibrate", "--images", str(rig_dir), "--out", "."]) == 2
    assert "the folder you are in" in caplog.text and "cd " in caplog.text


def test_bag_needs_topics(tmp_path, caplog):
    with caplog.at_level(logging.ERROR):
        rc = main(["calibrate", "--bag", str(tmp_path / "x.bag"), "--out", str(tmp_path / "o")])
    assert rc == 2 and "--topics" in caplog.text


def test_recalibration_from_previous_reports_change(rig_dir, tmp_path, capsys, caplog):
    """Also: --known-baseline makes the rig file and the COLMAP model metric, and a recalibration
    from a metric calibration stays metric."""
    first, second = tmp_path / "first", tmp_path / "second"
    common = ["--images", str(rig_dir), "--matcher", "sift", "--threads", "1"]
    gt, _ = read_ground_truth(rig_dir / "ground_truth.json")
    baseline_m = camera_distance(gt, "cam0", "cam2")  # the generator's units are metres
    assert main(["calibrate", *common, "--out", str(first),
                 "--known-baseline", "cam0", "cam2", str(baseline_m)]) == 0
    capsys.readouterr()
    rig = read_calibration(first)
    assert rig.metric_scale and camera_distance(rig, "cam0", "cam2") == pytest.approx(baseline_m)
    # Every other distance is then metric too (within the calibration's accuracy).
    assert camera_distance(rig, "cam1", "cam3") == pytest.approx(
        camera_distance(gt, "cam1", "cam3"), rel=0.03)
    model = pycolmap.Reconstruction(str(first / "colmap"))
    centres = {im.name: im.projection_center() for im in model.images.values()}
    assert np.linalg.norm(centres["cam0"] - centres["cam2"]) == pytest.approx(baseline_m)
    assert main(["calibrate", *common, "--out", str(second), "--previous", str(first)]) == 0
    printed = capsys.readouterr().out
    assert "change vs previous" in printed and "started previous calibration" in printed
    assert read_calibration(second).metric_scale  # the previous calibration's baseline
    quality = json.loads((second / "calibration.json").read_text())["quality"]
    # Same images: nothing moved, so the reported change is small.
    for change in quality["change_vs_previous"].values():
        assert abs(change["focal_change_pct"]) < 1.0 and change["rotation_change_deg"] < 0.5
    # The same cameras renamed: refused before any work, saying that the names differ (it ran
    # the whole calibration, then blamed a covered lens).
    renamed = tmp_path / "renamed"
    for k in range(4):
        (renamed / f"left{k}").mkdir(parents=True)
        (renamed / f"left{k}" / "0000.png").symlink_to(rig_dir / f"cam{k}" / "0000.png")
    with caplog.at_level(logging.ERROR):
        assert main(["calibrate", "--images", str(renamed), "--out", str(tmp_path / "third"),
                     "--previous", str(first)]) == 2
    assert "no camera is named as before" in caplog.text and not (tmp_path / "third").exists()


def test_exif_focal_lengths_are_read_from_the_images_and_can_be_ignored(rig_dir, tmp_path):
    """JPEGs carrying FocalLengthIn35mmFilm (as phones write it): the command starts from those
    focals, records them in quality.exif_focal_px, and --ignore-exif leaves them out."""
    gt, _ = read_ground_truth(rig_dir / "ground_truth.json")
    photos = tmp_path / "photos"
    photos.mkdir()
    written = {}
    for name, cam in gt.cameras.items():
        w, h = cam.intrinsics.width, cam.intrinsics.height
        f35 = round(cam.intrinsics.params[0] * np.hypot(36, 24) / np.hypot(w, h))  # whole mm
        written[name] = f35 * np.hypot(w, h) / np.hypot(36, 24)
        exif = Image.Exif()
        exif[0x010F] = "densecalib test"  # Make
        exif.get_ifd(0x8769)[0xA405] = f35  # FocalLengthIn35mmFilm
        Image.open(rig_dir / name / "0000.png").convert("RGB").save(
            photos / f"{name}.jpg", quality=95, exif=exif)
    common = ["calibrate", "--images", str(photos), "--matcher", "sift", "--threads", "1",
              "--consensus-runs", "1"]
    assert main([*common, "--out", str(tmp_path / "out")]) == 0
    quality = json.loads((tmp_path / "out" / "calibration.json").read_text())["quality"]
    assert quality["exif_focal_px"] == pytest.approx(written, abs=0.1)
    metrics = evaluate_calibration(read_calibration(tmp_path / "out"), gt)
    assert metrics["auc3"] >= 80.0 and metrics["median_focal_err"] <= 0.02
    assert main([*common, "--out", str(tmp_path / "plain"), "--ignore-exif"]) == 0
    quality = json.loads((tmp_path / "plain" / "calibration.json").read_text())["quality"]
    assert "exif_focal_px" not in quality


def test_one_camera_is_bad_input_with_exit_code_2(tmp_path, caplog):
    """A folder of one camera's images is input a rig cannot be made of: exit 2 (bad input), as
    documented, not 1 (a calibration that failed; issue 40)."""
    (tmp_path / "images" / "cam0").mkdir(parents=True)
    cv2.imwrite(str(tmp_path / "images" / "cam0" / "0000.png"), np.full((48, 64, 3), 90, np.uint8))
    assert main(["calibrate", "--images", str(tmp_path / "images"), "--out",
                 str(tmp_path / "out")]) == 2
    assert "Found only one camera (cam0)" in caplog.text
    assert not (tmp_path / "out").exists()


def test_a_focal_length_no_lens_has_is_refused(rig_dir, tmp_path, caplog):
    """--focal-px 1e9 (a unit slip: metres or nanometres for pixels) was accepted silently."""
    assert main(["calibrate", "--images", str(rig_dir), "--out", str(tmp_path / "out"),
                 "--focal-px", "cam1=1e9"]) == 2
    assert "The focal length given for camera cam1, 1e+09 px, is not a lens" in caplog.text
    assert not (tmp_path / "out").exists()
