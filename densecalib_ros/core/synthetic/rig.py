"""Synthetic camera rigs with exact ground truth: a static rig of 3-10 cameras (RADIAL pinhole or
OPENCV_FISHEYE) around a textured room with moving objects, or a plain room a person or animal
walks through, rendered by ray casting."""
from __future__ import annotations

import json
import os
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from ..errors import InputError
from ..io.export import calibration_from_dict, calibration_to_dict
from ..io.image_encoding import refuse_png_if_it_would_abort
from ..io.safe_write import write_text_atomic
from ..json_text import json_text
from ..types import CameraIntrinsics, RigCalibration, RigCamera, RigQuality
from .intrinsics import (FOV_LIMITS_DEG, FOV_RANGE_DEG, LENS_MIXES, LENS_PROFILES,
                         REFERENCE_HALF_FOV_DEG, a_limit, rig_intrinsics)
from .lens import cam_rays, img_from_cam_any
from .render import Finish, Photometry, StillRoom, render_camera
from .rooms import furnish, plain_room, plain_styles
from .scene import Box, Scene, random_scene
from .textures import STYLE_NAMES, build_atlas
from .walker import WALKERS, bound_of, walk_loop, walker_parts, walker_styles

LAYOUTS = ("arc", "bar", "outward")
BAR_YAW_DEG = 3.0  # a bar's cameras: each axis turned by up to this from the common direction
AIM_CENTRE_M = np.array([0.0, 0.0, 0.45])  # the middle of the points cameras look at
# Rooms: "textured" (scene.random_scene: every surface richly textured, 8-11 objects in the
# middle, a third of them moving between time steps) or "plain" (rooms.py: plain surfaces, a
# few textured things at the walls; what moves is the walker).
ROOMS = ("textured", "plain")
# Camera heights (m) and the heights (m) of the points they aim at, per mount. "any": the rigs
# before mounts existed. "high": Pose2Sim's ring stands 1.7-2.1 m high, tilted 18-25 deg down
# at a body 3-3.7 m away; wall-mounted mocap and surveillance cameras up to 2.4 m. "low": camera
# traps on stakes and trees, webcams on desks (Caliscope's), aimed about level.
MOUNTS = {"any": ((1.0, 2.0), (0.2, 0.7)), "high": ((1.7, 2.4), (0.6, 1.1)),
          "low": ((0.4, 1.1), (0.3, 0.9))}
# JPEG qualities a spec may ask for (0: none); below 10 the blocks are all there is.
JPEG_QUALITY_RANGE = (10, 100)


@dataclass
class RigSpec:
    """What to generate. fov_deg is the horizontal field of view of every camera; None draws one
    per camera (lenses "real": a rig focal ratio log-uniform in REAL_FOCAL_WIDTH_RATIOS, or
    fov_range_deg when given, each camera within REAL_FOCAL_JITTER of it; "ideal": 55-75 deg;
    fisheye 150-190 deg). camera_models: per camera, a model that replaces camera_model (a rig
    mixing lenses); empty: camera_model for all. lenses: LENS_PROFILES. lens_mix "mixed" draws
    each pinhole's field of view in fov_range_deg (default intrinsics.MIXED_FOV_DEG); "identical"
    makes every camera a unit of one model (one camera model for all)."""

    num_cameras: int = 6
    camera_model: str = "RADIAL"
    width: int = 1024
    height: int = 768
    num_time_steps: int = 1
    seed: int = 0
    fov_deg: float | None = None
    supersample: int = 2
    noise_std: float = 2.0  # sensor noise, 8-bit levels
    gap_deg: float = 20.0  # azimuth between neighbouring cameras on their arc (the baseline width)
    max_arc_deg: float = 140.0  # the arc of all cameras is gap_deg x (n - 1) clipped to [45, this]
    camera_models: tuple = ()
    # "arc": cameras around the scene, looking at its centre (gap_deg, max_arc_deg); "bar":
    # side by side bar_spacing_m apart at one wall, looking across the room with their axes
    # parallel to within BAR_YAW_DEG (a forward-facing array: what fixes the focal lengths is
    # weak there, core.method.focal_determination); "outward": one head of cameras near the
    # room's centre facing out, their yaws 360 / n deg apart (a 360-degree camera, a trap on a
    # post): neighbours share only the edges of their fields of view.
    layout: str = "arc"
    bar_spacing_m: float = 0.3
    lenses: str = "real"
    fov_range_deg: tuple | None = None  # pinhole, lenses "real": the rig's (min, max) h. FOV
    # The rigs users build (issue 81); the defaults are the rigs before these fields existed.
    room: str = "textured"  # ROOMS
    walker: str = "none"  # WALKERS: a person or animal walking a loop over the time steps
    mount: str = "any"  # MOUNTS: camera heights
    lens_mix: str = "rig"  # intrinsics.LENS_MIXES: one lens type, mixed lenses, identical units
    blur_sigma_px: float = 0.0  # optical blur before the noise (render.Finish)
    jpeg_quality: int = 0  # JPEG compression of every image, 0 = none (render.Finish)

    def model_of(self, c: int) -> str:
        return self.camera_models[c] if self.camera_models else self.camera_model


