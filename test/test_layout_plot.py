"""The rig's layout plot (core.products.layout_plot, `densecalib report --plot`), drawn by
matplotlib and checked on the figure it draws and the PNG it renders: where each camera is, axes
at one scale in metres or rig units, camera labels clear of each other, every scene point in view,
a legend inside the picture; and the core imports without matplotlib."""
import copy
import subprocess
import sys

import cv2
import numpy as np
import pytest
from test_report import upright_rig

from densecalib_ros.cli import main
from densecalib_ros.core.errors import InputError
from densecalib_ros.core.io.export import write_calibration_files
from densecalib_ros.core.products.layout_plot import (BEFORE_GREY, FIGURE_PX, LABEL_CHARS,
                                                      camera_colours, centres_as_in,
                                                      draw_layout, render, short_label)
from densecalib_ros.core.types import CameraIntrinsics, RigCalibration, RigCamera, RigQuality


def _anchors(plot, view):
    """(C, 2) where each camera's label hangs from: its dot, in the view's data coordinates."""
    return np.array([label.get_position() for label in plot.labels[view]])


def _legend_text(plot):
    return [t.get_text() for t in plot.figure.legends[0].get_texts()]


def test_cameras_sit_where_the_floor_frame_puts_them():
    """Floor frame: the top view shows floor x, y, the side view x and the height; the dots are
    drawn there, in each camera's colour, and the wall at y = 3 is seen edge-on beyond them.
    Without a floor, "up" from the cameras' image-up: the same heights."""
    rig, wall = upright_rig(with_floor=True)
    plot = draw_layout(rig, wall)
    np.testing.assert_allclose(_anchors(plot, "top"), [[0, 0], [1, 0], [2, 0.5]], atol=1e-9)
    np.testing.assert_allclose(_anchors(plot, "side"), [[0, 1], [1, 2], [2, 1.5]], atol=1e-9)
    np.testing.assert_allclose(plot.scene["top"][0].get_offsets()[:, 1], 3.0, atol=1e-9)
    image = render(plot)
    assert image.shape == (FIGURE_PX[1], FIGURE_PX[0], 3)
    for view in ("top", "side"):
        xy_px = plot.views[view].transData.transform(_anchors(plot, view))
        for (x, y), colour in zip(xy_px, camera_colours(3)):
            drawn = image[int(round(FIGURE_PX[1] - y)), int(round(x))].astype(int)
            assert np.abs(drawn - colour).max() < 30, (view, drawn, colour)

    rig, wall = upright_rig(with_floor=False)
    side = _anchors(draw_layout(rig, wall), "side")
    np.testing.assert_allclose(side[:, 1] - side[0, 1], [0.0, 1.0, 0.5], atol=1e-9)


def test_axes_are_at_one_scale_in_metres_or_rig_units():
    rig, wall = upright_rig(with_floor=True)
    plot = draw_layout(rig, wall)
    render(plot)
    for ax in plot.views.values():
        box = ax.get_window_extent()
        per_px = [np.ptp(ax.get_xlim()) / box.width, np.ptp(ax.get_ylim()) / box.height]
        assert per_px[0] == pytest.approx(per_px[1], rel=1e-6)  # a metre as long across as up
        assert ax.get_xlabel() == "x [m]"
    assert plot.views["side"].get_ylabel() == "z, up [m]" and plot.unit == "m"
    rig.metric_scale = False
    plot = draw_layout(rig, wall)
    assert plot.unit == "rig units"
    assert all("[rig units: no metric scale]" in label for ax in plot.views.values()
               for label in (ax.get_xlabel(), ax.get_ylabel()))


