"""Metric scale from a known baseline (core.products.scale)."""
import numpy as np
import pytest

from densecalib_ros.core.errors import InputError
from densecalib_ros.core.calibration_result import CalibrationResult
from densecalib_ros.core.products.scale import (apply_known_baseline, camera_distance,
                                                with_known_baseline)

from sfm_fixtures import gt_calibration, gt_rig

NAMES = ["cam0", "cam1", "cam2", "cam3"]


def _result(rig):
    return CalibrationResult(rig=rig, reconstruction=None, tracks=None, focal_init_px=None)


def test_known_baseline_scales_every_distance_and_leaves_the_input_alone():
    rig = gt_calibration(NAMES, *gt_rig(4, seed=2))
    before = camera_distance(rig, "cam1", "cam3") / camera_distance(rig, "cam0", "cam2")
    metric = with_known_baseline(_result(rig), "cam0", "cam2", 0.5).rig
    assert metric.metric_scale and not rig.metric_scale
    assert camera_distance(metric, "cam0", "cam2") == pytest.approx(0.5)
    assert camera_distance(metric, "cam1", "cam3") / 0.5 == pytest.approx(before)
    for name in NAMES:  # rotations and intrinsics are untouched
        np.testing.assert_array_equal(metric.cameras[name].cam_from_rig[:3, :3],
                                      rig.cameras[name].cam_from_rig[:3, :3])
    with pytest.raises(InputError, match="must be a length in metres between"):
        apply_known_baseline(rig, "cam0", "cam2", 0.0)


def test_a_baseline_camera_that_did_not_register_leaves_the_rig_up_to_scale_with_a_warning():
    rig = gt_calibration(NAMES, *gt_rig(4, seed=2))
    del rig.cameras["cam3"]
    rig.failed_cameras = ["cam3"]
    out = with_known_baseline(_result(rig), "cam0", "cam3", 0.5).rig
    assert not out.metric_scale
    assert "cam3 did not register" in out.quality.warnings[0]


def test_scale_command_from_a_measured_length_in_the_scene(tmp_path, caplog):
    """`densecalib scale` on a generated room calibrated up to scale: two scene points 1-2 m
    apart, clicked in two and three cameras, make every length metric (camera distances, the
    floor heights, the saved COLMAP model) within 2 %; a known baseline replaces that scale;
    bad input leaves the calibration as it was."""
    import json

    import pycolmap

    from densecalib_ros.cli import main
    from densecalib_ros.core.io.export import read_calibration
    from densecalib_ros.core.synthetic import RigSpec, generate_rig, write_rig

    rig = generate_rig(RigSpec(lenses="ideal", num_cameras=4, camera_model="RADIAL", width=640, height=480,
                               num_time_steps=2, seed=1))
    write_rig(rig, tmp_path / "images")
    out = tmp_path / "out"
    assert main(["calibrate", "--images", str(tmp_path / "images"), "--out", str(out),
                 "--floor", "--consensus-runs", "1", "--threads", "1"]) == 0
    assert not read_calibration(out).metric_scale

    ends = rig.world_points(0, 0, np.array([[120.0, 330.0], [520.0, 330.0]]))  # seen by cam0
    points = []
    for xyz in ends:
        seen = {}
        for c, name in enumerate(rig.names):
            xy, valid = rig.project(c, xyz[None])
            if valid[0] and rig.visible(0, c, xyz[None])[0]:
                seen[name] = xy[0] - 0.5  # COLMAP -> OpenCV pixels
        assert len(seen) >= 2
        points.append(["--point"] + [f"{n}={x:.4f},{y:.4f}" for n, (x, y) in seen.items()])
    length_m = float(np.linalg.norm(ends[0] - ends[1]))
    assert 1.0 < length_m < 4.0

    before = (out / "calibration.json").read_text()
    with caplog.at_level("ERROR"):
        assert main(["scale", str(out), "--distance", "1.0", *points[0]]) == 2
    assert "--distance needs the two ends" in caplog.text
    with caplog.at_level("ERROR"):
        assert main(["scale", str(out), "--baseline", "cam0", "cam1", "1", *points[0]]) == 2
    assert "--point goes with --distance" in caplog.text
    with caplog.at_level("ERROR"):
        assert main(["scale", str(out), "--baseline", "cam0", "cam1", "1", "--pixel-sigma",
                     "3"]) == 2
    assert "--pixel-sigma goes with --distance" in caplog.text
    assert (out / "calibration.json").read_text() == before

    assert main(["scale", str(out), "--distance", str(length_m), *points[0], *points[1]]) == 0
    metric = read_calibration(out)
    assert metric.metric_scale and metric.quality.scale_from_points["relative_std"] < 0.02
    for a, b in (("cam0", "cam1"), ("cam1", "cam3"), ("cam0", "cam2")):
        ia, ib = rig.names.index(a), rig.names.index(b)
        truth = float(np.linalg.norm(rig.center(ia) - rig.center(ib)))
        assert camera_distance(metric, a, b) == pytest.approx(truth, rel=0.02), (a, b)
    for i, name in enumerate(rig.names):  # the scene's floor is z = 0, in metres
        assert metric.quality.floor["camera_heights"][name] == pytest.approx(
            rig.center(i)[2], rel=0.02)
    model = pycolmap.Reconstruction(str(out / "colmap"))
    centres = {im.name: np.asarray(im.projection_center()) for im in model.images.values()}
    assert np.linalg.norm(centres["cam0"] - centres["cam2"]) == pytest.approx(
        camera_distance(metric, "cam0", "cam2"), rel=1e-6)

    truth01 = float(np.linalg.norm(rig.center(0) - rig.center(1)))
    assert main(["scale", str(out), "--baseline", "cam0", "cam1", str(truth01)]) == 0
    rebased = json.loads((out / "calibration.json").read_text())["quality"]
    assert "scale_from_points" not in rebased
    assert rebased["scale_from_baseline"]["baseline_m"] == pytest.approx(truth01)


def test_a_recalibration_that_lost_the_metric_scale_says_so():
    from densecalib_ros.core.products.scale import scaled_rig, warn_if_scale_lost

    rig = gt_calibration(NAMES, *gt_rig(4, seed=2))
    previous = scaled_rig(rig, 2.0, {"scale_from_points": {"factor": 2.0}})
    assert camera_distance(previous, "cam0", "cam2") == pytest.approx(
        2.0 * camera_distance(rig, "cam0", "cam2"))
    warn_if_scale_lost(rig, previous)
    assert "previous calibration was metric from two scene points" in rig.quality.warnings[0]
    metric = apply_known_baseline(rig, "cam0", "cam2", 0.5)
    warn_if_scale_lost(metric, previous)
    assert metric.quality.warnings == []  # metric again: the up-to-scale warning is gone
    # a scale replaced drops the warnings about the old one, keeps the others
    rig.quality.warnings += ["scale from points: point A: its pixels miss", "camera cam3 ..."]
    assert apply_known_baseline(rig, "cam0", "cam2", 0.5).quality.warnings == [
        "camera cam3 ..."]
