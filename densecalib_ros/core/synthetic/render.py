"""Ray-cast renderer: supersampled pixel rays -> scene hits -> texture * Lambert light, then
per-camera exposure, white balance, vignetting, optional blur, sensor noise, optional JPEG.
Chunked over image rows so memory stays bounded (~100 MB) at any resolution."""
from __future__ import annotations

from dataclasses import dataclass

import cv2
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


@dataclass(frozen=True)
class Finish:
    """What a camera does to the image after the light: optical blur (Gaussian, sigma in
    pixels, 0 = none) before the sensor noise, JPEG compression (quality 1-100, 0 = none) after
    the 8-bit quantisation."""

    blur_sigma_px: float = 0.0
    jpeg_quality: int = 0


@dataclass(frozen=True)
class StillRoom:
    """Scenes that differ only inside a sphere per time step (a walker in a still room): `base`
    is the scene without what moves; bounds[t] = (centre (3,), radius m) of what moves at time
    t. Only rays through that sphere are cast against the time step's scene."""

    base: Scene
    bounds: list


def _supersampled(rgb: np.ndarray, nr: int, w: int, s: int) -> np.ndarray:
    """Supersample radiances (nr * s * w * s, 3) -> pixel means (nr, w, 3)."""
    sub = rgb.reshape(nr, s, w, s, 3)
    acc = sub[:, 0, :, 0].copy()
    for i in range(s):
        for j in range(s):
            if i or j:
                acc += sub[:, i, :, j]
    return acc * np.float32(1 / (s * s))


def _through(origin: np.ndarray, dirs: np.ndarray, bound: tuple) -> np.ndarray:
    """Indices of the rays (from origin, outside the sphere) that pass through bound's sphere."""
    centre, radius = bound
    if radius <= 0:
        return np.zeros(0, np.int64)
    rel = (origin - centre).astype(dirs.dtype)
    b = dirs @ rel
    with np.errstate(invalid="ignore"):
        return np.nonzero((b < 0) & (b * b - (float(rel @ rel) - radius ** 2) > 0))[0]


def _render_rows(scenes: list[Scene], atlas: TextureAtlas, origin: np.ndarray,
                 sub_dirs: np.ndarray, ctr_dirs: np.ndarray, still: StillRoom | None
                 ) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Supersample radiances and pixel-centre hit distances of a chunk of rows, per scene."""
    ok = np.isfinite(ctr_dirs[:, 0])
    rgbs, depths = [], []
    if still is None:
        for scene in scenes:
            rgbs.append(shade(scene, atlas, origin, sub_dirs)[0])
            d = np.full(len(ctr_dirs), np.inf, np.float32)
            d[ok] = scene.intersect(origin, ctr_dirs[ok]).t
            depths.append(d)
        return rgbs, depths
    base_rgb = shade(still.base, atlas, origin, sub_dirs)[0]
    base_d = np.full(len(ctr_dirs), np.inf, np.float32)
    base_d[ok] = still.base.intersect(origin, ctr_dirs[ok]).t
    for scene, bound in zip(scenes, still.bounds):
        rgb, d = base_rgb.copy(), base_d.copy()
        idx = _through(origin, sub_dirs, bound)
        if idx.size:
            rgb[idx] = shade(scene, atlas, origin, sub_dirs[idx])[0]
        idx = _through(origin, ctr_dirs, bound)
        if idx.size:
            d[idx] = scene.intersect(origin, ctr_dirs[idx]).t
        rgbs.append(rgb)
        depths.append(d)
    return rgbs, depths


def render_camera(cam: CameraIntrinsics, cam_from_world: np.ndarray, a_limit: float,
                  scenes: list[Scene], atlas: TextureAtlas, photo: Photometry, supersample: int,
                  noise_std: float, noise_rngs: list[np.random.Generator],
                  still: StillRoom | None = None, finish: Finish = Finish()) -> tuple[
                      list[np.ndarray], list[np.ndarray]]:
    """Images (H, W, 3) uint8 and depth (H, W) float32 (distance along the pixel-centre ray, inf =
    no hit) of one camera for each scene (time step). still: where the scenes differ only in a
    bounded part (StillRoom), the rest is cast once."""
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
        rgbs, depths = _render_rows(scenes, atlas, origin, sub_dirs, ctr_dirs, still)
        for ti in range(len(scenes)):
            radiance[ti][rows] = _supersampled(rgbs[ti], nr, w, s)
            depth[ti][rows] = depths[ti].reshape(nr, w)
    # Camera response: vignetting over the pixel radius, exposure, white balance, noise.
    ys, xs = np.mgrid[0:h, 0:w].astype(np.float32) + 0.5
    rad2 = ((xs - w / 2) ** 2 + (ys - h / 2) ** 2) / ((w / 2) ** 2 + (h / 2) ** 2)
    response = ((1 - photo.vignetting * rad2) * photo.gain * 255)[..., None] \
        * photo.white_balance.astype(np.float32)
    images = []
    for ti, rad in enumerate(radiance):
        img = rad * response
        if finish.blur_sigma_px > 0:
            img = cv2.GaussianBlur(img, (0, 0), finish.blur_sigma_px)
        if noise_std > 0:
            img += noise_rngs[ti].normal(0, noise_std, img.shape).astype(np.float32)
        images.append(_jpeg(np.clip(np.rint(img), 0, 255).astype(np.uint8),
                            finish.jpeg_quality))
    return images, depth


def _jpeg(rgb: np.ndarray, quality: int) -> np.ndarray:
    """rgb after a JPEG encode and decode at quality (0: unchanged)."""
    if quality <= 0:
        return rgb
    ok, data = cv2.imencode(".jpg", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR),
                            [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    if not ok:
        raise ValueError("OpenCV could not encode a JPEG image.")
    return cv2.cvtColor(cv2.imdecode(data, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)
