"""Focal lengths from EXIF: the two tag routes, the checks, and real files written by Pillow."""
import logging
import math

import numpy as np
import pytest
from PIL import Image

from densecalib_ros.core.io.exif import camera_exif_focals, exif_focal_px, focal_px_from_tags

FOCAL_35MM, FOCAL_MM, PLANE_X_RES, PLANE_UNIT = 0xA405, 0x920A, 0xA20E, 0xA210
PIXEL_X, PIXEL_Y = 0xA002, 0xA003


def write_image(path, size, tags):
    """An image file of size (width, height) whose Exif sub-IFD holds `tags`."""
    exif = Image.Exif()
    exif[0x010F] = "densecalib test"  # Make: Pillow skips an Exif block without IFD0 entries
    exif.get_ifd(0x8769).update(tags)
    Image.fromarray(np.zeros((size[1], size[0], 3), np.uint8)).save(path, exif=exif)


def test_35mm_equivalent_is_taken_on_the_diagonal():
    # A 3:2 image is the 36 x 24 mm frame's shape: 36 mm equivalent = a focal of its width.
    assert focal_px_from_tags({FOCAL_35MM: 36}, (6000, 4000)) == pytest.approx(6000.0)
    # 4:3 at 28 mm equivalent (a phone's main camera): 28 / 43.27 of the 5000 px diagonal.
    assert focal_px_from_tags({FOCAL_35MM: 28}, (4000, 3000)) == pytest.approx(
        28 * 5000 / math.hypot(36, 24))
    # It wins over the focal-plane route, which would give another value here.
    tags = {FOCAL_35MM: 36, FOCAL_MM: 4.5, PLANE_X_RES: 1000.0, PLANE_UNIT: 4}
    assert focal_px_from_tags(tags, (6000, 4000)) == pytest.approx(6000.0)


def test_focal_plane_resolution_is_scaled_to_the_image_as_loaded():
    tags = {FOCAL_MM: 4.5, PLANE_X_RES: 1000.0, PLANE_UNIT: 4, PIXEL_X: 4000, PIXEL_Y: 3000}
    assert focal_px_from_tags(tags, (4000, 3000)) == pytest.approx(4500.0)
    assert focal_px_from_tags(tags, (2000, 1500)) == pytest.approx(2250.0)  # downscaled file
    assert focal_px_from_tags(tags, (1500, 2000)) == pytest.approx(2250.0)  # turned upright
    inch = {FOCAL_MM: 25.4, PLANE_X_RES: 2540.0, PLANE_UNIT: 2}
    assert focal_px_from_tags(inch, (3000, 2000)) == pytest.approx(2540.0)


@pytest.mark.parametrize("tags", [{}, {FOCAL_MM: 4.5}, {FOCAL_35MM: 0},
                                  {FOCAL_MM: 4.5, PLANE_X_RES: 1000.0, PLANE_UNIT: 1},
                                  {FOCAL_35MM: 2000}])  # no scale / no unit / 60x the image
def test_no_focal_without_a_scale_or_when_implausible(tags):
    assert focal_px_from_tags(tags, (1024, 768)) is None


def test_files_with_and_without_exif(tmp_path):
    write_image(tmp_path / "a.jpg", (640, 480), {FOCAL_35MM: 30})
    assert exif_focal_px(tmp_path / "a.jpg", (640, 480)) == pytest.approx(
        30 * 800 / math.hypot(36, 24))
    write_image(tmp_path / "b.png", (640, 480), {FOCAL_35MM: 30})  # PNG eXIf chunk
    assert exif_focal_px(tmp_path / "b.png", (640, 480)) == pytest.approx(
        30 * 800 / math.hypot(36, 24))
    Image.fromarray(np.zeros((48, 64), np.uint8)).save(tmp_path / "c.png")
    assert exif_focal_px(tmp_path / "c.png", (64, 48)) is None
    (tmp_path / "d.jpg").write_bytes(b"not an image")
    assert exif_focal_px(tmp_path / "d.jpg", (64, 48)) is None


def test_camera_focals_need_every_image_and_one_zoom(tmp_path, caplog):
    size = (640, 480)
    paths = []
    for t, (f_a, f_b, f_c) in enumerate([(30, 30, 24), (30, 50, None)]):
        row = []
        for name, f in (("a", f_a), ("b", f_b), ("c", f_c)):
            path = tmp_path / f"{name}{t}.jpg"
            write_image(path, size, {} if f is None else {FOCAL_35MM: f})
            row.append(path)
        paths.append(row)
    with caplog.at_level(logging.WARNING):
        focals = camera_exif_focals(paths, ["a", "b", "c"], [size] * 3)
    # a: the same on both; b: zoom changed (warned, left out); c: one image has none.
    assert list(focals) == ["a"] and focals["a"] == pytest.approx(30 * 800 / math.hypot(36, 24))
    assert "Camera b" in caplog.text and "differ" in caplog.text
