"""Ray-cast renderer: supersampled pixel rays -> scene hits -> texture * Lambert light, then
per-camera exposure, white balance, vignetting, sensor noise. Chunked over image rows so memory
stays bounded (~100 MB) at any resolution."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..types import CameraIntrinsics
from .lens import cam_rays
from .scene import Hit, Scene
from .textures import TextureAtlas

_CHUNK_RAYS = 1 << 17


@dataclass
class Photometry:
    """Per-camera photometric parameters."""

    gain: float  # exposure
    white_balance: np.ndarray  # (3,) RGB multipliers
    vignetting: float  # relative darkening at the image corner (radius = half diagonal)


def pixel_grid(width: int, height: int, rows: slice, supersample: int) -> np.ndarray:
    """COLMAP pixel positions (n, 2) of the supersamples of image rows `rows`, ordered
    (row, sub-row, column, sub-column) so a reshape to (r, s, W, s) averages them."""
    offs = (np.arange(supersample) + 0.5) / supersample
    ys = (np.arange(height)[rows][:, None] + offs[None, :]).reshape(-1)
    xs = (np.arange(width)[:, None] + offs[None, :]).reshape(-1)
    gx, gy = np.meshgrid(xs, ys)
    return np.stack([gx.reshape(-1), gy.reshape(-1)], axis=1)


def shade(scene: Scene, atlas: TextureAtlas, origin: np.ndarray, dirs: np.ndarray) -> tuple[
        np.ndarray, np.ndarray]:
    """Radiance (n, 3) float32 and hit distance (n,) for world rays dirs (n, 3) from origin (3,).
    Rays that hit nothing (NaN rays, beyond the lens circle) are black with distance inf."""
    rgb = np.zeros((len(dirs), 3), np.float32)
    t = np.full(len(dirs), np.inf, np.float32)
    idx = np.nonzero(np.isfinite(dirs[:, 0]))[0]
    hit = scene.intersect(origin, dirs[idx])
    t[idx] = hit.t
    got = np.isfinite(hit.t)
    if not got.all():
        idx, hit = idx[got], Hit(hit.t[got], hit.tex[got], hit.uv[got], hit.normal[got])
    p = origin + hit.t[:, None] * dirs[idx]
    to_light = scene.light_pos.astype(np.float32) - p
    dist2 = np.einsum("ij,ij->i", to_light, to_light)
    lambert = np.maximum(np.einsum("ij,ij->i", hit.normal, to_light), 0) / np.sqrt(dist2)
    light = 0.35 + 0.9 * lambert / (1 + dist2 / 16)
    rgb[idx] = atlas.lookup(hit.tex, hit.uv) * light[:, None]
    return rgb, t


def render_camera(cam: CameraIntrinsics, cam_from_world: np.ndarray, a_limit: float,
                  scenes: list[Scene], atlas: TextureAtlas, photo: Photometry, supersample: int,
                  noise_std: float, noise_rngs: list[np.random.Generator]) -> tuple[
                      list[np.ndarray], list[np.ndarray]]:
    """Images (H, W, 3) uint8 and depth (H, W) float32 (distance along the pixel-centre ray, inf =
    no hit) of one camera for each scene (time step)."""
    w, h, s = int(cam.width), int(cam.height), int(supersample)
    r_cam_from_world = cam_from_world[:3, :3]
    origin = (-r_cam_from_world.T @ cam_from_world[:3, 3]).astype(np.float32)
    r_world_from_cam = r_cam_from_world.T.astype(np.float32)
    radiance = [np.zeros((h, w, 3), np.float32) for _ in scenes]
    depth = [np.zeros((h, w), np.float32) for _ in scenes]
    rows_per_chunk = max(1, _CHUNK_RAYS // (w * s * s))
    for r0 in range(0, h, rows_per_chunk):
        rows = slice(r0, min(h, r0 + rows_per_chunk))
        nr = rows.stop - rows.start
        # Rays are shared by all time steps (static rig).
        sub_dirs = cam_rays(cam, pixel_grid(w, h, rows, s), a_limit, np.float32)[0] \
            @ r_world_from_cam.T
        ctr_dirs = cam_rays(cam, pixel_grid(w, h, rows, 1), a_limit, np.float32)[0] \
            @ r_world_from_cam.T
        for ti, scene in enumerate(scenes):
            rgb, _ = shade(scene, atlas, origin, sub_dirs)
            sub = rgb.reshape(nr, s, w, s, 3)
            acc = sub[:, 0, :, 0].copy()
            for i in range(s):
                for j in range(s):
                    if i or j:
                        acc += sub[:, i, :, j]
            radiance[ti][rows] = acc * np.float32(1 / (s * s))
            ok = np.isfinite(ctr_dirs[:, 0])
            d = np.full(len(ctr_dirs), np.inf, np.float32)
            d[ok] = scene.intersect(origin, ctr_dirs[ok]).t
            depth[ti][rows] = d.reshape(nr, w)
    # Camera response: vignetting over the pixel radius, exposure, white balance, noise.
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32) + 0.5
    rad2 = ((xs - w / 2) ** 2 + (ys - h / 2) ** 2) / ((w / 2) ** 2 + (h / 2) ** 2)
    response = ((1 - photo.vignetting * rad2) * photo.gain * 255)[..., None] \
        * photo.white_balance.astype(np.float32)
    images = []
    for ti, rad in enumerate(radiance):
        img = rad * response
        if noise_std > 0:
            img += noise_rngs[ti].normal(0, noise_std, img.shape).astype(np.float32)
        images.append(np.clip(np.rint(img), 0, 255).astype(np.uint8))
    return images, depth
