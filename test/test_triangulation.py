"""Measuring with a calibration (core.products.triangulation, `densecalib triangulate`): points seen
in two or three cameras (pinhole and fisheye) come back where they are, their standard deviations
match the scatter that pixel noise gives, floor-frame coordinates follow the calibration's floor,
and bad input is refused with what to do."""
import json
import logging

import numpy as np
import pytest
from sfm_fixtures import pose as _pose

from densecalib_ros.cli import main
from densecalib_ros.core.errors import InputError
from densecalib_ros.core.io.export import calibration_to_dict
from densecalib_ros.core.products.triangulation import triangulate
from densecalib_ros.core.types import CameraIntrinsics, RigCalibration, RigCamera, RigQuality


@pytest.fixture
def rig():
    floor_from_rig = _pose([-110, 0, 0], [0.0, 0.0, 1.2])
    return RigCalibration("a", {
        "a": RigCamera("a", CameraIntrinsics("RADIAL", 1024, 768,
                                             np.array([800.0, 515.0, 380.0, -0.1, 0.02])),
                       np.eye(4)),
        "b": RigCamera("b", CameraIntrinsics("OPENCV_FISHEYE", 1280, 960, np.array(
            [400.0, 401.0, 641.0, 478.0, 0.05, -0.02, 0.004, -0.0007])),
            _pose([0, -25, 0], [-0.9, 0.0, 0.2])),
        "c": RigCamera("c", CameraIntrinsics("RADIAL", 1024, 768,
                                             np.array([790.0, 510.0, 385.0, 0.03, 0.0])),
                       _pose([0, 20, 0], [0.8, 0.05, 0.1]))},
        quality=RigQuality(floor={"floor_from_rig": floor_from_rig.ravel().tolist(),
                                  "num_points": 1, "rms": 0.0, "camera_heights": {}}),
        metric_scale=True)


def _pixels(rig, xyz):
    """OpenCV pixels of a rig-frame point in the cameras whose image shows it."""
    out = {}
    for name, cam in rig.cameras.items():
        x = cam.cam_from_rig[:3, :3] @ xyz + cam.cam_from_rig[:3, 3]
        px = cam.intrinsics.to_pycolmap().img_from_cam(x[None])[0] - 0.5
        if x[2] > 0 and 0 <= px[0] < cam.intrinsics.width and 0 <= px[1] < cam.intrinsics.height:
            out[name] = tuple(px)
    return out


def test_points_come_back_and_their_sigma_matches_the_scatter(rig):
    rng = np.random.default_rng(0)
    for xyz in rng.uniform([-0.8, -0.5, 3.0], [0.8, 0.5, 5.0], (10, 3)):
        pixels = _pixels(rig, xyz)
        assert len(pixels) >= 2
        for views in (pixels, dict(list(pixels.items())[:2])):
            point = triangulate(rig, views)
            np.testing.assert_allclose(point.xyz_rig, xyz, atol=1e-7)
            assert max(point.residuals_px.values()) < 1e-5
    xyz = np.array([0.3, -0.2, 4.0])
    clean = _pixels(rig, xyz)
    predicted = triangulate(rig, clean, sigma_px=0.5).std
    scatter = np.std([triangulate(rig, {n: np.add(p, rng.normal(0, 0.5, 2))
                                        for n, p in clean.items()}).xyz_rig
                      for _ in range(400)], axis=0)
    np.testing.assert_allclose(scatter, predicted, rtol=0.15)
    # the floor frame: the calibration's floor_from_rig applied
    floor_from_rig = np.reshape(rig.quality.floor["floor_from_rig"], (4, 4))
    np.testing.assert_allclose(triangulate(rig, clean).xyz_floor,
                               floor_from_rig[:3, :3] @ xyz + floor_from_rig[:3, 3], atol=1e-7)


def test_pixels_of_different_points_are_flagged(rig):
    """A mis-click (or a stale calibration): the pixels still give a point, with a warning and
    each camera's miss (least squares spreads one bad click over all); 1 px off stays quiet."""
    pixels = _pixels(rig, np.array([0.1, 0.0, 3.5]))
    assert len(pixels) == 3
    point = triangulate(rig, dict(pixels, c=np.add(pixels["c"], (-40.0, 0.0))))
    assert len(point.warnings) == 1 and "do not meet at one point (misses of a " in \
        point.warnings[0] and max(point.residuals_px.values()) > 5.0
    assert not triangulate(rig, dict(pixels, c=np.add(pixels["c"], (1.0, 0.0)))).warnings


def test_nearly_parallel_rays_are_flagged(rig):
    near = RigCalibration("a", {"a": rig.cameras["a"], "c": RigCamera(
        "c", rig.cameras["c"].intrinsics, _pose([0, 0, 0], [-0.02, 0, 0]))})
    point = triangulate(near, _pixels(near, np.array([0.1, 0.0, 5.0])))
    assert point.parallax_deg < 1.0 and "barely determined" in point.warnings[0]
    assert point.std[2] > 20 * point.std[0]  # depth is the uncertain direction


def test_command_prints_points_and_distances(rig, tmp_path, capsys, caplog):
    calib = tmp_path / "calibration.json"
    calib.write_text(json.dumps(calibration_to_dict(rig)))
    ends = [np.array([-0.4, 0.3, 4.0]), np.array([0.6, 0.3, 4.0])]  # 1 m apart
    args = []
    for xyz in ends:
        args += ["--point"] + [f"{n}={x:.6f},{y:.6f}" for n, (x, y) in _pixels(rig, xyz).items()]
    assert main(["triangulate", str(calib), *args]) == 0
    out = capsys.readouterr().out
    assert "distance 0-1: 1 m" in out and "in the floor frame" in out
    assert main(["triangulate", str(calib), *args, "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["units"] == "m" and data["distances"][0][1] == pytest.approx(1.0, abs=1e-5)
    sigma = data["distance_sigmas"][0][1]  # as the text prints it; along x, the points' x sigmas
    assert f"(1-sigma {sigma:.2g})" in out and data["distance_sigmas"][0][0] == 0.0
    assert sigma == pytest.approx(np.hypot(data["points"][0]["std_rig"][0],
                                           data["points"][1]["std_rig"][0]), rel=0.05)
    with caplog.at_level(logging.ERROR):
        for bad, message in ((["--point", "a=10,10"], "at least two cameras"),
                             (["--point", "a=10,10", "z=5,5"], "not in the calibration"),
                             (["--point", "a=10,10", "c=2000,5"], "outside camera c's 1024x768"),
                             (["--point", "a=10", "c=5,5"], "expected CAMERA=X,Y")):
            assert main(["triangulate", str(calib), *bad]) == 2
            assert message in caplog.text


def test_rays_meeting_behind_a_camera_are_refused(rig):
    # a looks far right, c (0.72 left of a) far left: the rays part in front of the rig
    with pytest.raises(InputError, match="do not meet in front of camera"):
        triangulate(rig, {"a": (1000.0, 384.0), "c": (20.0, 384.0)})
