"""Procedural, non-repetitive textures in world units, stored in one flat atlas.

Each surface gets its own texture image covering its whole extent (no tiling), built from
multi-octave value noise (several scales, colour variation) plus layers of random shapes drawn with
OpenCV: stones/pebbles (ellipses), leaves (pointed polygons), cracks/twigs (random polylines),
posters/patches (rotated rectangles). Deterministic from the generator passed in.
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

# Surface styles: base colours (RGB 0..1) and shape-layer densities per square metre.
_STYLES = {
    "ground": dict(colors=[(0.42, 0.33, 0.22), (0.33, 0.38, 0.2), (0.55, 0.47, 0.35)],
                   stones=260, leaves=90, lines=12, patches=0.0),
    "plaster": dict(colors=[(0.72, 0.7, 0.64), (0.6, 0.62, 0.66), (0.76, 0.68, 0.55)],
                    stones=40, leaves=8, lines=10, patches=2.0),
    "stone": dict(colors=[(0.5, 0.48, 0.45), (0.4, 0.38, 0.36), (0.58, 0.52, 0.44)],
                  stones=320, leaves=0, lines=16, patches=0.0),
    "wood": dict(colors=[(0.55, 0.38, 0.22), (0.45, 0.3, 0.17), (0.65, 0.5, 0.32)],
                 stones=30, leaves=10, lines=40, patches=0.5),
    "painted": dict(colors=[(0.25, 0.45, 0.6), (0.7, 0.3, 0.25), (0.3, 0.55, 0.35)],
                    stones=70, leaves=25, lines=14, patches=3.0),
}
STYLE_NAMES = tuple(_STYLES)


@dataclass
class TextureAtlas:
    """All textures in one flat (N, 3) uint8 array: texture k is the row-major (h_k, w_k) block
    starting at start[k]; texel_m is the texel size in metres (texel centres at (i + 0.5) * texel_m)."""

    data: np.ndarray  # (N, 3) uint8 RGB
    start: np.ndarray  # (K,) int64
    width: np.ndarray  # (K,) int64
    height: np.ndarray  # (K,) int64
    texel_m: float

    def lookup(self, tex: np.ndarray, uv: np.ndarray) -> np.ndarray:
        """Bilinear colour (n, 3) float32 in [0, 1] at surface coordinates uv (n, 2) metres of
        texture ids tex (n,) (all >= 0)."""
        w = self.width[tex]
        h = self.height[tex]
        fu = np.clip(uv[:, 0] / self.texel_m - 0.5, 0, w - 1).astype(np.float32)
        fv = np.clip(uv[:, 1] / self.texel_m - 0.5, 0, h - 1).astype(np.float32)
        iu = np.minimum(fu.astype(np.int64), w - 2)
        iv = np.minimum(fv.astype(np.int64), h - 2)
        au = (fu - iu)[:, None]
        av = (fv - iv)[:, None]
        base = self.start[tex] + iv * w + iu
        d = self.data
        top = d[base] * (1 - au) + d[base + 1] * au
        bot = d[base + w] * (1 - au) + d[base + w + 1] * au
        return (top * (1 - av) + bot * av) * np.float32(1 / 255)


def value_noise(rng: np.random.Generator, h: int, w: int, texel_m: float,
                scales_m: list[float]) -> np.ndarray:
    """Sum of value-noise octaves (h, w) float32, one per feature scale in metres, amplitude
    ~ scale^0.6 (fractal, pink-ish), normalised to zero mean and unit std."""
    out = np.zeros((h, w), np.float32)
    for s in scales_m:
        gh = max(2, int(np.ceil(h * texel_m / s)) + 2)
        gw = max(2, int(np.ceil(w * texel_m / s)) + 2)
        grid = rng.standard_normal((gh, gw)).astype(np.float32)
        out += cv2.resize(grid, (w, h), interpolation=cv2.INTER_CUBIC) * np.float32(s ** 0.6)
    out -= out.mean()
    return out / max(float(out.std()), 1e-6)


def _shape_color(rng, base):
    c = np.clip(np.asarray(base) * rng.uniform(0.45, 1.6) + rng.normal(0, 0.08, 3), 0, 1)
    return tuple(float(v) for v in c)


def make_texture(rng: np.random.Generator, extent_m: tuple[float, float], texel_m: float,
                 style: str) -> np.ndarray:
    """(h, w, 3) uint8 RGB texture covering extent_m = (u, v) metres at texel_m per texel."""
    st = _STYLES[style]
    w = int(np.ceil(extent_m[0] / texel_m)) + 2
    h = int(np.ceil(extent_m[1] / texel_m)) + 2
    area = extent_m[0] * extent_m[1]
    colors = np.array(st["colors"], np.float32)
    colors = np.clip(colors * rng.uniform(0.8, 1.2, (len(colors), 1))
                     + rng.normal(0, 0.05, colors.shape), 0.05, 0.95).astype(np.float32)
    # Base: mixture of the palette by large-scale noise, then brightness at many scales.
    mix = value_noise(rng, h, w, texel_m, [1.2, 0.5, 0.2])
    mix2 = value_noise(rng, h, w, texel_m, [0.8, 0.3])
    img = np.empty((h, w, 3), np.float32)
    t1 = 1 / (1 + np.exp(-2.0 * mix))
    t2 = 1 / (1 + np.exp(-2.0 * mix2))
    for ch in range(3):
        img[..., ch] = (colors[0, ch] * (1 - t1) + colors[1, ch] * t1) * (1 - 0.5 * t2) \
            + colors[2, ch] * 0.5 * t2
    if style == "wood":  # plank seams and grain along v
        grain = value_noise(rng, h, max(2, w // 1), texel_m, [0.05, 0.02])
        stretch = cv2.resize(value_noise(rng, max(2, h // 8), w, texel_m, [0.03, 0.01]), (w, h))
        img *= (1 + 0.12 * stretch + 0.05 * grain)[..., None]
        x = 0.0
        while x < extent_m[0]:
            x += rng.uniform(0.09, 0.25)
            cv2.line(img, (int(x / texel_m), 0), (int(x / texel_m), h - 1),
                     (0.15, 0.1, 0.06), max(1, int(0.006 / texel_m)))
    # Shape layers, densities per m^2, sizes log-uniform over a decade or two.
    px = 1.0 / texel_m
    n_patch = rng.poisson(st["patches"] * area)
    for _ in range(n_patch):
        c = (rng.uniform(0, w), rng.uniform(0, h))
        size = (rng.uniform(0.08, 0.5) * px, rng.uniform(0.08, 0.5) * px)
        box = cv2.boxPoints((c, size, rng.uniform(0, 180))).astype(np.int32)
        cv2.fillPoly(img, [box], _shape_color(rng, colors[rng.integers(3)][::-1]))
        for _ in range(rng.integers(0, 5)):  # "print" on a poster: strokes
            p0 = box[0] + rng.uniform(0, 1, 2) * (box[2] - box[0])
            p1 = p0 + rng.normal(0, 0.04 * px, 2)
            cv2.line(img, tuple(int(v) for v in p0), tuple(int(v) for v in p1),
                     _shape_color(rng, (0.2, 0.2, 0.2)), max(1, int(0.008 * px)), cv2.LINE_AA)
    n_stones = rng.poisson(st["stones"] * area)
    sizes = np.exp(rng.uniform(np.log(0.004), np.log(0.09), n_stones)) * px
    sizes = np.maximum(sizes, 1.0)
    for s in sizes:
        c = (int(rng.uniform(0, w)), int(rng.uniform(0, h)))
        axes = (max(1, int(s)), max(1, int(s * rng.uniform(0.4, 1.0))))
        base = colors[rng.integers(3)]
        cv2.ellipse(img, c, axes, rng.uniform(0, 180), 0, 360, _shape_color(rng, base), -1,
                    cv2.LINE_AA)
        if s > 6:  # shaded rim makes stones look 3D and adds corners for detectors
            cv2.ellipse(img, c, axes, rng.uniform(0, 180), rng.uniform(0, 180),
                        rng.uniform(200, 360), _shape_color(rng, base * 0.5),
                        max(1, int(s / 8)), cv2.LINE_AA)
    n_leaves = rng.poisson(st["leaves"] * area)
    tt = np.linspace(0, np.pi, 7)
    for _ in range(n_leaves):
        length = np.exp(rng.uniform(np.log(0.015), np.log(0.12))) * px
        wid = length * rng.uniform(0.2, 0.45)
        outline = np.concatenate([np.stack([length * (1 - np.cos(tt)) / 2, wid * np.sin(tt)], 1),
                                  np.stack([length * (1 - np.cos(tt[::-1])) / 2,
                                            -wid * np.sin(tt[::-1])], 1)])
        ang = rng.uniform(0, 2 * np.pi)
        rot = np.array([[np.cos(ang), -np.sin(ang)], [np.sin(ang), np.cos(ang)]])
        pts = (outline @ rot.T + rng.uniform(0, 1, 2) * (w, h)).astype(np.int32)
        leaf = (rng.uniform(0.25, 0.75), rng.uniform(0.35, 0.7), rng.uniform(0.05, 0.25))
        cv2.fillPoly(img, [pts], _shape_color(rng, leaf), cv2.LINE_AA)
        cv2.line(img, tuple(int(v) for v in pts[0]), tuple(int(v) for v in pts[6]),
                 _shape_color(rng, np.array(leaf) * 0.6), 1, cv2.LINE_AA)
    n_lines = rng.poisson(st["lines"] * area)
    for _ in range(n_lines):  # cracks / twigs: random walks
        p = rng.uniform(0, 1, 2) * (w, h)
        ang = rng.uniform(0, 2 * np.pi)
        pts = [p.copy()]
        for _ in range(rng.integers(3, 12)):
            ang += rng.normal(0, 0.5)
            p = p + rng.uniform(0.01, 0.08) * px * np.array([np.cos(ang), np.sin(ang)])
            pts.append(p.copy())
        cv2.polylines(img, [np.array(pts, np.int32)], False, _shape_color(rng, colors[0] * 0.4),
                      max(1, int(rng.uniform(0.001, 0.006) * px)), cv2.LINE_AA)
    # Fine multi-scale brightness texture over everything (grain, dirt, stains).
    detail = value_noise(rng, h, w, texel_m, [0.3, 0.08, 0.03, 0.012, 3 * texel_m])
    img *= (1 + 0.18 * detail)[..., None]
    return (np.clip(img, 0, 1) * 255 + 0.5).astype(np.uint8)


def build_atlas(rng: np.random.Generator, extents: dict[int, tuple[float, float]],
                styles: dict[int, str], texel_m: float) -> TextureAtlas:
    """Textures for ids 0..K-1 (extents and styles keyed by id) in one atlas."""
    k = max(extents) + 1
    blocks, start, width, height = [], np.zeros(k, np.int64), np.zeros(k, np.int64), \
        np.zeros(k, np.int64)
    offset = 0
    for tid in range(k):
        tex = make_texture(rng, extents[tid], texel_m, styles[tid])
        height[tid], width[tid] = tex.shape[:2]
        start[tid] = offset
        offset += tex.shape[0] * tex.shape[1]
        blocks.append(tex.reshape(-1, 3))
    return TextureAtlas(np.concatenate(blocks), start, width, height, texel_m)
