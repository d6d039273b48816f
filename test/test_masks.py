"""Masks (core.method.masks, `calibrate --mask`): matches with an end on a masked pixel are dropped
in both directions; a burnt-in info strip, identical in every camera, is matched across cameras
unless masked, and the masked calibration neither uses it nor loses accuracy."""
import cv2
import numpy as np
import pycolmap
import pytest

from densecalib_ros.cli import main
from densecalib_ros.core.errors import InputError
from densecalib_ros.core.io.export import read_calibration
from densecalib_ros.core.method.masks import apply_masks, check_masks, read_mask
from densecalib_ros.core.metrics import evaluate_calibration
from densecalib_ros.core.synthetic import RigSpec, generate_rig, write_rig
from densecalib_ros.core.types import SiteMatches, SiteMatchSet


def test_matches_touching_a_mask_are_dropped_both_ways():
    sites = [np.array([[5.5, 5.5], [50.5, 50.5], [80.5, 10.5]]),
             np.array([[10.5, 90.5], [60.5, 60.5], [70.5, 20.5]])]
    fwd = SiteMatches(target=np.array([0, 1, 2], np.int32), certainty=np.ones(3, np.float32),
                      target_xy_px=np.array([[10.5, 90.5], [60.5, 60.5], [np.nan, np.nan]]))
    bwd = SiteMatches(target=np.array([0, 1, 2], np.int32), certainty=np.ones(3, np.float32))
    match_set = SiteMatchSet(sites, {(0, 1): fwd, (1, 0): bwd}, [(100, 100), (100, 100)])
    mask0 = np.zeros((100, 100), bool)
    mask0[:20, :20] = True  # camera 0's site 0
    mask1 = np.zeros((100, 100), bool)
    mask1[80:, :] = True  # camera 1's bottom strip: its site 0
    assert apply_masks(match_set, [mask0, mask1]) == 2
    assert fwd.target.tolist() == [-1, 1, 2] and fwd.certainty.tolist() == [0, 1, 1]
    assert np.isnan(fwd.target_xy_px[0]).all()
    assert bwd.target.tolist() == [-1, 1, 2]
    assert apply_masks(match_set, [None, None]) == 0


def test_mask_errors(tmp_path):
    with pytest.raises(InputError, match="Cannot read mask"):
        read_mask(tmp_path / "none.png")
    cv2.imwrite(str(tmp_path / "black.png"), np.zeros((4, 4), np.uint8))
    with pytest.raises(InputError, match="black everywhere"):
        read_mask(tmp_path / "black.png")
    with pytest.raises(InputError, match="unknown camera.*camX"):
        check_masks({"camX": np.zeros((4, 4), bool)}, ["cam0"], [(4, 4)])
    with pytest.raises(InputError, match="mask of camera cam0 is 4x4, its images 8x4"):
        check_masks({"cam0": np.zeros((4, 4), bool)}, ["cam0"], [(8, 4)])


STRIP_PX = 48  # the info strip's height at the image bottom


def _strip_observations(out):
    rec = pycolmap.Reconstruction(str(out / "colmap"))
    return sum(1 for im in rec.images.values() for p in im.points2D
               if p.has_point3D() and p.xy[1] > 480 - STRIP_PX)


def test_info_strip_is_used_unless_masked(tmp_path, capsys):
    rig = generate_rig(RigSpec(lenses="ideal", num_cameras=4, camera_model="RADIAL", width=640, height=480,
                               seed=3))
    for frames in rig.images:  # a trail camera's info strip: the same in every camera
        for image in frames:
            image[-STRIP_PX:] = 20
            cv2.putText(image, "2026-05-01 10:00:05  23C  CAM TRAIL-PRO  MOON 3/4", (8, 470),
                        cv2.FONT_HERSHEY_SIMPLEX, 0.7, (240, 240, 240), 2, cv2.LINE_AA)
    images = tmp_path / "images"
    write_rig(rig, images)
    mask = np.full((480, 640), 255, np.uint8)
    mask[-STRIP_PX:] = 0
    cv2.imwrite(str(tmp_path / "strip.png"), mask)
    common = ["--matcher", "sift", "--threads", "1", "--consensus-runs", "1"]
    plain, masked, found = tmp_path / "plain", tmp_path / "masked", tmp_path / "found"
    assert main(["calibrate", "--images", str(images), "--out", str(plain), *common,
                 "--keep-info-strips"]) == 0
    assert main(["calibrate", "--images", str(images), "--out", str(masked), *common,
                 "--mask", str(tmp_path / "strip.png")]) == 0
    assert main(["calibrate", "--images", str(images), "--out", str(found), *common]) == 0
    assert _strip_observations(plain) > 0  # the strip's text matched across cameras
    assert _strip_observations(masked) == 0
    assert _strip_observations(found) == 0  # found by itself (core.method.info_strip) and ignored
    assert read_calibration(found).quality.info_strips == {
        n: f"{STRIP_PX + 4} px at the bottom" for n in rig.names}  # the bar + a 4 px margin
    assert read_calibration(masked).quality.info_strips is None  # the user's mask rules
    assert main(["report", str(found)]) == 0
    assert "info strips ignored: cam0 52 px at the bottom, cam1 52 px" in capsys.readouterr().out
    for out in (masked, found):
        calibration = read_calibration(out)
        metrics = evaluate_calibration(calibration, rig.ground_truth())
        assert metrics["auc3"] >= 80.0 and metrics["median_focal_err"] <= 0.02
    assert read_calibration(masked).quality.masked_cameras == ["cam0", "cam1", "cam2", "cam3"]
