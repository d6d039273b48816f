"""A generated arena for the time-offset tests: an animal (a bright disc) walks over a textured
floor; each camera films its own part of it at its own frame rate, start time and gain."""
import cv2
import numpy as np

WORLD_H, WORLD_W = 360, 640
DURATION_S = 20.0


def animal_path(seed=0):
    """World position (x, y) [px] of an animal over time: rests and dashes of random speed and
    heading, tabulated every millisecond from before the first to after the last recording."""
    rng = np.random.default_rng(seed)
    t = np.arange(-3.0, DURATION_S + 3.0, 0.001)
    speed = np.zeros_like(t)
    start = 0
    while start < len(t):
        length = int(rng.uniform(0.2, 1.2) * 1000)
        speed[start:start + length] = rng.choice([0.0, rng.uniform(60, 400)])
        start += length
    heading = np.cumsum(rng.normal(0, 0.02, len(t)))
    pos = np.zeros((len(t), 2))
    pos[0] = (WORLD_W / 2, WORLD_H / 2)
    for i in range(1, len(t)):
        step = speed[i] * 0.001 * np.array([np.cos(heading[i]), np.sin(heading[i])])
        nxt = pos[i - 1] + step
        if not (40 < nxt[0] < WORLD_W - 40 and 40 < nxt[1] < WORLD_H - 40):
            heading[i:] += np.pi  # turn back at the arena wall
            nxt = pos[i - 1] - step
        pos[i] = nxt
    return t, pos


def arena_views(cameras, moving=True, size=(320, 200), seed=1):
    """camera -> generator of its grey frames (frame k at world time start + k / fps) for
    cameras = {name: (fps, start in world time [s], view (y0, y1, x0, x1) of the world, gain)},
    DURATION_S long."""
    rng = np.random.default_rng(seed)
    floor = cv2.resize(rng.integers(60, 120, (36, 64), dtype=np.uint8), (WORLD_W, WORLD_H),
                       interpolation=cv2.INTER_LINEAR)
    t_path, pos = animal_path()

    def frames(fps, start_s, view_box, gain):
        y0, y1, x0, x1 = view_box
        for k in range(int(DURATION_S * fps)):
            world = floor.copy()
            if moving:
                x, y = pos[np.searchsorted(t_path, start_s + k / fps)]
                cv2.circle(world, (int(round(x)), int(round(y))), 22, 230, -1)
                cv2.circle(world, (int(round(x)) + 8, int(round(y))), 7, 20, -1)
            view = cv2.resize(world[y0:y1, x0:x1], size, interpolation=cv2.INTER_AREA)
            view = view.astype(np.float32) * gain + rng.normal(0, 2, view.shape)
            yield np.clip(view, 0, 255).astype(np.uint8)

    return {name: frames(*spec) for name, spec in cameras.items()}