def test_every_scene_point_is_in_view_and_strays_are_drawn_at_its_edge():
    """The whole wall is in view (none left out as the bulk's 5-95 % would); three points
    triangulated a kilometre off would shrink it to a dot: they are drawn at the edge of the
    view and counted in the legend."""
    rig, wall = upright_rig(with_floor=True)
    floor_from_rig = np.asarray(rig.quality.floor["floor_from_rig"]).reshape(4, 4)
    far_floor = np.array([[900.0, 1000.0, 5.0, 1.0], [-800.0, 3.0, 1.0, 1.0],
                          [1.0, 2.0, 700.0, 1.0]])
    far_rig = (far_floor @ np.linalg.inv(floor_from_rig).T)[:, :3]
    for points, strays in ((wall, 0), (np.vstack([wall, far_rig]), 3)):
        plot = draw_layout(rig, points)
        render(plot)
        assert plot.num_stray_points == strays
        for view, ax in plot.views.items():
            shown, edge = (s.get_offsets() for s in plot.scene[view])
            assert len(shown) == len(wall) and len(edge) == strays
            for xy in (shown, edge):
                assert (xy[:, 0] >= ax.get_xlim()[0]).all() and (xy[:, 0] <= ax.get_xlim()[1]).all()
                assert (xy[:, 1] >= ax.get_ylim()[0]).all() and (xy[:, 1] <= ax.get_ylim()[1]).all()
            assert ax.get_xlim()[1] - ax.get_xlim()[0] < 10.0  # the scene, not the strays
        stray_entries = [t for t in _legend_text(plot) if "stray scene point" in t]
        assert len(stray_entries) == (1 if strays else 0)
        assert not strays or stray_entries[0].startswith("3 stray scene point(s)")
    top = plot.views["top"]
    assert top.get_xlim()[0] < -1.0 and top.get_xlim()[1] > 3.0  # the wall's ends: x -1 .. 3


def _ring_rig(names, radius=0.3):
    """Fisheye cameras on a ring of `radius` units, looking outward, a little apart in height;
    no metric scale."""
    lens = CameraIntrinsics("OPENCV_FISHEYE", 1280, 960,
                            np.array([400.0, 400.0, 640.0, 480.0, 0.01, -0.002, 3e-4, -1e-4]))
    poses = {}
    for i, name in enumerate(names):
        angle = 2 * np.pi * i / len(names)
        centre = np.array([radius * np.cos(angle), 0.05 * (i % 3), radius * np.sin(angle)])
        z = np.array([np.cos(angle), 0.0, np.sin(angle)])
        rotation = np.stack([np.cross([0.0, 1.0, 0.0], z), [0.0, 1.0, 0.0], z])
        poses[name] = np.eye(4)
        poses[name][:3, :3], poses[name][:3, 3] = rotation, -rotation @ centre
    rig_from_first = np.linalg.inv(poses[names[0]])
    return RigCalibration(names[0], {n: RigCamera(n, copy.deepcopy(lens), p @ rig_from_first)
                                     for n, p in poses.items()},
                          quality=RigQuality(), metric_scale=False)


def test_camera_labels_stay_clear_of_each_other_on_a_crowded_rig():
    """Ten cameras closer together than their names are long (on the plot): every label box is
    clear of every other, inside its view, and the legend inside the picture."""
    names = [f"arena_north_east_ceiling_cam_{i:02d}" for i in range(10)]
    rig = _ring_rig(names)
    rng = np.random.default_rng(0)
    directions = rng.normal(size=(3000, 3)) * [1.0, 0.3, 1.0]
    points = directions / np.linalg.norm(directions, axis=1, keepdims=True) * \
        rng.uniform(3.0, 5.0, (3000, 1))
    plot = draw_layout(rig, points)
    image = render(plot)
    assert image.shape == (FIGURE_PX[1], FIGURE_PX[0], 3)
    for view, ax in plot.views.items():
        labels = plot.labels[view]
        assert [t.get_text() for t in labels] == [short_label(n) for n in names]
        assert all(len(t.get_text()) <= LABEL_CHARS for t in labels)
        boxes = [t.get_window_extent() for t in labels]
        dots_px = ax.transData.transform(_anchors(plot, view))
        gaps = np.linalg.norm(dots_px[:, None] - dots_px[None], axis=2)[np.triu_indices(10, 1)]
        assert gaps.min() < min(b.width for b in boxes)  # as drawn beside them, they would touch
        overlapping = [(names[i], names[j]) for i in range(10) for j in range(i + 1, 10)
                       if boxes[i].overlaps(boxes[j])]
        assert not overlapping, (view, overlapping)
        inside = ax.get_window_extent()
        assert all(inside.x0 <= b.x0 and b.x1 <= inside.x1 and inside.y0 <= b.y0
                   and b.y1 <= inside.y1 for b in boxes), view
    legend = plot.figure.legends[0].get_window_extent()
    assert 0 <= legend.x0 and legend.x1 <= FIGURE_PX[0] and 0 <= legend.y0 \
        and legend.y1 <= FIGURE_PX[1]
    assert len(_legend_text(plot)) == 10 + 3  # the cameras, scene points, optical axis, view


