"""Burnt-in info strips found automatically (core.method.info_strip): a trail camera's bar of text
along the top or bottom edge is found (dark or light, JPEG-compressed, both edges), and what is not
a bar is left alone: textured scenes, a flat sky, a fisheye's black border around its image circle,
a vignetted flat ceiling, and the real images in ../shared/data."""
import glob
import os
from pathlib import Path

import cv2
import numpy as np
import pytest

from densecalib_ros.core.method.info_strip import InfoStrip, find_info_strip, strips_mask
from densecalib_ros.core.synthetic import RigSpec, generate_rig

TEXT = "2026-05-01 10:00:05  23C  1012hPa  MOON 3/4  CAM 2"


@pytest.fixture(scope="module")
def scene():
    """Two textured 640x480 frames of one generated camera."""
    rig = generate_rig(RigSpec(lenses="ideal", num_cameras=3, camera_model="RADIAL", width=640, height=480,
                               num_time_steps=2, seed=4))
    return [frames[0] for frames in rig.images]


def _bar(image, side="bottom", rows=30, colour=0, ink=255, text=TEXT):
    out = image.copy()
    band = slice(0, rows) if side == "top" else slice(image.shape[0] - rows, None)
    out[band] = colour
    baseline = rows - 9 if side == "top" else image.shape[0] - 9
    cv2.putText(out, text, (6, baseline), cv2.FONT_HERSHEY_SIMPLEX, 0.55, (ink,) * 3, 1,
                cv2.LINE_AA)
    return out


def test_bars_of_text_are_found(scene):
    assert find_info_strip(scene) == []
    assert find_info_strip([_bar(im) for im in scene]) == [InfoStrip("bottom", 34)]  # + margin
    assert find_info_strip([_bar(im, "top", 40, colour=235, ink=10) for im in scene]) == [
        InfoStrip("top", 44)]  # dark text on a light bar
    both = [_bar(_bar(im, "top", 24, text="TRAILCAM PRO"), "bottom") for im in scene]
    assert find_info_strip(both) == [InfoStrip("top", 28), InfoStrip("bottom", 34)]
    jpeg = [cv2.imdecode(cv2.imencode(".jpg", _bar(im), [cv2.IMWRITE_JPEG_QUALITY, 60])[1],
                         cv2.IMREAD_UNCHANGED) for im in scene]
    (strip,) = find_info_strip(jpeg)  # the blurred edge may cost a row or two of the bar
    assert strip.side == "bottom" and 30 <= strip.rows <= 34
    mask = strips_mask(find_info_strip(both), 480, 640)
    assert mask[:28].all() and mask[-34:].all() and not mask[28:-34].any()


def test_what_is_not_a_bar_is_left_alone(scene):
    flat_sky = [im.copy() for im in scene]
    for im in flat_sky:
        im[:60] = 200  # a flat sky without text
    assert find_info_strip(flat_sky) == []
    # a bar without text, or text without a bar edge to edge
    assert find_info_strip([_bar(im, text="") for im in scene]) == []
    # a fisheye's black border: the image circle's scene reaches into it, widening row by row
    fisheye = [im.copy() for im in scene]
    ys, xs = np.mgrid[:480, :640]
    outside = (xs - 320) ** 2 + (ys - 240) ** 2 > 300 ** 2
    for im in fisheye:
        im[outside] = 0
    assert find_info_strip(fisheye) == []
    # a flat, vignetted ceiling with lamps: dark corners, not a bar from edge to edge
    ceiling = np.full((480, 640, 3), 150, np.uint8)
    ceiling[(xs - 320) ** 2 + (ys - 240) ** 2 > 330 ** 2] = 30
    for x in range(60, 600, 60):
        cv2.circle(ceiling, (x, 20), 5, (255, 255, 255), -1)
    assert find_info_strip([ceiling]) == []
    # a bar found in only one frame of three, or at heights far apart, is no bar
    assert find_info_strip([_bar(scene[0]), scene[1], scene[1]]) == []
    assert find_info_strip([_bar(scene[0], rows=20), _bar(scene[1], rows=60)]) == []


def test_real_images_have_no_info_strip():
    data = Path(os.environ.get("DENSECALIB_DATA", Path(__file__).resolve().parents[2] / "shared"
                               / "data"))
    files = sorted(glob.glob(str(data / "**" / "*.jpg"), recursive=True)
                   + glob.glob(str(data / "**" / "*.png"), recursive=True))
    if not files:
        pytest.skip(f"no real images under {data} (the shared test data)")
    from densecalib_ros.core.io.image_io import read_image

    found = [f for f in files if find_info_strip([read_image(f)])]
    assert found == [], found
