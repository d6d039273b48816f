import cv2
import numpy as np
import pytest

from densecalib_ros.core.errors import InputError, NotEnoughCamerasError
from densecalib_ros.core.image_io import read_image_folder


def _write(path, value, size=(40, 30)):
    path.parent.mkdir(parents=True, exist_ok=True)
    img = np.full((size[1], size[0], 3), value, np.uint8)
    img[0, 0] = (255, 0, 0)  # RGB red in the corner: checks the BGR -> RGB conversion
    assert cv2.imwrite(str(path), img[..., ::-1])


def test_flat_folder_one_image_per_camera(tmp_path):
    _write(tmp_path / "left.png", 10)
    _write(tmp_path / "right.jpg", 200)
    (tmp_path / "notes.txt").write_text("ignored")
    frame_sets, names = read_image_folder(tmp_path)
    assert names == ["left", "right"]
    assert len(frame_sets) == 1 and frame_sets[0][0].shape == (30, 40, 3)
    assert tuple(frame_sets[0][0][0, 0]) == (255, 0, 0)
    assert abs(int(frame_sets[0][1][5, 5, 1]) - 200) <= 8  # JPEG


def test_subfolders_aligned_by_stem_and_subsampled(tmp_path):
    for cam in ("a", "b", "c"):
        for t in range(4):
            _write(tmp_path / cam / f"{t:04d}.png", 50 * t)
    frame_sets, names = read_image_folder(tmp_path, max_frame_sets=2)
    assert names == ["a", "b", "c"]
    assert len(frame_sets) == 2
    assert int(frame_sets[1][2][5, 5, 0]) == 150  # the last time step is kept


def test_unreadable_image_names_the_file(tmp_path):
    _write(tmp_path / "a.png", 10)
    (tmp_path / "b.png").write_bytes(b"not a png")
    with pytest.raises(InputError, match="b.png"):
        read_image_folder(tmp_path)


def test_one_camera_is_not_enough(tmp_path):
    _write(tmp_path / "only.png", 10)
    with pytest.raises(NotEnoughCamerasError, match="only"):
        read_image_folder(tmp_path)


def test_misaligned_subfolders_and_empty_folder(tmp_path):
    _write(tmp_path / "a" / "x1.png", 1)
    _write(tmp_path / "a" / "x2.png", 1)
    _write(tmp_path / "b" / "y1.png", 1)
    with pytest.raises(InputError, match="different numbers"):
        read_image_folder(tmp_path)
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(InputError, match="No images"):
        read_image_folder(empty)
    with pytest.raises(InputError, match="does not exist"):
        read_image_folder(tmp_path / "missing")
