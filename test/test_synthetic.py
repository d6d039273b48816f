"""Synthetic rig generator: exact geometry against pycolmap, occlusion-consistent depth, fisheye
beyond 90 degrees, determinism, time steps, file round trip, input validation."""
import json

import cv2
import numpy as np
import pytest

from densecalib_ros.cli import main as cli_main
from densecalib_ros.core.errors import InputError
from densecalib_ros.core.synthetic import RigSpec, generate_rig, read_ground_truth, write_rig
from densecalib_ros.core.synthetic.lens import cam_rays, img_from_cam_any


@pytest.fixture(scope="module")
def radial_rig():
    return generate_rig(RigSpec(lenses="ideal", num_cameras=4, camera_model="RADIAL", width=320, height=240,
                                num_time_steps=2, seed=3, noise_std=0.0))


@pytest.fixture(scope="module")
def fisheye_rig():
    return generate_rig(RigSpec(lenses="ideal", num_cameras=3, camera_model="OPENCV_FISHEYE", width=320,
                                height=240, seed=5, fov_deg=195.0))


def _pixels(rng, cam, n):
    return rng.uniform([0, 0], [cam.width, cam.height], (n, 2))


@pytest.mark.parametrize("which", ["radial_rig", "fisheye_rig"])
def test_reprojection_matches_pycolmap(which, request):
    rig = request.getfixturevalue(which)
    rng = np.random.default_rng(0)
    for c, cam in enumerate(rig.cameras):
        xy = _pixels(rng, cam, 400)
        x_world = rig.world_points(0, c, xy)
        x_cam = x_world @ rig.cam_from_world[c][:3, :3].T + rig.cam_from_world[c][:3, 3]
        front = np.isfinite(x_world[:, 0]) & (x_cam[:, 2] > 1e-3)
        assert front.sum() > 150
        xy_proj, valid = rig.project(c, x_world[front])
        assert valid.all()
        # Our unprojection inverts pycolmap's projection exactly.
        np.testing.assert_allclose(xy_proj, xy[front], atol=1e-6)
        ref = cam.to_pycolmap().img_from_cam(x_cam[front])
        np.testing.assert_allclose(xy_proj, ref, atol=1e-9)
        # Our own forward model (used beyond 90 deg) equals pycolmap's in front of the camera.
        np.testing.assert_allclose(img_from_cam_any(cam, x_cam[front])[0], ref, atol=1e-6)
        # The stored depth map is the distance along the pixel-centre ray.
        centres = np.floor(xy[front]) + 0.5
        x_ctr = rig.world_points(0, c, centres)
        dist = np.linalg.norm(x_ctr - rig.center(c), axis=1)
        d_map = rig.depth[0][c][centres[:, 1].astype(int), centres[:, 0].astype(int)]
        np.testing.assert_allclose(d_map, dist, rtol=1e-4)


def test_points_seen_by_two_cameras_are_consistent(radial_rig):
    rig = radial_rig
    rng = np.random.default_rng(1)
    n_cams = len(rig.names)
    for a in range(n_cams):
        xy_a = _pixels(rng, rig.cameras[a], 500)
        x = rig.world_points(0, a, xy_a)
        for b in range(n_cams):
            if a == b:
                continue
            xy_b, vis = rig.transfer(0, a, b, xy_a)
            assert vis.mean() > 0.15, f"cameras {a}, {b} overlap too little"
            # Depth test: b's depth map at the projection equals the distance to the point
            # (nearest pixel, so allow a few % at depth edges / grazing surfaces).
            cols = np.clip(xy_b[vis, 0].astype(int), 0, rig.cameras[b].width - 1)
            rows = np.clip(xy_b[vis, 1].astype(int), 0, rig.cameras[b].height - 1)
            dist = np.linalg.norm(x[vis] - rig.center(b), axis=1)
            rel = np.abs(rig.depth[0][b][rows, cols] - dist) / dist
            assert np.mean(rel < 0.03) > 0.9
            # The round trip b -> a lands on the original pixel.
            back, vis_back = rig.transfer(0, b, a, xy_b[vis])
            assert vis_back.mean() > 0.97
            np.testing.assert_allclose(back[vis_back], xy_a[vis][vis_back], atol=1e-5)
            assert not rig.visible(0, b, x[~vis & np.isfinite(x[:, 0])]).any()


