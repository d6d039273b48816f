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
# The rooms users calibrate in (issue 81): plain surfaces, and what people and animals wear. Kept
# out of STYLE_NAMES, which the textured rooms draw from, so that those stay as they were. Base
# colours (RGB 0..1); make_plain_texture says what each style adds.
PLAIN_STYLES = {
    "plain_wall": [(0.82, 0.81, 0.77), (0.78, 0.78, 0.76), (0.80, 0.75, 0.66)],  # paint
    "plain_floor": [(0.20, 0.34, 0.62), (0.62, 0.30, 0.18), (0.38, 0.36, 0.33)],  # mats, rug, lino
    "cloth": [(0.15, 0.35, 0.55), (0.55, 0.15, 0.12), (0.20, 0.20, 0.22), (0.60, 0.60, 0.55)],
    "skin": [(0.80, 0.62, 0.50), (0.55, 0.38, 0.28), (0.90, 0.75, 0.65)],
    "fur": [(0.45, 0.32, 0.20), (0.60, 0.55, 0.45), (0.25, 0.22, 0.20)],
}
# A plain surface's brightness: the real rooms' plain walls, floors and mats (Caliscope's and
# Pose2Sim's frames at 640 px: 22-48 % of each frame in 16 px blocks of mean gradient under 2
# levels/px, which is their sensor noise's) vary by a few per cent over decimetres to metres
# (PLAIN_SHADING: paint, light fall-off the Lambert light leaves out) and by about a level at the
# texel (PLAIN_GRAIN: 1 % of a 200-level wall, under the 2-level sensor noise).
PLAIN_SHADING = 0.04
PLAIN_GRAIN = 0.01
# What plain walls carry: switches, sockets, frames and scuffs, a few per wall (per m^2), of low
# contrast (a fraction of the wall's brightness).
PLAIN_MARKS_PER_M2 = 0.3
PLAIN_MARK_CONTRAST = (0.05, 0.25)
# Floors: the seams of mats, lino sheets and rug edges every 1-2 m.
FLOOR_SEAM_SPACING_M = (1.0, 2.0)
# Clothes: stripes or checks of 1.5-6 cm period (shirts), 15-45 % contrast, in folds of 5-20 cm
# that shade by CLOTH_FOLDS; skin: almost plain (Pose2Sim's bare torso); fur: fine hair texture
# of FUR_HAIR and, on half the animals, FUR_SPOTS_PER_M2 spots of 2-8 cm (a dappled coat).
CLOTH_PERIOD_M = (0.015, 0.06)
CLOTH_CONTRAST = (0.15, 0.45)
CLOTH_FOLDS = 0.15
SKIN_SHADING = 0.05
FUR_HAIR = 0.25
FUR_SPOTS_PER_M2 = 60.0


@dataclass
class TextureAtlas:
    """All textures shelf-packed into one (H, W, 3) uint8 image: texture k occupies the block
    with top-left texel (x0[k], y0[k]) and size (width[k], height[k]); texel_m is the texel size
    in metres (texel centres at (i + 0.5) * texel_m of the surface coordinates)."""

    image: np.ndarray  # (H, W, 3) uint8 RGB, H and W < 32767 (cv2.remap limit)
    x0: np.ndarray  # (K,) float32
    y0: np.ndarray  # (K,) float32
    width: np.ndarray  # (K,) float32
    height: np.ndarray  # (K,) float32
    texel_m: float

    def lookup(self, tex: np.ndarray, uv: np.ndarray) -> np.ndarray:
        """Bilinear colour (n, 3) float32 in [0, 1] at surface coordinates uv (n, 2) metres of
        texture ids tex (n,) (all >= 0)."""
        n = len(tex)
        if n == 0:
            return np.zeros((0, 3), np.float32)
        inv = np.float32(1 / self.texel_m)
        fu = np.clip(uv[:, 0] * inv - 0.5, 0, self.width[tex] - 1) + self.x0[tex]
        fv = np.clip(uv[:, 1] * inv - 0.5, 0, self.height[tex] - 1) + self.y0[tex]
        # cv2.remap does the gather + bilinear blend in C; maps must be 2D (rows < 32767).
        cols = 1024
        pad = (-n) % cols
        map_x = np.pad(fu.astype(np.float32), (0, pad)).reshape(-1, cols)
        map_y = np.pad(fv.astype(np.float32), (0, pad)).reshape(-1, cols)
        out = cv2.remap(self.image, map_x, map_y, cv2.INTER_LINEAR)
        return out.reshape(-1, 3)[:n].astype(np.float32) * np.float32(1 / 255)


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


