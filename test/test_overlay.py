"""Residual overlays (core.products.overlay): colour bands and legend on a drawn image; the
residuals of a real COLMAP model equal pycolmap's own projection of its points."""
import numpy as np
import pycolmap
import pytest

from densecalib_ros.core.errors import InputError
from densecalib_ros.core.products.overlay import BANDS_PX, camera_residuals, draw_residuals


def test_dots_take_the_colour_of_their_residual_band():
    observed = np.array([[20.0, 60.0], [60.0, 60.0], [100.0, 60.0]])
    reprojected = observed + np.array([[0.5, 0.0], [0.0, 2.0], [0.0, 5.0]])
    image = draw_residuals(np.zeros((120, 160, 3), np.uint8), observed, reprojected, title="cam7")
    for (x, y), (_, colour) in zip(observed.astype(int), BANDS_PX):
        assert tuple(image[y, x]) == colour
    assert image[5:15, 5:60].any()  # the legend
    gray = draw_residuals(np.zeros((120, 160), np.uint8), observed[:0], reprojected[:0])
    assert gray.shape == (120, 160, 3)


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
