"""Generated rigs as users build them (issue 81): a plain room a person or animal walks through,
camera mounts, lens mixes, blur and JPEG; the rigs generated before these existed unchanged.
Real renders at tiny sizes."""
from pathlib import Path

import cv2
import numpy as np
import pytest

from densecalib_ros.cli import main as cli_main
from densecalib_ros.core.errors import InputError
from densecalib_ros.core.synthetic import RigSpec, generate_rig, read_ground_truth
from densecalib_ros.core.synthetic.intrinsics import (CROPPED_FRAME_PP_FRACTION, PP_OFFSET_FRACTION,
                                                    UNIT_FOCAL_SPREAD, UNIT_K_SPREAD)
from densecalib_ros.core.synthetic.lens import cam_rays
from densecalib_ros.core.synthetic.rig import MOUNTS

PERSON_PARTS = 6  # legs, arms, torso, head: the last objects of a walker rig's scenes


def _surface_ids(rig, t, c):
    """Texture id hit by every pixel-centre ray of camera c at time t, (H, W)."""
    cam = rig.cameras[c]
    ys, xs = np.mgrid[0:cam.height, 0:cam.width] + 0.5
    rays, _ = cam_rays(cam, np.stack([xs.ravel(), ys.ravel()], 1), rig.ray_limit_rad[c])
    hit = rig.scenes[t].intersect(rig.center(c), rays @ rig.cam_from_world[c][:3, :3])
    return hit.tex.reshape(cam.height, cam.width)


def _gradient(image):
    """Gradient magnitude (H, W) in 8-bit levels per pixel of an RGB image's grey."""
    grey = cv2.cvtColor(image, cv2.COLOR_RGB2GRAY).astype(np.float32)
    return np.hypot(cv2.Sobel(grey, cv2.CV_32F, 1, 0) / 8, cv2.Sobel(grey, cv2.CV_32F, 0, 1) / 8)


# Rigs generated before issue 81's fields existed (e02bda5's generator) and what they rendered:
# per image its 8x8-pixel block means and its depth map's block medians, and the intrinsics and
# poses (REFERENCE). Bit-exact digests of the same differed between CPUs (an AMD EPYC and an
# Intel Xeon round the render's floats differently), so the comparison allows that rounding and
# no more: a pixel a level off moves its block's mean by 1/64 of a level (16 such in a block
# are allowed); another texture, pose or lens moves it by many.
BEFORE = {
    "pinhole-3cam-s121": dict(num_cameras=3, seed=121, gap_deg=50, max_arc_deg=360, width=160,
                              height=120),
    "fisheye-4cam-s201": dict(num_cameras=4, camera_model="OPENCV_FISHEYE", seed=201, width=160,
                              height=120),
    "long-3cam-3steps-s111": dict(num_cameras=3, fov_range_deg=(25.0, 35.0), seed=111,
                                  width=160, height=120, num_time_steps=3),
}
REFERENCE = Path(__file__).parent / "data" / "rigs_before_issue_81.npz"
BLOCK_PX = 8


def rendered_summary(rig) -> dict:
    """name -> array: the images' block means, the depth maps' block medians, the intrinsics'
    params and the cam_from_world poses of a generated rig."""
    def blocks(a):
        h, w = a.shape[0] // BLOCK_PX, a.shape[1] // BLOCK_PX
        return a[:h * BLOCK_PX, :w * BLOCK_PX].reshape(h, BLOCK_PX, w, BLOCK_PX, *a.shape[2:])
    frames = [(t, c) for t in range(len(rig.images)) for c in range(len(rig.names))]
    return {"images": np.array([blocks(rig.images[t][c].astype(np.float64)).mean(axis=(1, 3))
                                for t, c in frames]),
            "depth": np.array([np.median(blocks(rig.depth[t][c].astype(np.float64)), axis=(1, 3))
                               for t, c in frames]),
            "params": np.concatenate([np.asarray(cam.params, np.float64) for cam in rig.cameras]),
            "poses": np.array(rig.cam_from_world, np.float64)}


@pytest.mark.parametrize("name", sorted(BEFORE))
def test_rigs_of_the_fields_before_render_as_before(name):
    now = rendered_summary(generate_rig(RigSpec(**BEFORE[name])))
    with np.load(REFERENCE) as before:
        np.testing.assert_allclose(now["images"], before[f"{name}/images"], rtol=0, atol=0.25)
        np.testing.assert_allclose(now["depth"], before[f"{name}/depth"], rtol=1e-6)
        np.testing.assert_allclose(now["params"], before[f"{name}/params"], rtol=1e-9)
        np.testing.assert_allclose(now["poses"], before[f"{name}/poses"], rtol=0, atol=1e-9)