def test_deterministic_from_seed():
    spec = RigSpec(lenses="ideal", num_cameras=3, width=96, height=72, seed=7)
    r1, r2 = generate_rig(spec), generate_rig(spec)
    r3 = generate_rig(RigSpec(lenses="ideal", num_cameras=3, width=96, height=72, seed=8))
    for c in range(3):
        np.testing.assert_array_equal(r1.images[0][c], r2.images[0][c])
        np.testing.assert_array_equal(r1.cam_from_world[c], r2.cam_from_world[c])
        assert np.abs(r1.images[0][c].astype(int) - r3.images[0][c]).mean() > 10
    assert not np.allclose(r1.cameras[1].params, r3.cameras[1].params)


def test_fisheye_beyond_90_degrees(fisheye_rig):
    rig = fisheye_rig
    rng = np.random.default_rng(2)
    for c, cam in enumerate(rig.cameras):
        img, depth = rig.images[0][c], rig.depth[0][c]
        h, w = depth.shape
        # Horizontal FOV 195 deg: the left/right edge centres look behind the image plane and
        # still see the room; the image is filled up to the lens circle.
        for y, x in [(h // 2, 0), (h // 2, w - 1), (0, w // 2), (h - 1, w // 2)]:
            assert np.isfinite(depth[y, x]) and img[y, x].max() > 10
        assert np.isfinite(depth).mean() > 0.9
        xy = _pixels(rng, cam, 3000)
        rays, ok = cam_rays(cam, xy, rig.ray_limit_rad[c])
        behind = ok & (rays[:, 2] < -0.05)
        assert behind.sum() > 20
        x_world = rig.world_points(0, c, xy[behind])
        assert np.isfinite(x_world).all()
        xy_back, valid = rig.project(c, x_world, beyond_90deg=True)
        assert valid.all()
        np.testing.assert_allclose(xy_back, xy[behind], atol=1e-6)
        # pycolmap cannot project behind the camera: the default projection says invalid.
        assert not rig.project(c, x_world)[1].any()


def test_write_and_read_ground_truth(tmp_path, radial_rig):
    rig = radial_rig
    write_rig(rig, tmp_path / "rig")
    for c, name in enumerate(rig.names):
        for t in range(2):
            png = cv2.imread(str(tmp_path / "rig" / name / f"{t:04d}.png"))[..., ::-1]
            np.testing.assert_array_equal(png, rig.images[t][c])
    data = json.loads((tmp_path / "rig" / "ground_truth.json").read_text())
    assert set(data["cam_from_world"]) == set(rig.names)
    calib, cam_from_world = read_ground_truth(tmp_path / "rig")
    truth = rig.ground_truth()
    assert calib.reference_camera == "cam0" and calib.metric_scale
    np.testing.assert_allclose(calib.cameras["cam0"].cam_from_rig, np.eye(4), atol=1e-12)
    for c, name in enumerate(rig.names):
        np.testing.assert_allclose(calib.cameras[name].intrinsics.params,
                                   rig.cameras[c].params)
        np.testing.assert_allclose(calib.cameras[name].cam_from_rig,
                                   truth.cameras[name].cam_from_rig)
        np.testing.assert_allclose(cam_from_world[name], rig.cam_from_world[c])
    with pytest.raises(InputError):
        read_ground_truth(tmp_path / "missing.json")


def _surface_ids(rig, t, c):
    """Texture id hit by every pixel-centre ray of camera c at time t, (H, W)."""
    cam = rig.cameras[c]
    ys, xs = np.mgrid[0:cam.height, 0:cam.width] + 0.5
    rays, _ = cam_rays(cam, np.stack([xs.ravel(), ys.ravel()], 1), rig.ray_limit_rad[c])
    hit = rig.scenes[t].intersect(rig.center(c), rays @ rig.cam_from_world[c][:3, :3])
    return hit.tex.reshape(cam.height, cam.width)


def test_objects_move_between_time_steps_walls_do_not(radial_rig):
    rig = radial_rig
    s0, s1 = rig.scenes
    moved = [i for i, (a, b) in enumerate(zip(s0.objects, s1.objects))
             if not (np.array_equal(a.center, b.center) and a.yaw == b.yaw)]
    assert 0 < len(moved) < len(s0.objects)
    moving_tex = {tid for i in moved for tid in s0.objects[i].tex}
    changed_any = 0.0
    for c in range(len(rig.names)):
        tex0, tex1 = _surface_ids(rig, 0, c), _surface_ids(rig, 1, c)
        same = (tex0 == tex1) & ~np.isin(tex0, list(moving_tex))
        # Away from moved silhouettes (supersamples reach one pixel out), nothing changes.
        static = cv2.erode(same.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
        assert static.mean() > 0.5
        np.testing.assert_array_equal(rig.images[0][c][static], rig.images[1][c][static])
        changed = (tex0 != tex1) | np.isin(tex0, list(moving_tex))
        diff = np.abs(rig.images[0][c].astype(int) - rig.images[1][c]).max(axis=2)
        if changed.any():
            assert (diff[changed] > 0).mean() > 0.5
        changed_any = max(changed_any, changed.mean())
    assert changed_any > 0.002


def test_bad_spec_raises():
    with pytest.raises(InputError, match="3 to 10"):
        generate_rig(RigSpec(lenses="ideal", num_cameras=2))
    with pytest.raises(InputError, match="3 to 10"):
        generate_rig(RigSpec(lenses="ideal", num_cameras=11))
    with pytest.raises(InputError, match="RADIAL"):
        generate_rig(RigSpec(lenses="ideal", camera_model="PINHOLE"))
    with pytest.raises(InputError, match="fov_deg"):
        generate_rig(RigSpec(lenses="ideal", camera_model="RADIAL", fov_deg=170.0))
    with pytest.raises(InputError, match="one model per camera"):
        generate_rig(RigSpec(lenses="ideal", num_cameras=3, camera_models=("RADIAL", "OPENCV_FISHEYE")))
    with pytest.raises(InputError, match="fov_deg=70.0 for OPENCV_FISHEYE"):
        generate_rig(RigSpec(lenses="ideal", num_cameras=3, fov_deg=70.0,
                             camera_models=("RADIAL", "OPENCV_FISHEYE", "RADIAL")))


def test_rig_mixing_lenses_draws_each_camera_of_its_model():
    spec = dict(num_cameras=3, width=64, height=48, seed=5)
    mixed = generate_rig(RigSpec(lenses="ideal", camera_models=("RADIAL", "OPENCV_FISHEYE", "RADIAL"), **spec))
    assert [c.model for c in mixed.cameras] == ["RADIAL", "OPENCV_FISHEYE", "RADIAL"]
    assert mixed.ray_limit_rad[1] > np.pi / 2 > mixed.ray_limit_rad[0]  # fisheye: beyond 90 deg
    plain = generate_rig(RigSpec(lenses="ideal", **spec))
    np.testing.assert_array_equal(plain.cameras[0].params,
                                  generate_rig(RigSpec(lenses="ideal", camera_models=("RADIAL",) * 3,
                                                       **spec)).cameras[0].params)


def test_bar_layout_puts_cameras_side_by_side_looking_the_same_way():
    from densecalib_ros.core.synthetic.rig import BAR_YAW_DEG

    rig = generate_rig(RigSpec(lenses="ideal", num_cameras=5, width=64, height=48, seed=2, layout="bar",
                               bar_spacing_m=0.25))
    centres = np.array([-T[:3, :3].T @ T[:3, 3] for T in rig.cam_from_world])
    np.testing.assert_allclose(np.diff(centres[:, 0]), 0.25, atol=1e-9)  # along the wall
    assert np.ptp(centres[:, 1]) < 1e-9 and np.ptp(centres[:, 2]) <= 0.04 + 1e-9
    axes = np.array([T[2, :3] for T in rig.cam_from_world])  # optical axes in the world
    angles = np.degrees(np.arccos(np.clip(axes @ axes.T, -1.0, 1.0)))
    assert angles.max() <= 2 * BAR_YAW_DEG + 1e-6 and angles.max() > 0.1
    assert np.all(axes[:, 2] < 0)  # a little down: the floor is in view
    with pytest.raises(InputError, match="layout"):
        generate_rig(RigSpec(lenses="ideal", layout="ring"))
    with pytest.raises(InputError, match="spacing"):
        generate_rig(RigSpec(lenses="ideal", layout="bar", bar_spacing_m=2.0))


def test_outward_layout_puts_one_head_of_cameras_facing_out_evenly_round():
    from densecalib_ros.core.synthetic.rig import OUTWARD_JITTER_DEG, OUTWARD_RADIUS_M

    rig = generate_rig(RigSpec(num_cameras=4, camera_model="OPENCV_FISHEYE", fov_deg=220.0,
                               width=64, height=48, seed=3, layout="outward", room="plain",
                               mount="low"))
    centres = np.array([-T[:3, :3].T @ T[:3, 3] for T in rig.cam_from_world])
    head = centres.mean(axis=0)
    np.testing.assert_allclose(np.linalg.norm(centres[:, :2] - head[:2], axis=1),
                               OUTWARD_RADIUS_M, rtol=0.1)
    axes = np.array([T[2, :3] for T in rig.cam_from_world])  # optical axes in the world
    out = (centres - head)[:, :2]
    assert np.all(np.einsum("ij,ij->i", axes[:, :2], out) > 0)  # each faces away from the head
    yaws = np.sort(np.degrees(np.arctan2(axes[:, 1], axes[:, 0])) % 360)
    steps = np.diff(np.r_[yaws, yaws[0] + 360])
    assert np.all(np.abs(steps - 90) <= 2 * OUTWARD_JITTER_DEG + 1e-6)
    assert np.all(np.abs(np.degrees(np.arcsin(axes[:, 2]))) <= OUTWARD_JITTER_DEG + 1e-6)


def test_generate_command(tmp_path):
    rc = cli_main(["generate", "--out", str(tmp_path / "out"), "--cameras", "3", "--width", "64",
                   "--height", "48", "--time-steps", "2", "--model", "OPENCV_FISHEYE"])
    assert rc == 0
    assert sorted(p.name for p in (tmp_path / "out" / "cam2").iterdir()) == ["0000.png",
                                                                             "0001.png"]
    calib, _ = read_ground_truth(tmp_path / "out" / "ground_truth.json")
    assert calib.cameras["cam1"].intrinsics.model == "OPENCV_FISHEYE"
    assert cli_main(["generate", "--out", str(tmp_path / "bad"), "--cameras", "2"]) == 2
    assert cli_main(["generate", "--out", str(tmp_path / "mixed"), "--cameras", "3", "--width",
                     "64", "--height", "48", "--fisheye-cameras", "2"]) == 0
    calib, _ = read_ground_truth(tmp_path / "mixed" / "ground_truth.json")
    # Real lenses by default: pinhole cameras have fy != fx (OPENCV with p1 = p2 = 0).
    assert [calib.cameras[f"cam{c}"].intrinsics.model for c in range(3)] == [
        "OPENCV", "OPENCV", "OPENCV_FISHEYE"]
    assert cli_main(["generate", "--out", str(tmp_path / "ideal"), "--cameras", "3", "--width",
                     "64", "--height", "48", "--lenses", "ideal"]) == 0
    calib, _ = read_ground_truth(tmp_path / "ideal" / "ground_truth.json")
    assert {c.intrinsics.model for c in calib.cameras.values()} == {"RADIAL"}
    assert cli_main(["generate", "--out", str(tmp_path / "bad"), "--cameras", "3",
                     "--fisheye-cameras", "3"]) == 2
    assert cli_main(["generate", "--out", str(tmp_path / "bar"), "--cameras", "3", "--width",
                     "64", "--height", "48", "--layout", "bar", "--bar-spacing-m", "0.1"]) == 0
    calib, _ = read_ground_truth(tmp_path / "bar" / "ground_truth.json")
    centres = [-c.cam_from_rig[:3, :3].T @ c.cam_from_rig[:3, 3] for c in calib.cameras.values()]
    assert np.linalg.norm(centres[2] - centres[0]) == pytest.approx(0.2, abs=0.05)