def _shape_colors(rng, bases: np.ndarray) -> list[tuple[float, float, float]]:
    """Random variations (brightness, tint) of base colours (n, 3) -> n RGB tuples."""
    bases = np.asarray(bases, np.float64).reshape(-1, 3)
    c = bases * rng.uniform(0.45, 1.6, (len(bases), 1)) + rng.normal(0, 0.06, bases.shape)
    grey = c.mean(axis=1, keepdims=True)
    c = np.clip(grey + 0.7 * (c - grey), 0, 1)  # muted, natural saturation
    return [tuple(v) for v in c.tolist()]


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
        grain = value_noise(rng, h, w, texel_m, [0.05, 0.02])
        stretch = cv2.resize(value_noise(rng, max(2, h // 8), w, texel_m, [0.03, 0.01]), (w, h))
        img *= (1 + 0.12 * stretch + 0.05 * grain)[..., None]
        x = 0.0
        while x < extent_m[0]:
            x += rng.uniform(0.09, 0.25)
            cv2.line(img, (int(x / texel_m), 0), (int(x / texel_m), h - 1),
                     (0.15, 0.1, 0.06), max(1, int(0.006 / texel_m)))
    px = 1.0 / texel_m
    # Shape layers, densities per m^2, sizes log-uniform over a decade or two; drawn in this
    # order (the rng's draws with them).
    _patches(img, rng, colors, rng.poisson(st["patches"] * area), px)
    _stones(img, rng, colors, rng.poisson(st["stones"] * area), px)
    _leaves(img, rng, rng.poisson(st["leaves"] * area), px)
    _lines(img, rng, colors, rng.poisson(st["lines"] * area), px)
    # Fine multi-scale brightness texture over everything (grain, dirt, stains).
    detail = value_noise(rng, h, w, texel_m, [0.3, 0.08, 0.03, 0.012, 3 * texel_m])
    img *= (1 + 0.18 * detail)[..., None]
    return (np.clip(img, 0, 1) * 255 + 0.5).astype(np.uint8)


def make_plain_texture(rng: np.random.Generator, extent_m: tuple[float, float], texel_m: float,
                       style: str) -> np.ndarray:
    """(h, w, 3) uint8 RGB texture of a PLAIN_STYLES style covering extent_m = (u, v) metres:
    one base colour of the style, shaded and grained (PLAIN_SHADING, PLAIN_GRAIN), with what the
    style carries (walls: marks; floors: seams; cloth: stripes or checks in folds; fur: hair)."""
    w = int(np.ceil(extent_m[0] / texel_m)) + 2
    h = int(np.ceil(extent_m[1] / texel_m)) + 2
    palette = np.array(PLAIN_STYLES[style], np.float32)
    # One of the style's colours, +-10 % in brightness and a slight tint: no two walls alike.
    base = palette[rng.integers(len(palette))] * np.float32(rng.uniform(0.9, 1.1))
    img = np.empty((h, w, 3), np.float32)
    img[:] = np.clip(base + rng.normal(0, 0.02, 3), 0.03, 0.97)
    px = 1.0 / texel_m
    if style == "plain_wall":
        _marks(img, rng, rng.poisson(PLAIN_MARKS_PER_M2 * extent_m[0] * extent_m[1]), px)
    elif style == "plain_floor":
        _seams(img, rng, extent_m, px)
    elif style == "cloth":
        _weave(img, rng, texel_m)
    elif style == "fur":
        img *= (1 + FUR_HAIR * value_noise(rng, h, w, texel_m, [0.05, 0.015, 3 * texel_m])
                )[..., None]
        spots = rng.poisson(rng.choice([0.0, FUR_SPOTS_PER_M2]) * extent_m[0] * extent_m[1])
        _stones(img, rng, palette * 0.6, spots, px, (0.01, 0.04))
    shading = {"cloth": CLOTH_FOLDS, "skin": SKIN_SHADING}.get(style, PLAIN_SHADING)
    img *= (1 + shading * value_noise(rng, h, w, texel_m, [1.0, 0.3])
            + PLAIN_GRAIN * value_noise(rng, h, w, texel_m, [3 * texel_m]))[..., None]
    return (np.clip(img, 0, 1) * 255 + 0.5).astype(np.uint8)


def _marks(img: np.ndarray, rng: np.random.Generator, n_marks: int, px: float) -> None:
    """Small low-contrast rectangles and strokes on a plain wall (PLAIN_MARKS_PER_M2)."""
    h, w = img.shape[:2]
    wall = img[0, 0].copy()
    for _ in range(n_marks):
        shade = 1 + rng.choice([-1, 1]) * rng.uniform(*PLAIN_MARK_CONTRAST)
        col = tuple(float(v) for v in np.clip(wall * shade, 0, 1))
        c = (rng.uniform(0, w), rng.uniform(0, h))
        if rng.random() < 0.6:  # a switch, a socket, a frame (6-40 cm); else a scuff (~10 cm)
            size = (rng.uniform(0.06, 0.4) * px, rng.uniform(0.06, 0.4) * px)
            cv2.fillPoly(img, [cv2.boxPoints((c, size, rng.uniform(-3, 3))).astype(np.int32)],
                         col)
        else:  # a scuff
            end = np.array(c) + rng.normal(0, 0.1 * px, 2)
            cv2.line(img, tuple(int(v) for v in c), tuple(int(v) for v in end), col,
                     max(1, int(0.005 * px)), cv2.LINE_AA)


def _seams(img: np.ndarray, rng: np.random.Generator, extent_m: tuple[float, float],
           px: float) -> None:
    """Straight dark seams along u and v every FLOOR_SEAM_SPACING_M."""
    h, w = img.shape[:2]
    col = tuple(float(v) for v in img[0, 0] * 0.6)
    width = max(1, int(0.005 * px))
    for axis, extent in enumerate(extent_m):
        at = rng.uniform(*FLOOR_SEAM_SPACING_M)
        while at < extent:
            k = int(at * px)
            ends = ((k, 0), (k, h - 1)) if axis == 0 else ((0, k), (w - 1, k))
            cv2.line(img, *ends, col, width)
            at += rng.uniform(*FLOOR_SEAM_SPACING_M)


def _weave(img: np.ndarray, rng: np.random.Generator, texel_m: float) -> None:
    """Stripes (along v) or checks of CLOTH_PERIOD_M and CLOTH_CONTRAST."""
    h, w = img.shape[:2]
    period_px = rng.uniform(*CLOTH_PERIOD_M) / texel_m
    contrast = rng.uniform(*CLOTH_CONTRAST)
    u = np.sin(2 * np.pi * (np.arange(w) + rng.uniform(0, period_px)) / period_px) > 0
    pattern = np.broadcast_to(u[None, :], (h, w)).astype(np.float32)
    if rng.random() < 0.5:  # checks, else stripes, as often
        v = np.sin(2 * np.pi * (np.arange(h) + rng.uniform(0, period_px)) / period_px) > 0
        pattern = 0.5 * (pattern + v[:, None])
    img *= (1 - contrast * pattern)[..., None]


def _patches(img: np.ndarray, rng: np.random.Generator, colors: np.ndarray, n_patch: int,
             px: float) -> None:
    """Rectangles of the palette's colours, some with strokes ("print" on a poster)."""
    h, w = img.shape[:2]
    for col in _shape_colors(rng, colors[rng.integers(0, 3, n_patch)][:, ::-1]):
        c = (rng.uniform(0, w), rng.uniform(0, h))
        size = (rng.uniform(0.08, 0.5) * px, rng.uniform(0.08, 0.5) * px)
        box = cv2.boxPoints((c, size, rng.uniform(0, 180))).astype(np.int32)
        cv2.fillPoly(img, [box], col)
        n_strokes = int(rng.integers(0, 5))
        for stroke in _shape_colors(rng, np.full((n_strokes, 3), 0.2)):
            p0 = box[0] + rng.uniform(0, 1, 2) * (box[2] - box[0])
            p1 = p0 + rng.normal(0, 0.04 * px, 2)
            cv2.line(img, tuple(int(v) for v in p0), tuple(int(v) for v in p1), stroke,
                     max(1, int(0.008 * px)), cv2.LINE_AA)


def _stones(img: np.ndarray, rng: np.random.Generator, colors: np.ndarray, n_stones: int,
            px: float, sizes_m: tuple = (0.004, 0.09)) -> None:
    """Ellipses of sizes_m (log-uniform), the larger with a shaded rim (3D look, corners for
    detectors)."""
    h, w = img.shape[:2]
    sizes = np.maximum(np.exp(rng.uniform(np.log(sizes_m[0]), np.log(sizes_m[1]), n_stones))
                       * px, 1.0)
    centres = (rng.uniform(0, 1, (n_stones, 2)) * (w, h)).astype(int).tolist()
    flat = rng.uniform(0.4, 1.0, n_stones)
    angles = rng.uniform(0, 180, (n_stones, 4))
    angles[:, 3] += 200
    bases = colors[rng.integers(0, 3, n_stones)]
    fill = _shape_colors(rng, bases)
    rim = _shape_colors(rng, bases * 0.5)
    for i, s in enumerate(sizes.tolist()):
        axes = (max(1, int(s)), max(1, int(s * flat[i])))
        cv2.ellipse(img, centres[i], axes, angles[i, 0], 0, 360, fill[i], -1, cv2.LINE_AA)
        if s > 6:
            cv2.ellipse(img, centres[i], axes, angles[i, 1], angles[i, 2], angles[i, 3], rim[i],
                        max(1, int(s / 8)), cv2.LINE_AA)


def _leaves(img: np.ndarray, rng: np.random.Generator, n_leaves: int, px: float) -> None:
    """Green-brown leaf shapes with a vein."""
    h, w = img.shape[:2]
    tt = np.linspace(0, np.pi, 7)
    half_leaf = np.stack([(1 - np.cos(tt)) / 2, np.sin(tt)], 1)
    outline = np.concatenate([half_leaf, half_leaf[::-1] * (1, -1)])  # unit length/width
    leaf_base = np.stack([rng.uniform(0.25, 0.75, n_leaves), rng.uniform(0.35, 0.7, n_leaves),
                          rng.uniform(0.05, 0.25, n_leaves)], 1)
    leaf_fill = _shape_colors(rng, leaf_base)
    leaf_vein = _shape_colors(rng, leaf_base * 0.6)
    for i in range(n_leaves):
        length = np.exp(rng.uniform(np.log(0.015), np.log(0.12))) * px
        ang = rng.uniform(0, 2 * np.pi)
        rot = np.array([[np.cos(ang), -np.sin(ang)], [np.sin(ang), np.cos(ang)]])
        pts = ((outline * (length, length * rng.uniform(0.2, 0.45))) @ rot.T
               + rng.uniform(0, 1, 2) * (w, h)).astype(np.int32)
        cv2.fillPoly(img, [pts], leaf_fill[i], cv2.LINE_AA)
        cv2.line(img, tuple(pts[0].tolist()), tuple(pts[6].tolist()), leaf_vein[i], 1,
                 cv2.LINE_AA)


def _lines(img: np.ndarray, rng: np.random.Generator, colors: np.ndarray, n_lines: int,
           px: float) -> None:
    """Cracks and twigs: random walks."""
    h, w = img.shape[:2]
    for col in _shape_colors(rng, np.tile(colors[0] * 0.4, (n_lines, 1))):
        p = rng.uniform(0, 1, 2) * (w, h)
        ang = rng.uniform(0, 2 * np.pi)
        pts = [p.copy()]
        for _ in range(rng.integers(3, 12)):
            ang += rng.normal(0, 0.5)
            p = p + rng.uniform(0.01, 0.08) * px * np.array([np.cos(ang), np.sin(ang)])
            pts.append(p.copy())
        cv2.polylines(img, [np.array(pts, np.int32)], False, col,
                      max(1, int(rng.uniform(0.001, 0.006) * px)), cv2.LINE_AA)


def build_atlas(rng: np.random.Generator, extents: dict[int, tuple[float, float]],
                styles: dict[int, str], texel_m: float) -> TextureAtlas:
    """Textures for ids 0..K-1 (extents and styles keyed by id), shelf-packed into one atlas."""
    k = max(extents) + 1
    textures = [(make_plain_texture if styles[tid] in PLAIN_STYLES else make_texture)(
        rng, extents[tid], texel_m, styles[tid]) for tid in range(k)]
    atlas_w = max(4096, max(t.shape[1] for t in textures))
    x0, y0 = np.zeros(k, np.float32), np.zeros(k, np.float32)
    x = y = shelf_h = 0
    for tid in sorted(range(k), key=lambda i: -textures[i].shape[0]):  # tallest first
        h, w = textures[tid].shape[:2]
        if x + w > atlas_w:
            x, y, shelf_h = 0, y + shelf_h, 0
        x0[tid], y0[tid] = x, y
        x += w
        shelf_h = max(shelf_h, h)
    image = np.zeros((y + shelf_h, atlas_w, 3), np.uint8)
    for tid, tex in enumerate(textures):
        image[int(y0[tid]):int(y0[tid]) + tex.shape[0], int(x0[tid]):int(x0[tid]) + tex.shape[1]] \
            = tex
    if max(image.shape[:2]) >= 32767:
        raise ValueError(f"Texture atlas {image.shape[:2]} exceeds cv2.remap's 32767 limit: "
                         "increase texel_m.")
    sizes = np.array([t.shape[:2] for t in textures], np.float32)
    return TextureAtlas(image, x0, y0, sizes[:, 1], sizes[:, 0], texel_m)