@pytest.fixture(scope="module")
def walker_rig():
    return generate_rig(RigSpec(num_cameras=4, seed=6, room="plain", walker="person",
                                mount="high", lens_mix="mixed", gap_deg=90.0, max_arc_deg=360.0,
                                width=160, height=90, num_time_steps=3, supersample=1,
                                noise_std=0.0))


def test_the_walker_is_seen_by_several_cameras_at_once_and_walks_between_steps(walker_rig):
    rig = walker_rig
    for t in range(3):
        walker_tex = [tid for part in rig.scenes[t].objects[-PERSON_PARTS:] for tid in part.tex]
        seen = [np.isin(_surface_ids(rig, t, c), walker_tex).mean() for c in range(4)]
        assert sum(share > 0.005 for share in seen) >= 2, (t, seen)
    heads = np.array([scene.objects[-1].center for scene in rig.scenes])
    assert np.all(np.linalg.norm(np.diff(heads[:, :2], axis=0), axis=1) > 0.5)
    assert 1.4 < heads[0, 2] < 1.8  # a person's head
    # The room stays: pixels that see the still room at both steps are the same, bit for bit;
    # those whose surface changed changed.
    for c in range(4):
        ids0, ids1 = _surface_ids(rig, 0, c), _surface_ids(rig, 1, c)
        moving = [tid for part in rig.scenes[0].objects[-PERSON_PARTS:] for tid in part.tex]
        still = (ids0 == ids1) & ~np.isin(ids0, moving)
        still = cv2.erode(still.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
        np.testing.assert_array_equal(rig.images[0][c][still], rig.images[1][c][still])
        changed = (ids0 != ids1) & np.isin(ids0, moving)
        if changed.sum() > 20:
            diff = np.abs(rig.images[0][c].astype(int) - rig.images[1][c]).max(axis=2)
            assert (diff[changed] > 0).mean() > 0.5


def test_depth_on_the_walker_is_the_distance_to_its_surface(walker_rig):
    """Only rays near the walker are cast again at each step: their depth is still exact."""
    rig = walker_rig
    checked = 0
    for t in range(3):
        walker_tex = [tid for part in rig.scenes[t].objects[-PERSON_PARTS:] for tid in part.tex]
        for c in range(4):
            rows, cols = np.nonzero(np.isin(_surface_ids(rig, t, c), walker_tex))
            if rows.size:
                xy = np.stack([cols + 0.5, rows + 0.5], axis=1)
                dist = np.linalg.norm(rig.world_points(t, c, xy) - rig.center(c), axis=1)
                # The depth maps' rays are float32, world_points' float64.
                np.testing.assert_allclose(rig.depth[t][c][rows, cols], dist, rtol=1e-3)
                checked += rows.size
    assert checked > 100


def test_plain_rooms_floors_have_the_gradients_of_noise_not_of_texture():
    """Mean gradient over the floor (texture 4) away from its edges, noise off: a plain room's
    is under 1.5 levels/px, the textured room's several times more."""
    def floor_gradient(room, seed):
        rig = generate_rig(RigSpec(num_cameras=3, seed=seed, room=room, width=320, height=180,
                                   noise_std=0.0, supersample=1))
        values = []
        for c in range(3):
            floor = cv2.erode((_surface_ids(rig, 0, c) == 4).astype(np.uint8),
                              np.ones((5, 5), np.uint8)).astype(bool)
            if floor.mean() > 0.1:
                values.append(_gradient(rig.images[0][c])[floor].mean())
        return values

    plain, textured = floor_gradient("plain", 1), floor_gradient("textured", 3)
    assert plain and textured
    assert max(plain) < 1.5 and min(textured) > 4 * max(plain)


def test_identical_units_share_a_model_and_mixed_lenses_do_not():
    spec = dict(num_cameras=4, width=128, height=72, supersample=1)
    for model in ("RADIAL", "OPENCV_FISHEYE"):
        units = generate_rig(RigSpec(seed=2, camera_model=model, lens_mix="identical", **spec))
        params = np.array([cam.params for cam in units.cameras])
        assert len({cam.model for cam in units.cameras}) == 1
        focal = params[:, 0]
        assert np.ptp(focal) / focal.mean() <= 2 * UNIT_FOCAL_SPREAD + 1e-9
        k_at = 4  # OPENCV and OPENCV_FISHEYE: fx, fy, cx, cy, k1, k2, ...
        for i, spread in enumerate(UNIT_K_SPREAD):
            assert 0 < np.ptp(params[:, k_at + i]) <= 2 * spread + 1e-12
        assert np.ptp(params[:, 2]) > 0.1  # each unit its own principal point
    mixed = generate_rig(RigSpec(seed=2, lens_mix="mixed", **spec))
    fov = [2 * np.degrees(np.arctan(64 / cam.params[0])) for cam in mixed.cameras]
    assert 45 < min(fov) and max(fov) < 95 and np.ptp(fov) > 5
    assert np.ptp([cam.params[4] for cam in mixed.cameras]) > 0.02  # k1 differs too


def test_mixed_webcams_of_a_cropped_frame_put_the_principal_point_off_centre_vertically():
    """A 16:9 frame read out of a 4:3 sensor: cy up to CROPPED_FRAME_PP_FRACTION of the height
    off-centre (Caliscope's webcams: up to 4.8 %), cx as any real lens's; a 4:3 frame as before."""
    def offsets(width, height):
        rig = generate_rig(RigSpec(num_cameras=8, seed=3, lens_mix="mixed", width=width,
                                   height=height, supersample=1))
        params = np.array([cam.params for cam in rig.cameras])  # OPENCV: fx, fy, cx, cy, ...
        return (np.abs(params[:, 2] / width - 0.5).max(),
                np.abs(params[:, 3] / height - 0.5).max())

    cx_off, cy_off = offsets(128, 72)
    assert cx_off <= PP_OFFSET_FRACTION
    assert PP_OFFSET_FRACTION < cy_off <= CROPPED_FRAME_PP_FRACTION
    assert max(offsets(128, 96)) <= PP_OFFSET_FRACTION


@pytest.mark.parametrize("mount", ["high", "low"])
def test_mounts_put_the_cameras_at_their_heights(mount):
    rig = generate_rig(RigSpec(num_cameras=5, seed=4, room="plain", mount=mount, width=64,
                               height=36, supersample=1))
    (z_lo, z_hi), _ = MOUNTS[mount]
    heights = [rig.center(c)[2] for c in range(5)]
    assert z_lo <= min(heights) and max(heights) <= z_hi
    tilt_down = np.degrees(np.arcsin([-pose[2, 2] for pose in rig.cam_from_world]))
    if mount == "high":
        assert tilt_down.min() > 10  # looking down at the body, as Pose2Sim's ring does
    else:
        assert np.abs(tilt_down).max() < 25  # about level


def test_blur_and_jpeg_act_only_when_asked():
    spec = dict(num_cameras=3, seed=5, room="plain", walker="animal", width=160, height=96,
                noise_std=0.0, supersample=1)
    plain = generate_rig(RigSpec(**spec))
    blurred = generate_rig(RigSpec(blur_sigma_px=1.0, **spec))
    jpeg = generate_rig(RigSpec(jpeg_quality=30, **spec))
    for c in range(3):
        assert _gradient(blurred.images[0][c]).mean() < 0.8 * _gradient(plain.images[0][c]).mean()
        diff = np.abs(jpeg.images[0][c].astype(int) - plain.images[0][c])
        assert 0.3 < diff.mean() < 8
    np.testing.assert_array_equal(plain.cam_from_world[1], jpeg.cam_from_world[1])


def test_the_new_fields_are_checked():
    with pytest.raises(InputError, match="room='plain'"):
        generate_rig(RigSpec(num_cameras=3, walker="person"))
    with pytest.raises(InputError, match="one camera model"):
        generate_rig(RigSpec(num_cameras=3, lens_mix="identical",
                             camera_models=("RADIAL", "OPENCV_FISHEYE", "RADIAL")))
    for field, value in (("room", "garden"), ("walker", "bird"), ("mount", "ceiling"),
                         ("lens_mix", "some"), ("jpeg_quality", 5), ("blur_sigma_px", -1.0)):
        with pytest.raises(InputError, match=field):
            generate_rig(RigSpec(num_cameras=3, **{field: value}))


def test_generate_command_writes_a_room_a_person_walks_through(tmp_path):
    out = tmp_path / "rig"
    assert cli_main(["generate", "--out", str(out), "--cameras", "3", "--width", "64",
                     "--height", "36", "--time-steps", "2", "--room", "plain", "--walker",
                     "person", "--mount", "high", "--lens-mix", "identical", "--jpeg-quality",
                     "60", "--blur-sigma-px", "0.5"]) == 0
    assert sorted(p.name for p in (out / "cam1").iterdir()) == ["0000.png", "0001.png"]
    calib, _ = read_ground_truth(out)
    focal = [cam.intrinsics.params[0] for cam in calib.cameras.values()]
    assert np.ptp(focal) / np.mean(focal) <= 2 * UNIT_FOCAL_SPREAD + 1e-9
    assert cli_main(["generate", "--out", str(tmp_path / "bad"), "--cameras", "3",
                     "--walker", "person"]) == 2
