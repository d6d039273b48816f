"""A person or a four-legged animal walking a loop through a generated room over the time steps:
a compound body of the scene's primitives (boxes, vertical cylinders, spheres), turned to face
where it walks, its legs (and a person's arms) swinging with the gait.

Body frame: x forward (the heading), y to the left, z up; sizes in metres for a body of scale 1.
Each part keeps its texture ids at every time step, so its surface moves with it.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .scene import Box, Cylinder, Scene, Sphere

WALKERS = ("none", "person", "animal")
# People of 1.55-1.9 m: the person below is 1.72 m tall at scale 1.
PERSON_SCALE = (0.9, 1.1)
# Animals from a large dog to a deer: the animal below is 1.1 m long, 1.1 m to the head's top.
ANIMAL_SCALE = (0.8, 1.3)
# A gait cycle (two steps): a person's 1.4 m, a trotting animal's 1.0 m at scale 1.
STRIDE_M = {"person": 1.4, "animal": 1.0}
# The loop keeps this far from the walls (m): the cameras stand up to 0.9 m from them, the
# furniture is at most 0.6 m deep and the largest body reaches 0.9 m from its centre.
WALK_WALL_MARGIN_M = 1.5
# The loop's half axes: this fraction (uniform) of what the margin leaves, so that it crosses
# most of the floor between the cameras.
WALK_EXTENT = (0.6, 1.0)
# No part of the body comes nearer a camera than this (m): the loop shrinks until none does.
CAMERA_CLEARANCE_M = 0.3


@dataclass(frozen=True)
class Walk:
    """Where the walker is at each time step: xy (T, 2) metres on the floor, heading (T,) rad
    from +x, gait phase (T,) rad; its kind and scale."""

    kind: str
    scale: float
    xy: np.ndarray
    heading: np.ndarray
    phase: np.ndarray


def walk_loop(rng: np.random.Generator, kind: str, scene: Scene, steps: int,
              cameras_xyz: np.ndarray) -> Walk:
    """One lap of an ellipse about the room's centre over `steps` time steps (the frame sets are
    spread over the walk), starting anywhere on it, either way round, shrunk until the body
    keeps CAMERA_CLEARANCE_M from every camera centre (cameras_xyz (N, 3))."""
    scale = rng.uniform(*(PERSON_SCALE if kind == "person" else ANIMAL_SCALE))
    room = np.minimum(-scene.room_min[:2], scene.room_max[:2])
    # At least 0.3 m half axes: a loop, not a walk on the spot, in the smallest room.
    axes = np.maximum(room - WALK_WALL_MARGIN_M, 0.3) * rng.uniform(*WALK_EXTENT, 2)
    turn = rng.choice([-1.0, 1.0])
    angle = rng.uniform(0, 2 * np.pi) + turn * 2 * np.pi * np.arange(steps) / steps
    phase0 = rng.uniform(0, 2 * np.pi)
    while True:
        xy = np.stack([axes[0] * np.cos(angle), axes[1] * np.sin(angle)], axis=1)
        velocity = turn * np.stack([-axes[0] * np.sin(angle), axes[1] * np.cos(angle)], axis=1)
        heading = np.arctan2(velocity[:, 1], velocity[:, 0])
        walked = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))]
        phase = phase0 + 2 * np.pi * walked / (STRIDE_M[kind] * scale)
        walk = Walk(kind, float(scale), xy, heading, phase)
        if _clear_of(walk, cameras_xyz) or axes.max() < 0.05:  # 5 cm: about on the spot
            return walk
        axes = axes * 0.85  # a little smaller each try: the loop stays as wide as it can


def _clear_of(walk: Walk, cameras_xyz: np.ndarray) -> bool:
    for t in range(len(walk.xy)):
        centre, radius = bound_of(walker_parts(walk, t, 0))
        if np.min(np.linalg.norm(np.asarray(cameras_xyz) - centre, axis=1)) \
                < radius + CAMERA_CLEARANCE_M:
            return False
    return True


def _at(walk: Walk, t: int, forward: float, left: float, z: float) -> np.ndarray:
    """A point of the body frame at time t (scaled) in the world."""
    c, s = np.cos(walk.heading[t]), np.sin(walk.heading[t])
    f, lt = forward * walk.scale, left * walk.scale
    return np.array([walk.xy[t, 0] + c * f - s * lt, walk.xy[t, 1] + s * f + c * lt,
                     z * walk.scale])


def _person(walk: Walk, t: int) -> list:
    """Legs, arms (cylinders), torso (box), head (sphere), without textures: an adult's
    proportions (legs 0.85 m, torso 0.6 m tall and 0.38 m across the shoulders, arms 0.6 m,
    head 0.22 m), a foot 0.16 m ahead or behind at mid-swing, a hand 0.12 m."""
    k, h, swing = walk.scale, float(walk.heading[t]), np.sin(walk.phase[t])
    parts = []
    for side in (1.0, -1.0):  # a leg forward, the same side's arm back
        parts.append(Cylinder(_at(walk, t, 0.16 * side * swing, 0.1 * side, 0.0), 0.075 * k,
                              0.85 * k, h, ()))
        parts.append(Cylinder(_at(walk, t, -0.12 * side * swing, 0.25 * side, 0.83), 0.05 * k,
                              0.6 * k, h, ()))
    parts.append(Box(_at(walk, t, 0.0, 0.0, 1.15), np.array([0.22, 0.38, 0.6]) * k, h, ()))
    parts.append(Sphere(_at(walk, t, 0.0, 0.0, 1.6), 0.11 * k, h, ()))
    return parts


def _animal(walk: Walk, t: int) -> list:
    """Four legs (cylinders, diagonal pairs together: a trot), body and neck (boxes), head: a
    dog's proportions (legs 0.5 m, a 0.9 m body, the head up front at 1.05 m), a foot 0.1 m
    ahead or behind at mid-swing."""
    k, h, swing = walk.scale, float(walk.heading[t]), np.sin(walk.phase[t])
    parts = []
    for fore in (0.33, -0.33):
        for side in (0.11, -0.11):
            pair = 1.0 if (fore > 0) == (side > 0) else -1.0
            parts.append(Cylinder(_at(walk, t, fore + 0.1 * pair * swing, side, 0.0), 0.045 * k,
                                  0.5 * k, h, ()))
    parts.append(Box(_at(walk, t, 0.0, 0.0, 0.67), np.array([0.9, 0.32, 0.34]) * k, h, ()))
    parts.append(Box(_at(walk, t, 0.42, 0.0, 0.88), np.array([0.14, 0.14, 0.3]) * k, h, ()))
    parts.append(Sphere(_at(walk, t, 0.55, 0.0, 1.05), 0.12 * k, h, ()))
    return parts


def _with_textures(parts: list, first_tex: int) -> list:
    """The parts with consecutive texture ids from first_tex (the same ids at every step)."""
    out, tex = [], first_tex
    for p in parts:
        count = {Box: 6, Cylinder: 2, Sphere: 1}[type(p)]
        p.tex = tuple(range(tex, tex + count))
        tex += count
        out.append(p)
    return out


def walker_parts(walk: Walk, t: int, first_tex: int) -> list:
    """The walker's parts at time step t, textured from id first_tex on."""
    return _with_textures((_person if walk.kind == "person" else _animal)(walk, t), first_tex)


def walker_styles(rng: np.random.Generator, kind: str, parts: list) -> dict[int, str]:
    """Texture style per id of the walker's parts (textures.PLAIN_STYLES): a person's legs and
    torso in cloth, arms bare or in sleeves, the head skin; an animal's coat fur all over."""
    if kind == "animal":
        return {tid: "fur" for p in parts for tid in p.tex}
    sleeves = "cloth" if rng.random() < 0.5 else "skin"  # half of them in sleeves
    styles = {}
    for i, p in enumerate(parts):  # _person's order: (leg, arm) x 2, torso, head
        style = "skin" if isinstance(p, Sphere) else sleeves if i in (1, 3) else "cloth"
        styles.update({tid: style for tid in p.tex})
    return styles


def bound_of(parts: list) -> tuple[np.ndarray, float]:
    """A sphere (centre (3,), radius m) holding all the parts."""
    centres = np.array([p.bound_center() for p in parts])
    centre = (centres.min(axis=0) + centres.max(axis=0)) / 2
    radius = max(float(np.linalg.norm(p.bound_center() - centre)) + p.bound_radius()
                 for p in parts)
    return centre, radius * 1.001