def test_layout_plot_against_another_calibration_rings_where_a_camera_was():
    """--against: the other calibration's cameras as grey rings joined to the cameras now; cam2,
    0.3 m further along the floor's x now, has its ring 0.3 m to the left of its dot."""
    rig, wall = upright_rig(with_floor=True)
    before = copy.deepcopy(rig)
    floor_from_rig = np.asarray(rig.quality.floor["floor_from_rig"]).reshape(4, 4)
    shift_rig = np.linalg.inv(floor_from_rig)[:3, :3] @ [-0.3, 0.0, 0.0]  # 0.3 m back in floor x
    before.cameras["cam2"].cam_from_rig[:3, 3] -= before.cameras["cam2"].cam_from_rig[:3, :3] @ \
        shift_rig
    moved = centres_as_in(rig, before) - centres_as_in(rig, rig)
    np.testing.assert_allclose(np.linalg.norm(moved, axis=1), [0, 0, 0.3], atol=1e-9)
    plot = draw_layout(rig, wall, against=before)
    rings = np.array([line.get_xydata()[0] for line in plot.views["top"].get_lines()
                      if line.get_marker() == "o" and line.get_markerfacecolor() == "none"
                      and line.get_markeredgecolor() == BEFORE_GREY])
    np.testing.assert_allclose(rings, [[0, 0], [1, 0], [1.7, 0.5]], atol=1e-9)
    assert "camera in the\nother calibration" in _legend_text(plot)
    # an up-to-scale calibration is brought to this one's unit (by the median of the cameras'
    # distance ratios)
    scaled = copy.deepcopy(rig)
    scaled.metric_scale = False
    for cam in scaled.cameras.values():
        cam.cam_from_rig[:3, 3] *= 3.0
    np.testing.assert_allclose(centres_as_in(rig, scaled), centres_as_in(rig, rig), atol=1e-9)
    before.reference_camera = "cam1"  # rig frames of different cameras: refused
    with pytest.raises(InputError, match="different reference cameras"):
        draw_layout(rig, wall, against=before)


def test_report_plot_command(tmp_path, caplog):
    rig, _ = upright_rig(with_floor=True)
    write_calibration_files(rig, tmp_path / "calib")
    assert main(["report", str(tmp_path / "calib"), "--plot", str(tmp_path / "rig.png")]) == 0
    assert cv2.imread(str(tmp_path / "rig.png")).shape == (FIGURE_PX[1], FIGURE_PX[0], 3)
    assert "without scene points" in caplog.text  # no COLMAP model saved with this one
    assert main(["report", str(tmp_path / "calib"), "--plot", str(tmp_path / "rig.jpg")]) == 2
    assert "give a .png file name" in caplog.text


def test_the_core_and_the_command_import_without_matplotlib():
    """matplotlib loads when a plot is drawn, not when the core or the command line is
    imported (it takes most of a second, and the node never draws)."""
    code = ("import sys\nimport densecalib_ros.core, densecalib_ros.cli\n"
            "import densecalib_ros.core.products.layout_plot, densecalib_ros.commands.report\n"
            "print(sorted(m for m in sys.modules if m.split('.')[0] == 'matplotlib'))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.strip() == "[]"
