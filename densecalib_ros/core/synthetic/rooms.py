"""The rooms users calibrate in (issue 81): plain walls, floor and ceiling, a few textured things
against the walls (cupboards, shelves, posters), the middle left free for whoever walks through.

Unlike scene.random_scene's room, where every surface is richly textured and 8-11 objects stand
in the middle, here most of what a camera sees is plain (textures.PLAIN_STYLES)."""
from __future__ import annotations

import numpy as np

from .scene import Box, Scene

# Rooms from an office to a motion-capture lab: half extents (m) along x and y, and heights.
PLAIN_ROOM_HALF_M = ((3.0, 4.0), (2.6, 3.4))
PLAIN_ROOM_HEIGHT_M = (2.6, 3.2)
# Textured things: this many (inclusive) per room, each a cupboard or shelf (FURNITURE_*, a
# textured style of textures.STYLE_NAMES) or a poster (POSTER_*); Caliscope's room has two
# posters, shelves, a desk, a door, Pose2Sim's lab cupboards, desks, windows and a platform.
PLAIN_ROOM_THINGS = (6, 10)
FURNITURE_SIZE_M = ((0.4, 0.6), (0.6, 2.0), (0.7, 2.2))  # depth, width, height
# Each wall is papered or panelled (a textured style) with this chance: Caliscope's room has a
# wallpapered wall, Pose2Sim's lab windows and cupboards along two. With the things, the rooms'
# frames come out a little plainer than the real rooms' (at 640 px, 16 px blocks of mean
# gradient under 2 levels/px: 54 % median against 22-48 %; docs/benchmarks.md).
TEXTURED_WALL_CHANCE = 0.5
POSTER_SIZE_M = ((0.5, 1.0), (0.6, 1.2))  # width, height; 2 cm thick, 1.2-1.8 m up its middle
POSTER_HEIGHT_M = (1.2, 1.8)
POSTER_SHARE = 0.4  # of the things; Caliscope's room: two posters of five things
# A thing keeps this far (m, in the floor plane) from every camera: none stands in front of a
# lens, hiding the room.
THING_CAMERA_CLEARANCE_M = 1.0


def plain_room(rng: np.random.Generator) -> Scene:
    """An empty room (textures 0-5: walls -x, +x, -y, +y, floor, ceiling), its light near the
    ceiling."""
    half = np.array([rng.uniform(*PLAIN_ROOM_HALF_M[0]), rng.uniform(*PLAIN_ROOM_HALF_M[1])])
    room_max = np.array([half[0], half[1], rng.uniform(*PLAIN_ROOM_HEIGHT_M)])
    light = np.array([rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 1.0), room_max[2] - 0.2])
    return Scene(np.array([-half[0], -half[1], 0.0]), room_max, tuple(range(6)), [], light)


def _against_wall(rng: np.random.Generator, scene: Scene, depth: float, width: float,
                  height: float, z: float) -> Box:
    """A box of (depth, width, height) with its back on a random wall, its middle z high."""
    wall = int(rng.integers(4))  # -x, +x, -y, +y
    axis, sign = wall // 2, (-1.0, 1.0)[wall % 2]
    along = 1 - axis
    room_half = scene.room_max[:2]
    centre = np.zeros(3)
    # 5 mm off the wall (no two surfaces coincide), 10 cm from the corners.
    centre[axis] = sign * (room_half[axis] - depth / 2 - 0.005)
    centre[along] = rng.uniform(-1, 1) * max(room_half[along] - width / 2 - 0.1, 0.0)
    centre[2] = z
    size = np.array([depth, width, height]) if axis == 0 else np.array([width, depth, height])
    return Box(centre, size, 0.0, ())


def furnish(rng: np.random.Generator, scene: Scene, cameras_xyz: np.ndarray) -> list[Box]:
    """PLAIN_ROOM_THINGS cupboards, shelves and posters against the walls, each
    THING_CAMERA_CLEARANCE_M from every camera (a place is drawn again where one is not), with
    texture ids after the room's."""
    things, tex = [], 6
    for _ in range(int(rng.integers(PLAIN_ROOM_THINGS[0], PLAIN_ROOM_THINGS[1] + 1))):
        poster = rng.random() < POSTER_SHARE
        for _ in range(50):  # places drawn for a thing before it is left out
            if poster:
                w, h = (rng.uniform(*r) for r in POSTER_SIZE_M)
                box = _against_wall(rng, scene, 0.02, w, h, rng.uniform(*POSTER_HEIGHT_M))
            else:
                d, w, h = (rng.uniform(*r) for r in FURNITURE_SIZE_M)
                box = _against_wall(rng, scene, d, w, h, h / 2)
            gap = np.abs(np.asarray(cameras_xyz)[:, :2] - box.center[:2]) - box.size[:2] / 2
            if np.min(np.linalg.norm(np.maximum(gap, 0.0), axis=1)) >= THING_CAMERA_CLEARANCE_M:
                break
        else:
            continue  # no place clear of the cameras on this try: one thing fewer
        box.tex = tuple(range(tex, tex + 6))
        tex += 6
        things.append(box)
    return things


def plain_styles(rng: np.random.Generator, scene: Scene) -> dict[int, str]:
    """Texture style per id: plain walls (each papered with TEXTURED_WALL_CHANCE), floor and
    ceiling; each thing one textured material (posters "painted", furniture wood or painted)."""
    styles = {tid: str(rng.choice(["stone", "wood", "painted"]))
              if rng.random() < TEXTURED_WALL_CHANCE else "plain_wall"
              for tid in scene.room_tex[:4]}
    styles[scene.room_tex[4]] = "plain_floor"
    styles[scene.room_tex[5]] = "plain_wall"
    for thing in scene.objects:
        poster = min(thing.size[:2]) < 0.05  # 2 cm thick; furniture is at least 0.4 m deep
        style = "painted" if poster else str(rng.choice(["wood", "painted"]))
        styles.update({tid: style for tid in thing.tex})
    return styles