@dataclass
class SyntheticRig:
    """A rendered rig. World frame: metres, z up. images[t][c]: (H, W, 3) uint8 RGB;
    depth[t][c]: (H, W) float32 distance along the pixel-centre ray (m), inf where nothing is hit
    (outside a fisheye's lens circle). scenes[t] is the analytic scene at time t;
    ray_limit_rad[c] the largest angle from the optical axis that camera c images."""

    names: list[str]
    cameras: list[CameraIntrinsics]
    cam_from_world: list[np.ndarray]
    images: list[list[np.ndarray]]
    depth: list[list[np.ndarray]]
    scenes: list[Scene]
    ray_limit_rad: list[float]

    def ground_truth(self) -> RigCalibration:
        """Exact calibration; rig frame = cam0's frame, translations in metres."""
        rig_from_world_inv = np.linalg.inv(self.cam_from_world[0])
        cams = {n: RigCamera(n, cam, c_w @ rig_from_world_inv)
                for n, cam, c_w in zip(self.names, self.cameras, self.cam_from_world)}
        return RigCalibration(reference_camera=self.names[0], cameras=cams,
                              quality=RigQuality(source="synthetic ground truth"), metric_scale=True)

    def center(self, c: int) -> np.ndarray:
        """Camera c's projection centre (3,) in the world frame."""
        return -self.cam_from_world[c][:3, :3].T @ self.cam_from_world[c][:3, 3]

    def _rays_world(self, c: int, xy_px: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        cam = self.cameras[c]
        a_lim = a_limit(cam, self.ray_limit_rad[c])
        rays, _ = cam_rays(cam, np.asarray(xy_px, np.float64).reshape(-1, 2), a_lim)
        return self.center(c), rays @ self.cam_from_world[c][:3, :3]

    def world_points(self, t: int, c: int, xy_px: np.ndarray) -> np.ndarray:
        """COLMAP pixels (N, 2) of camera c at time t -> world points (N, 3) on the visible surface,
        NaN where the pixel sees nothing. Exact: the pixel's own ray is cast against the analytic
        scene (not the per-pixel depth map), so it holds at sub-pixel positions and at edges."""
        origin, dirs = self._rays_world(c, xy_px)
        out = np.full(dirs.shape, np.nan)
        ok = np.isfinite(dirs[:, 0])
        hit_t = self.scenes[t].intersect(origin, dirs[ok]).t
        out[ok] = origin + hit_t[:, None] * dirs[ok]  # inf -> inf/nan rows
        out[~np.isfinite(out).all(axis=1)] = np.nan
        return out

    def project(self, c: int, points_world: np.ndarray, beyond_90deg: bool = False) -> tuple[
            np.ndarray, np.ndarray]:
        """World points (N, 3) -> COLMAP pixels (N, 2) of camera c and valid (N,) bool.

        Default: pycolmap's img_from_cam (exact COLMAP projection); valid = in front of the camera
        (z > 0), within the imaged angle and inside the image. beyond_90deg=True (fisheye only)
        also projects points behind the image plane, which pycolmap cannot (NaN): there valid =
        within the lens circle and inside the image, using the same model extended to theta > 90.
        No occlusion test (see `visible`)."""
        cam = self.cameras[c]
        x = np.asarray(points_world, np.float64).reshape(-1, 3)
        x_cam = x @ self.cam_from_world[c][:3, :3].T + self.cam_from_world[c][:3, 3]
        xy_any, theta = img_from_cam_any(cam, x_cam)
        if beyond_90deg and cam.model == "OPENCV_FISHEYE":
            xy = xy_any
            valid = theta <= self.ray_limit_rad[c]
        else:
            valid = (x_cam[:, 2] > 0) & (theta <= self.ray_limit_rad[c])
            xy = np.full((len(x), 2), np.nan)
            if valid.any():
                xy[valid] = cam.to_pycolmap().img_from_cam(x_cam[valid])
        with np.errstate(invalid="ignore"):
            valid &= (np.isfinite(xy).all(axis=1) & (xy[:, 0] >= 0) & (xy[:, 1] >= 0)
                      & (xy[:, 0] <= cam.width) & (xy[:, 1] <= cam.height))
        return xy, valid

    def visible(self, t: int, c: int, points_world: np.ndarray, tol_m: float = 1e-3) -> np.ndarray:
        """(N,) bool: world points (N, 3) imaged by camera c at time t (inside the image and not
        occluded: the ray from the camera hits the point first, within tol_m)."""
        x = np.asarray(points_world, np.float64).reshape(-1, 3)
        xy, valid = self.project(c, x, beyond_90deg=True)
        out = np.zeros(len(x), bool)
        idx = np.nonzero(valid)[0]
        if idx.size:
            origin = self.center(c)
            vec = x[idx] - origin
            dist = np.linalg.norm(vec, axis=1)
            hit_t = self.scenes[t].intersect(origin, vec / dist[:, None]).t
            out[idx] = np.abs(hit_t - dist) <= tol_m
        return out

    def transfer(self, t: int, a: int, b: int, xy_a_px: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Ground-truth correspondences: pixels (N, 2) of camera a -> pixels (N, 2) of camera b at
        time t and (N,) bool where the surface point is visible in b (in the image, unoccluded)."""
        x = self.world_points(t, a, xy_a_px)
        ok = np.isfinite(x[:, 0])
        xy_b = np.full((len(x), 2), np.nan)
        vis = np.zeros(len(x), bool)
        if ok.any():
            xy_b[ok] = self.project(b, x[ok], beyond_90deg=True)[0]
            vis[ok] = self.visible(t, b, x[ok])
        xy_b[~vis] = np.nan
        return xy_b, vis


def _check_spec(spec: RigSpec) -> None:
    if not 3 <= int(spec.num_cameras) <= 10:
        raise InputError(f"{spec.num_cameras} cameras: a synthetic rig has 3 to 10 (--cameras).")
    if spec.camera_models and len(spec.camera_models) != int(spec.num_cameras):
        raise InputError(f"camera_models has {len(spec.camera_models)} entries for "
                         f"{spec.num_cameras} cameras: give one model per camera (or none).")
    models = set(spec.camera_models or (spec.camera_model,))
    for model in models:
        if model not in FOV_RANGE_DEG:
            raise InputError(f"Unsupported camera model {model!r}: use one of "
                             f"{', '.join(FOV_RANGE_DEG)}.")
    if spec.lenses not in LENS_PROFILES:
        raise InputError(f"lenses={spec.lenses!r}: use one of {', '.join(LENS_PROFILES)}.")
    if spec.fov_range_deg is not None:
        lo, hi = FOV_LIMITS_DEG["RADIAL"]
        if len(spec.fov_range_deg) != 2 or not lo <= min(spec.fov_range_deg) \
                <= max(spec.fov_range_deg) <= hi:
            raise InputError(f"fov_range_deg={spec.fov_range_deg}: give (min, max) within "
                             f"{lo}..{hi} deg.")
    if spec.width < 32 or spec.height < 32:
        raise InputError(f"Image size {spec.width}x{spec.height} is too small: use >= 32x32.")
    if not 0 < spec.gap_deg <= 180 or not 45 <= spec.max_arc_deg <= 360:
        raise InputError(f"gap_deg={spec.gap_deg}, max_arc_deg={spec.max_arc_deg}: use a gap in "
                         "(0, 180] deg and an arc in [45, 360] deg.")
    if spec.layout not in LAYOUTS or not 0.02 <= spec.bar_spacing_m <= 0.6:
        raise InputError(f"layout={spec.layout!r}, bar_spacing_m={spec.bar_spacing_m}: use a "
                         f"layout of {', '.join(LAYOUTS)} and a spacing of 0.02-0.6 m.")
    if spec.num_time_steps < 1 or spec.supersample < 1 or spec.noise_std < 0:
        raise InputError("num_time_steps and supersample must be >= 1 and noise_std >= 0.")
    _check_users_rig(spec, models)
    for model in sorted(models) if spec.fov_deg is not None else ():
        lo, hi = FOV_LIMITS_DEG[model]
        if not lo <= spec.fov_deg <= hi:
            raise InputError(f"fov_deg={spec.fov_deg} for {model}: use {lo}..{hi}.")


def _check_users_rig(spec: RigSpec, models: set) -> None:
    """The fields of issue 81's rigs: room, walker, mount, lens mix, blur, JPEG."""
    choices = dict(room=ROOMS, walker=WALKERS, mount=tuple(MOUNTS), lens_mix=LENS_MIXES)
    for name, valid in choices.items():
        if getattr(spec, name) not in valid:
            raise InputError(f"{name}={getattr(spec, name)!r}: use one of {', '.join(valid)}.")
    if spec.walker != "none" and spec.room != "plain":
        raise InputError(f"walker={spec.walker!r} needs room='plain' (--room plain): the "
                         "textured room's middle is full of objects.")
    if spec.lens_mix == "identical" and len(models) > 1:
        raise InputError("lens_mix='identical' makes every camera a unit of one model: give "
                         "one camera model, not camera_models mixing several.")
    if spec.blur_sigma_px < 0 or not (spec.jpeg_quality == 0 or JPEG_QUALITY_RANGE[0]
                                      <= spec.jpeg_quality <= JPEG_QUALITY_RANGE[1]):
        raise InputError(f"blur_sigma_px={spec.blur_sigma_px}, jpeg_quality="
                         f"{spec.jpeg_quality}: use a blur >= 0 and a quality of 0 (none) or "
                         f"{JPEG_QUALITY_RANGE[0]}-{JPEG_QUALITY_RANGE[1]}.")
    if spec.layout == "bar" and spec.mount != "any":
        raise InputError(f"mount={spec.mount!r} places cameras on an arc: use layout 'arc'.")


def _look_at(position: np.ndarray, target: np.ndarray, roll: float) -> np.ndarray:
    """cam_from_world (4x4) of a camera at position looking at target (x right, y down, z fwd)."""
    fwd = target - position
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    down = np.cross(fwd, right)
    c, s = np.cos(roll), np.sin(roll)
    right, down = c * right + s * down, -s * right + c * down
    r_cam_from_world = np.stack([right, down, fwd])
    out = np.eye(4)
    out[:3, :3] = r_cam_from_world
    out[:3, 3] = -r_cam_from_world @ position
    return out


def _sample_poses(rng: np.random.Generator, n: int, scene: Scene, gap_deg: float,
                  max_arc_deg: float, aim_scatter: float = 1.0,
                  mount: tuple = MOUNTS["any"]) -> list[np.ndarray]:
    """Cameras on an arc around the room centre (gap_deg per camera gap, 45-max_arc_deg in all),
    at mount's heights, all looking at points near the centre at mount's aim heights: every
    pair overlaps, baselines are wide. Larger gaps (an arena ringed by cameras) make
    neighbouring views less alike."""
    (z_lo, z_hi), (aim_lo, aim_hi) = mount
    arc = np.deg2rad(np.clip(gap_deg * (n - 1), 45.0, max_arc_deg))
    az = rng.uniform(-np.pi, np.pi) + np.linspace(-arc / 2, arc / 2, n) \
        + rng.uniform(-4, 4, n) * np.pi / 180
    semi = scene.room_max[:2] - 0.4
    poses = []
    for a in az:
        xy = semi * rng.uniform(0.88, 1.0) * np.array([np.cos(a), np.sin(a)])
        position = np.array([xy[0], xy[1], rng.uniform(z_lo, z_hi)])
        target = np.array([rng.uniform(-0.6, 0.6), rng.uniform(-0.5, 0.5),
                           rng.uniform(aim_lo, aim_hi)])
        if aim_scatter != 1.0:
            target = AIM_CENTRE_M + (target - AIM_CENTRE_M) * aim_scatter
        poses.append(_look_at(position, target, np.deg2rad(rng.uniform(-6, 6))))
    return poses


# An outward head: its cameras this far from its axis, each yaw within OUTWARD_JITTER_DEG of its
# place (n equal steps round), axes within OUTWARD_JITTER_DEG of level, as a hand-built mount.
OUTWARD_RADIUS_M = 0.08
OUTWARD_JITTER_DEG = 3.0


def _outward_poses(rng: np.random.Generator, n: int, mount: tuple) -> list[np.ndarray]:
    """Cameras on one head within 0.3 m of the room's centre at one of mount's heights, facing
    out, their yaws 360 / n deg apart."""
    centre = np.r_[rng.uniform(-0.3, 0.3, 2), rng.uniform(*mount[0])]
    first = rng.uniform(0.0, 2 * np.pi)
    jitter = np.deg2rad(OUTWARD_JITTER_DEG)
    poses = []
    for c in range(n):
        yaw = first + 2 * np.pi * c / n + rng.uniform(-jitter, jitter)
        pitch = rng.uniform(-jitter, jitter)
        out = np.array([np.cos(yaw), np.sin(yaw), 0.0])
        position = centre + OUTWARD_RADIUS_M * out
        ahead = np.r_[np.cos(pitch) * out[:2], np.sin(pitch)]
        poses.append(_look_at(position, position + ahead, rng.uniform(-jitter, jitter)))
    return poses


def _bar_poses(rng: np.random.Generator, n: int, scene: Scene, spacing_m: float
               ) -> list[np.ndarray]:
    """Cameras side by side spacing_m apart along one long wall, 0.3 m from it, 1.0-1.8 m high,
    looking across the room and a little down, each axis turned by up to BAR_YAW_DEG."""
    side = rng.choice([-1.0, 1.0])  # which long wall
    x = (np.arange(n) - (n - 1) / 2) * spacing_m + rng.uniform(-0.5, 0.5)
    y = side * (scene.room_max[1] - 0.3)
    z = rng.uniform(1.0, 1.8)
    poses = []
    for xi in x:
        position = np.array([xi, y, z + rng.uniform(-0.02, 0.02)])
        yaw = np.deg2rad(rng.uniform(-BAR_YAW_DEG, BAR_YAW_DEG))
        ahead = np.array([np.sin(yaw), -side * np.cos(yaw), 0.0]) * 3.0 + [0.0, 0.0, -0.3]
        poses.append(_look_at(position, position + ahead, np.deg2rad(rng.uniform(-2, 2))))
    return poses


def _texture_styles(rng: np.random.Generator, scene: Scene) -> dict[int, str]:
    styles = {scene.room_tex[4]: "ground", scene.room_tex[5]: "plaster"}
    for tid in scene.room_tex[:4]:
        styles[tid] = str(rng.choice(["plaster", "stone", "wood", "painted"]))
    for obj in scene.objects:
        # One material per object (a box is one material on all faces).
        style = str(rng.choice(STYLE_NAMES if isinstance(obj, Box) else STYLE_NAMES[1:]))
        styles.update({tid: style for tid in obj.tex})
    return styles


def _rig_poses(rng: np.random.Generator, spec: RigSpec, scene: Scene,
               narrowest_half_fov: float) -> list[np.ndarray]:
    n = int(spec.num_cameras)
    if spec.layout == "bar":
        return _bar_poses(rng, n, scene, float(spec.bar_spacing_m))
    if spec.layout == "outward":
        return _outward_poses(rng, n, MOUNTS[spec.mount])
    # Long lenses see a small part of the room: their aim scatters as little in the image.
    aim = 1.0 if spec.lenses == "ideal" else min(
        1.0, np.tan(narrowest_half_fov) / np.tan(np.deg2rad(REFERENCE_HALF_FOV_DEG)))
    return _sample_poses(rng, n, scene, float(spec.gap_deg), float(spec.max_arc_deg), aim,
                         MOUNTS[spec.mount])


def _texel_m(spec: RigSpec, narrowest_half_fov: float) -> float:
    """Texel ~ the pixel footprint at ~3 m of a 65 deg camera of this width (detail scales with
    the resolution; at 1024 px wide this is ~4 mm), finer for long lenses down to 1.5 mm."""
    half_fov = np.deg2rad(REFERENCE_HALF_FOV_DEG)
    if spec.lenses == "ideal":
        return float(np.clip(3.0 * 2 * np.tan(half_fov) / spec.width, 0.003, 0.03))
    return float(np.clip(3.0 * 2 * np.tan(min(half_fov, narrowest_half_fov)) / spec.width,
                         0.0015, 0.03))


def _plain_world(spec: RigSpec, rng_scene: np.random.Generator, rng_tex: np.random.Generator,
                 room: Scene, poses: list[np.ndarray]
                 ) -> tuple[list[Scene], StillRoom, dict[int, str]]:
    """A plain room's scene per time step: its furniture, and the walker on its loop; what moves
    (StillRoom) and the texture styles."""
    centres = np.array([-p[:3, :3].T @ p[:3, 3] for p in poses])
    base = Scene(room.room_min, room.room_max, room.room_tex, furnish(rng_scene, room, centres),
                 room.light_pos)
    styles = plain_styles(rng_tex, base)
    steps = int(spec.num_time_steps)
    if spec.walker == "none":
        return [base] * steps, StillRoom(base, [(np.zeros(3), 0.0)] * steps), styles
    walk = walk_loop(rng_scene, spec.walker, room, steps, centres)
    first_tex = max(styles) + 1
    parts = [walker_parts(walk, t, first_tex) for t in range(steps)]
    styles.update(walker_styles(rng_tex, spec.walker, parts[0]))
    scenes = [Scene(base.room_min, base.room_max, base.room_tex, base.objects + p, base.light_pos)
              for p in parts]
    return scenes, StillRoom(base, [bound_of(p) for p in parts]), styles


def generate_rig(spec: RigSpec) -> SyntheticRig:
    """Render a random rig for spec (deterministic from spec.seed)."""
    _check_spec(spec)
    n, steps = int(spec.num_cameras), int(spec.num_time_steps)
    seeds = np.random.SeedSequence(int(spec.seed)).spawn(6)
    rng_cam, rng_scene, rng_tex, rng_move, rng_photo = (np.random.default_rng(s)
                                                          for s in seeds[:5])
    noise_seeds = seeds[5].spawn(n * steps)

    if spec.room == "textured":
        scene = random_scene(rng_scene)
        moving = rng_move.choice(len(scene.objects), size=max(2, len(scene.objects) // 3),
                                 replace=False).tolist()
        scenes = [scene]
        for _ in range(1, steps):
            scenes.append(scenes[-1].moved(rng_move, moving, 0.25))
    else:
        scene = plain_room(rng_scene)
    cams, limits, narrowest_half_fov = rig_intrinsics(rng_cam, spec)
    poses = _rig_poses(rng_cam, spec, scene, narrowest_half_fov)
    if spec.room == "textured":
        still, styles = None, _texture_styles(rng_tex, scene)
    else:
        scenes, still, styles = _plain_world(spec, rng_scene, rng_tex, scene, poses)
    atlas = build_atlas(rng_tex, scenes[0].surface_extents(), styles,
                        _texel_m(spec, narrowest_half_fov))

    images = [[None] * n for _ in range(steps)]
    depth = [[None] * n for _ in range(steps)]
    finish = Finish(float(spec.blur_sigma_px), int(spec.jpeg_quality))
    for c in range(n):
        photo = Photometry(gain=rng_photo.uniform(0.85, 1.15),
                           white_balance=rng_photo.uniform(0.95, 1.05, 3),
                           vignetting=rng_photo.uniform(0.1, 0.3))
        noise_rngs = [np.random.default_rng(noise_seeds[c * steps + t]) for t in range(steps)]
        imgs, deps = render_camera(cams[c], poses[c], a_limit(cams[c], limits[c]), scenes, atlas,
                                   photo, spec.supersample, spec.noise_std, noise_rngs, still,
                                   finish)
        for t in range(steps):
            images[t][c] = imgs[t]
            depth[t][c] = deps[t]
    return SyntheticRig(names=[f"cam{c}" for c in range(n)], cameras=list(cams),
                        cam_from_world=poses, images=images, depth=depth, scenes=scenes,
                        ray_limit_rad=[float(v) for v in limits])


def write_rig(rig: SyntheticRig, out_dir: str | os.PathLike) -> None:
    """out_dir/<camera>/<t:04d>.png (RGB) for every camera and time step, and
    out_dir/ground_truth.json (calibration.json format + "cam_from_world": {name: 16 floats})."""
    refuse_png_if_it_would_abort()
    out_dir = Path(out_dir)
    for c, name in enumerate(rig.names):
        (out_dir / name).mkdir(parents=True, exist_ok=True)
        for t, frame in enumerate(rig.images):
            path = out_dir / name / f"{t:04d}.png"
            if not cv2.imwrite(str(path), cv2.cvtColor(frame[c], cv2.COLOR_RGB2BGR)):
                raise InputError(f"Cannot write {path}: check that the folder is writable.")
    data = calibration_to_dict(rig.ground_truth())
    data["cam_from_world"] = {name: [float(v) for v in m.reshape(-1)]
                              for name, m in zip(rig.names, rig.cam_from_world)}
    write_text_atomic(out_dir / "ground_truth.json", json_text(data) + "\n")


def read_ground_truth(path: str | os.PathLike) -> tuple[RigCalibration, dict[str, np.ndarray]]:
    """ground_truth.json (or a folder holding it) -> (calibration, cam_from_world 4x4 per name)."""
    path = Path(path)
    if path.is_dir():
        path = path / "ground_truth.json"
    try:
        data = json.loads(path.read_text())
        cam_from_world = {name: np.array(v, np.float64).reshape(4, 4)
                          for name, v in data["cam_from_world"].items()}
    except (OSError, json.JSONDecodeError, KeyError, ValueError, AttributeError) as exc:
        raise InputError(f"Cannot read synthetic ground truth {path} ({exc!r}): expected a file "
                         "written by `densecalib generate`.") from exc
    return calibration_from_dict(data), cam_from_world
