"""Residual overlays (core.products.overlay): colour bands and legend on a drawn image; the
residuals of a real COLMAP model equal pycolmap's own projection of its points."""
import numpy as np
import pycolmap
import pytest

from densecalib_ros.core.errors import InputError
from densecalib_ros.core.products.overlay import (BANDS_PX, camera_residuals, draw_residuals,
                                                  legend_band, legend_lines)


def test_dots_take_the_colour_of_their_residual_band():
    observed = np.array([[20.0, 60.0], [60.0, 60.0], [100.0, 60.0]])
    reprojected = observed + np.array([[0.5, 0.0], [0.0, 2.0], [0.0, 5.0]])
    image = draw_residuals(np.zeros((120, 160, 3), np.uint8), observed, reprojected, title="cam7")
    assert image.shape == (120, 160, 3)  # at the image's size
    for (x, y), (_, colour) in zip(observed.astype(int), BANDS_PX):
        assert tuple(image[y, x]) == colour
    assert image[5:15, 5:60].any()  # the legend
    gray = draw_residuals(np.zeros((120, 160), np.uint8), observed[:0], reprojected[:0])
    assert gray.shape == (120, 160, 3)


def _lines(band):
    """The number of lines of a legend band: rows of ink parted by rows without."""
    inked = np.flatnonzero(band.any(axis=(1, 2)))
    return 1 + int((np.diff(inked) > 1).sum())


def test_the_legend_is_never_cut_off():
    """A long camera name on a narrow image: the legend wraps (and its letters shrink) to stay
    within the width; on a wide image it takes fewer lines. Its colour key shows the three
    bands' colours. Drawn across the top over the image darkened, or across the bottom where
    the top holds more points."""
    title = "arena_north_east_ceiling_cam_07"
    lines = legend_lines(np.array([0.5, 2.0]), 10.0, title)
    words = [w for line in lines for text, _ in line for w in text.split()]
    assert title + ":" in words and "x10" in words and "median" in words
    bands = {width: legend_band(lines, width) for width in (160, 1600)}
    for width, band in bands.items():
        assert band.shape[1:] == (width, 3)
        letters = np.flatnonzero((band == 255).all(axis=2).any(axis=0))
        assert letters.max() < width - 2  # no letter runs off the right edge
        for _, colour in BANDS_PX:  # the key's swatches
            assert (band == colour).all(axis=2).sum() >= 16
    assert _lines(bands[1600]) == 2 and _lines(bands[160]) >= 4  # wrapped onto more lines

    background = np.full((120, 160, 3), 200, np.uint8)
    image = draw_residuals(background, np.zeros((0, 2)), np.zeros((0, 2)), title=title)
    height = len(legend_band(legend_lines(np.zeros(0), 10.0, title), 160))
    changed = np.flatnonzero((image != background).any(axis=(1, 2)))
    assert changed.min() == 0 and changed.max() == height - 1  # across the top
    assert (image[:height] == int(200 * 0.35)).all(axis=2).mean() > 0.5  # darkened beneath
    crowded_top = np.column_stack([np.linspace(5, 150, 40), np.full(40, 10.0)])
    image = draw_residuals(np.zeros((120, 160, 3), np.uint8), crowded_top, crowded_top + 0.2)
    assert (image[:20] == BANDS_PX[0][1]).all(axis=2).sum() > 40  # the points stay in view
    assert image[120 - height // 2:].any()  # the legend: across the bottom


def test_residuals_match_pycolmap_projection(tmp_path):
    rec = pycolmap.Reconstruction()
    rec.add_camera_with_trivial_rig(pycolmap.Camera(model="RADIAL", width=640, height=480,
                                                    params=[500.0, 320.0, 240.0, -0.05, 0.01],
                                                    camera_id=1))
    rng = np.random.default_rng(0)
    xyz = rng.uniform([-1, -1, 3], [1, 1, 6], (30, 3))
    pose = pycolmap.Rigid3d(pycolmap.Rotation3d(np.array([0.02, -0.01, 0.03, 1.0])),
                            np.array([0.1, 0.0, 0.2]))
    cam = rec.camera(1)
    x_cam = xyz @ pose.matrix()[:, :3].T + pose.matrix()[:, 3]
    noisy = cam.img_from_cam(x_cam) + rng.normal(0, 1.5, (30, 2))
    image = pycolmap.Image(name="cam0", keypoints=noisy, camera_id=1, image_id=1)
    rec.add_image_with_trivial_frame(image, pose)
    for i, p in enumerate(xyz):
        track = pycolmap.Track()
        track.add_elements([pycolmap.TrackElement(1, i)])
        rec.add_point3D(p, track)
    observed, reprojected = camera_residuals(rec, "cam0")
    assert observed.shape == reprojected.shape == (30, 2)
    im = rec.image(1)
    for obs, proj, p2 in zip(observed, reprojected, im.points2D):
        assert np.allclose(obs, p2.xy - 0.5)
        assert np.allclose(proj, im.project_point(rec.point3D(p2.point3D_id).xyz) - 0.5)
    with pytest.raises(InputError, match="no image of camera 'cam9'.*cam0"):
        camera_residuals(rec, "cam9")
