"""Analytic scene of a synthetic rig: an enclosed room (floor, 4 walls, ceiling) holding boxes,
vertical cylinders and spheres, with vectorised ray casting in numpy.

World frame: metres, z up, floor at z = 0. Every surface (room face, box face, cylinder side/top,
sphere) has a texture id and local surface coordinates (u, v) in metres, attached to the object, so
a surface point looks the same from every camera and moves with its object between time steps.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

_EPS_T = 1e-6  # minimum hit distance (m): ignores self-hits at the ray origin


def _rot_z(yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@dataclass
class Box:
    """Box of size (sx, sy, sz) standing on z = centre.z - sz/2, rotated by yaw about z.
    tex: texture ids of the faces (-x, +x, -y, +y, -z, +z)."""

    center: np.ndarray  # (3,) world
    size: np.ndarray  # (3,)
    yaw: float
    tex: tuple[int, ...]

    def bound_center(self) -> np.ndarray:
        return self.center

    def bound_radius(self) -> float:
        return float(np.linalg.norm(self.size)) / 2 * 1.001

    def extents_uv(self) -> list[tuple[float, float]]:
        sx, sy, sz = self.size
        return [(sy, sz), (sy, sz), (sx, sz), (sx, sz), (sx, sy), (sx, sy)]


@dataclass
class Cylinder:
    """Vertical cylinder from z0 to z0 + height, rotated by yaw (moves its texture). tex: (side, top)."""

    center: np.ndarray  # (3,): x, y of the axis, z0 of the bottom
    radius: float
    height: float
    yaw: float
    tex: tuple[int, ...]

    def bound_center(self) -> np.ndarray:
        return self.center + np.array([0.0, 0.0, self.height / 2])

    def bound_radius(self) -> float:
        return float(np.hypot(self.radius, self.height / 2)) * 1.001

    def extents_uv(self) -> list[tuple[float, float]]:
        return [(2 * np.pi * self.radius, self.height), (2 * self.radius, 2 * self.radius)]


@dataclass
class Sphere:
    center: np.ndarray  # (3,)
    radius: float
    yaw: float
    tex: tuple[int, ...]  # (surface,)

    def bound_center(self) -> np.ndarray:
        return self.center

    def bound_radius(self) -> float:
        return self.radius * 1.001

    def extents_uv(self) -> list[tuple[float, float]]:
        return [(2 * np.pi * self.radius, np.pi * self.radius)]


@dataclass
class Hit:
    """Ray-cast result for n rays: distance t along the (unit) ray, inf where nothing was hit;
    texture id (-1 = none), surface coordinates uv (metres), unit normal facing the ray origin."""

    t: np.ndarray  # (n,)
    tex: np.ndarray  # (n,) int32
    uv: np.ndarray  # (n, 2)
    normal: np.ndarray  # (n, 3)


@dataclass
class Scene:
    room_min: np.ndarray  # (3,)
    room_max: np.ndarray  # (3,)
    room_tex: tuple[int, ...]  # faces (-x, +x, -y, +y, floor, ceiling)
    objects: list = field(default_factory=list)
    light_pos: np.ndarray = field(default_factory=lambda: np.array([0.6, -0.9, 2.8]))

    def surface_extents(self) -> dict[int, tuple[float, float]]:
        """Texture id -> (u, v) extent in metres of the surface it covers."""
        size = self.room_max - self.room_min
        ext = {self.room_tex[0]: (size[1], size[2]), self.room_tex[1]: (size[1], size[2]),
               self.room_tex[2]: (size[0], size[2]), self.room_tex[3]: (size[0], size[2]),
               self.room_tex[4]: (size[0], size[1]), self.room_tex[5]: (size[0], size[1])}
        for obj in self.objects:
            ext.update(zip(obj.tex, obj.extents_uv()))
        return ext

    def moved(self, rng: np.random.Generator, moving: list[int], step_m: float) -> "Scene":
        """A copy with the objects at indices `moving` shifted (<= step_m) and turned, kept inside
        the central area where they were generated."""
        objs = list(self.objects)
        for i in moving:
            o = objs[i]
            shift = np.zeros(3)
            shift[:2] = rng.uniform(-step_m, step_m, 2)
            c = o.center + shift
            c[:2] = np.clip(c[:2], 0.45 * self.room_min[:2], 0.45 * self.room_max[:2])
            objs[i] = replace(o, center=c, yaw=o.yaw + rng.uniform(-0.4, 0.4))
        return replace(self, objects=objs)

    def intersect(self, origin: np.ndarray, dirs: np.ndarray) -> Hit:
        """Cast rays origin + t * dirs (origin (3,) world, dirs (n, 3) unit, world frame).
        The origin must be inside the room and outside every object."""
        n = dirs.shape[0]
        dt = dirs.dtype
        origin = np.asarray(origin, dt)  # keep float32 rays in float32 (speed)
        best_t = _room_exit(origin, dirs, self.room_min.astype(dt), self.room_max.astype(dt))
        best_k = np.full(n, -1, np.int32)  # -1 = room, k = objects[k]
        for k, obj in enumerate(self.objects):
            # Cull with the bounding sphere (one mat-vec) before the exact test.
            rel = (origin - obj.bound_center()).astype(dt)
            b = dirs @ rel
            cand = np.nonzero(b * b - (float(rel @ rel) - obj.bound_radius() ** 2) > 0)[0]
            if cand.size == 0:
                continue
            t = _INTERSECT_T[type(obj)](obj, origin, dirs[cand])
            closer = t < best_t[cand]
            best_t[cand[closer]] = t[closer]
            best_k[cand[closer]] = k
        tex = np.full(n, -1, np.int32)
        uv = np.zeros((n, 2), dt)
        normal = np.zeros((n, 3), dt)
        hit = np.isfinite(best_t)
        sel = np.nonzero(hit & (best_k == -1))[0]
        if sel.size:
            _room_surface(self, origin, dirs[sel], best_t[sel], sel, tex, uv, normal)
        for k, obj in enumerate(self.objects):
            sel = np.nonzero(best_k == k)[0]
            if sel.size:
                _SURFACE[type(obj)](obj, origin, dirs[sel], best_t[sel], sel, tex, uv, normal)
        # Normals face the viewer (room faces point inwards already, objects outwards).
        return Hit(best_t, tex, uv, normal)


def _room_axis_t(origin, dirs, lo, hi):
    """Exit distance of rays from inside the room along each axis: 3 arrays (n,)."""
    out = []
    with np.errstate(divide="ignore", invalid="ignore"):
        for i in range(3):
            d = dirs[:, i]
            t = np.where(d > 0, (hi[i] - origin[i]) / d, (lo[i] - origin[i]) / d)
            out.append(np.where(d == 0, np.inf, t))
    return out


def _room_exit(origin, dirs, lo, hi):
    tx, ty, tz = _room_axis_t(origin, dirs, lo, hi)
    return np.minimum(np.minimum(tx, ty), tz)


_ROOM_NORMALS = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1.0]])


def _room_surface(scene, origin, d, t, sel, tex, uv, normal):
    lo, hi = scene.room_min.astype(d.dtype), scene.room_max.astype(d.dtype)
    tx, ty, tz = _room_axis_t(origin, d, lo, hi)
    on_x = tx <= np.minimum(ty, tz)
    on_z = ~on_x & (tz < ty)
    # face: 0:-x 1:+x 2:-y 3:+y 4:floor 5:ceiling (the wall the ray leaves through)
    face = np.where(on_x, (d[:, 0] > 0).astype(np.int32),
                    np.where(on_z, 4 + (d[:, 2] > 0), 2 + (d[:, 1] > 0)))
    q = origin - lo + t[:, None] * d
    tex[sel] = np.asarray(scene.room_tex, np.int32)[face]
    uv[sel, 0] = np.where(on_x, q[:, 1], q[:, 0])
    uv[sel, 1] = np.where(on_z, q[:, 1], q[:, 2])
    normal[sel] = _ROOM_NORMALS.astype(d.dtype)[face]  # pointing into the room


def _local(obj, origin, dirs):
    r_world_from_obj = _rot_z(obj.yaw)
    # row vectors: x_obj = R^T x_world
    o = ((origin - obj.center) @ r_world_from_obj).astype(dirs.dtype)
    d = dirs @ r_world_from_obj.astype(dirs.dtype)
    return o, d, r_world_from_obj


def _box_t(box, origin, dirs):
    o, d, _ = _local(box, origin, dirs)
    half = (box.size / 2).astype(d.dtype)
    with np.errstate(divide="ignore", invalid="ignore"):
        t1 = (-half - o) / d
        t2 = (half - o) / d
    # Rays parallel to a slab: inside it -> unbounded, outside -> miss.
    par = d == 0
    inside = np.abs(o) <= half
    t1 = np.where(par, np.where(inside, -np.inf, np.inf), t1)
    t2 = np.where(par, np.where(inside, np.inf, -np.inf), t2)
    lo, hi = np.minimum(t1, t2), np.maximum(t1, t2)
    t_near = np.maximum(np.maximum(lo[:, 0], lo[:, 1]), lo[:, 2])
    t_far = np.minimum(np.minimum(hi[:, 0], hi[:, 1]), hi[:, 2])
    ok = (t_near <= t_far) & (t_near > _EPS_T)
    return np.where(ok, t_near, np.inf)


def _box_surface(box, origin, dirs, t, sel, tex, uv, normal):
    o, d, r = _local(box, origin, dirs)
    half = (box.size / 2).astype(d.dtype)
    p = o + t[:, None] * d
    axis = (np.abs(p) / half).argmax(axis=1)
    positive = p[np.arange(len(p)), axis] > 0
    face = 2 * axis + positive
    q = p + half
    u = np.where(axis == 0, q[:, 1], q[:, 0])
    v = np.where(axis == 2, q[:, 1], q[:, 2])
    tex[sel] = np.asarray(box.tex, np.int32)[face]
    uv[sel, 0] = u
    uv[sel, 1] = v
    nrm = np.zeros_like(d)
    nrm[np.arange(len(d)), axis] = np.where(positive, 1.0, -1.0)
    normal[sel] = nrm @ r.T.astype(d.dtype)


def _cyl_t(cyl, origin, dirs):
    o, d, _ = _local(cyl, origin, dirs)
    a = d[:, 0] ** 2 + d[:, 1] ** 2
    b = 2 * (o[0] * d[:, 0] + o[1] * d[:, 1])
    c = o[0] ** 2 + o[1] ** 2 - cyl.radius ** 2
    disc = b * b - 4 * a * c
    with np.errstate(divide="ignore", invalid="ignore"):
        t_side = (-b - np.sqrt(np.maximum(disc, 0))) / (2 * a)
        z = o[2] + t_side * d[:, 2]
        side_ok = (disc > 0) & (a > 0) & (t_side > _EPS_T) & (z >= 0) & (z <= cyl.height)
        t_top = (cyl.height - o[2]) / d[:, 2]
        xt = o[0] + t_top * d[:, 0]
        yt = o[1] + t_top * d[:, 1]
        top_ok = (d[:, 2] < 0) & (t_top > _EPS_T) & (xt * xt + yt * yt <= cyl.radius ** 2)
    return np.minimum(np.where(side_ok, t_side, np.inf), np.where(top_ok, t_top, np.inf))


def _cyl_surface(cyl, origin, dirs, t, sel, tex, uv, normal):
    o, d, r = _local(cyl, origin, dirs)
    p = o + t[:, None] * d
    on_top = np.abs(p[:, 2] - cyl.height) < 1e-6 * max(1.0, cyl.height)
    on_top &= p[:, 0] ** 2 + p[:, 1] ** 2 < cyl.radius ** 2 * (1 - 1e-9)
    ang = np.arctan2(p[:, 1], p[:, 0]) + np.pi
    u = np.where(on_top, p[:, 0] + cyl.radius, ang * cyl.radius)
    v = np.where(on_top, p[:, 1] + cyl.radius, p[:, 2])
    tex[sel] = np.where(on_top, cyl.tex[1], cyl.tex[0])
    uv[sel, 0] = u
    uv[sel, 1] = v
    nrm = np.stack([p[:, 0], p[:, 1], np.zeros_like(p[:, 0])], axis=1) / cyl.radius
    nrm[on_top] = (0.0, 0.0, 1.0)
    normal[sel] = nrm @ r.T.astype(d.dtype)


def _sphere_t(sph, origin, dirs):
    o = (origin - sph.center).astype(dirs.dtype)
    b = dirs @ o
    c = float(o @ o) - sph.radius ** 2
    disc = b * b - c
    t = -b - np.sqrt(np.maximum(disc, 0))
    return np.where((disc > 0) & (t > _EPS_T), t, np.inf)


def _sphere_surface(sph, origin, dirs, t, sel, tex, uv, normal):
    o, d, r = _local(sph, origin, dirs)
    p = o + t[:, None] * d
    nrm = p / sph.radius
    lon = np.arctan2(nrm[:, 1], nrm[:, 0]) + np.pi
    lat = np.arcsin(np.clip(nrm[:, 2], -1, 1)) + np.pi / 2
    tex[sel] = sph.tex[0]
    uv[sel, 0] = lon * sph.radius
    uv[sel, 1] = lat * sph.radius
    normal[sel] = nrm @ r.T.astype(d.dtype)


_INTERSECT_T = {Box: _box_t, Cylinder: _cyl_t, Sphere: _sphere_t}
_SURFACE = {Box: _box_surface, Cylinder: _cyl_surface, Sphere: _sphere_surface}


def random_scene(rng: np.random.Generator, next_tex: int = 0) -> Scene:
    """A room of about 7 x 6 x 3 m with 8-11 objects in its central area (|x|, |y| < ~1.7 m)."""
    half = np.array([rng.uniform(3.3, 3.8), rng.uniform(2.8, 3.3)])
    room_min = np.array([-half[0], -half[1], 0.0])
    room_max = np.array([half[0], half[1], rng.uniform(2.7, 3.2)])
    tex = iter(range(next_tex, next_tex + 10_000))
    room_tex = tuple(next(tex) for _ in range(6))
    objects = []
    n_obj = int(rng.integers(8, 12))
    for i in range(n_obj):
        xy = rng.uniform(-1.0, 1.0, 2) * np.array([1.6, 1.3])
        kind = ("box", "box", "cyl", "sphere")[i % 4] if i < 4 else rng.choice(
            ["box", "box", "cyl", "sphere"])
        yaw = rng.uniform(-np.pi, np.pi)
        if kind == "box":
            size = np.array([rng.uniform(0.25, 0.8), rng.uniform(0.25, 0.8), rng.uniform(0.2, 1.3)])
            objects.append(Box(np.array([xy[0], xy[1], size[2] / 2]), size, yaw,
                               tuple(next(tex) for _ in range(6))))
        elif kind == "cyl":
            objects.append(Cylinder(np.array([xy[0], xy[1], 0.0]), rng.uniform(0.12, 0.35),
                                    rng.uniform(0.4, 1.6), yaw, (next(tex), next(tex))))
        else:
            rad = rng.uniform(0.15, 0.4)
            z = rad + (rng.uniform(0.0, 0.8) if rng.random() < 0.4 else 0.0)
            objects.append(Sphere(np.array([xy[0], xy[1], z]), rad, yaw, (next(tex),)))
    light = np.array([rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 1.0), room_max[2] - 0.2])
    return Scene(room_min, room_max, room_tex, objects, light)
