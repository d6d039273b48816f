import logging
import os

import cv2
import numpy as np
import pytest
from PIL import Image

from densecalib_ros.core.errors import InputError, NotEnoughCamerasError
from densecalib_ros.core.io.exif import exif_capture_time_s
from densecalib_ros.core.io.image_io import list_image_folder, read_image, read_image_folder


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


def test_names_in_other_encodings(tmp_path):
    """A camera folder named with a byte that is not UTF-8 is refused naming it (cv2.imread
    crashed the process on it); an image file so named in a camera folder reads."""
    png = cv2.imencode(".png", np.full((30, 40, 3), 10, np.uint8))[1].tobytes()
    odd = os.fsdecode(b"\xff")
    for camera in (f"cam{odd}", "cam1"):
        (tmp_path / "a" / camera).mkdir(parents=True)
        (tmp_path / "a" / camera / "0000.png").write_bytes(png)
        (tmp_path / "b" / camera.replace(odd, "0")).mkdir(parents=True, exist_ok=True)
        (tmp_path / "b" / camera.replace(odd, "0") / f"{odd}.png").write_bytes(png)
    with pytest.raises(InputError, match=r"Camera name 'cam\\udcff' is not printable UTF-8"):
        read_image_folder(tmp_path / "a")
    frame_sets, names = read_image_folder(tmp_path / "b")
    assert names == ["cam0", "cam1"] and frame_sets[0][1].shape == (30, 40, 3)


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


def test_unaligned_subfolders_need_a_choice_and_order_pairs_evenly(tmp_path):
    for i in range(5):
        _write(tmp_path / "a" / f"IMG_{i:04d}.png", 10 * i)
    for i in range(3):
        _write(tmp_path / "b" / f"DSC{i:05d}.png", 100 + 10 * i)
    with pytest.raises(InputError, match="--align time.*--align order"):
        list_image_folder(tmp_path)
    with pytest.raises(InputError, match="--align name: no file name is in every camera"):
        list_image_folder(tmp_path, align="name")
    paths, names = list_image_folder(tmp_path, align="order")
    assert names == ["a", "b"]
    assert [[p.name for p in row] for row in paths] == [
        ["IMG_0000.png", "DSC00000.png"], ["IMG_0002.png", "DSC00001.png"],
        ["IMG_0004.png", "DSC00002.png"]]


def test_frame_numbers_pair_however_padded(tmp_path):
    """One camera numbering its frames 1, 2, 10 beside others' 0001, 0002, 0010: the frames pair
    by number (by sorted name, 10 would sit beside 0002), and in number order."""
    for cam in ("a", "b"):
        for t in (1, 2, 10):
            _write(tmp_path / cam / f"{t:04d}.png", 20 * t)
    for t in (1, 2, 10):
        _write(tmp_path / "c" / f"{t}.png", 20 * t)
    paths, names = list_image_folder(tmp_path)
    assert names == ["a", "b", "c"]
    assert [[p.name for p in row] for row in paths] == [
        ["0001.png", "0001.png", "1.png"], ["0002.png", "0002.png", "2.png"],
        ["0010.png", "0010.png", "10.png"]]
    paths, _ = list_image_folder(tmp_path, align="order")
    assert [p.name for p in paths[1]] == ["0002.png", "0002.png", "2.png"]


def test_one_image_per_camera_takes_no_alignment(tmp_path):
    _write(tmp_path / "left.png", 10)
    _write(tmp_path / "right.png", 20)
    with pytest.raises(InputError, match="one image per camera.*--align time belong"):
        list_image_folder(tmp_path, align="time")
    with pytest.raises(InputError, match="nothing to pair: --time-offset belong"):
        list_image_folder(tmp_path, time_offsets_s={"left": 60.0})


def _write_shot(path, when, subsec=""):
    """An image file whose EXIF says it was taken at `when` ("YYYY:MM:DD HH:MM:SS")."""
    path.parent.mkdir(parents=True, exist_ok=True)
    exif = Image.Exif()
    exif[0x010F] = "trail cam"  # Make: Pillow skips an Exif block without IFD0 entries
    exif.get_ifd(0x8769).update({0x9003: when, **({0x9291: subsec} if subsec else {})})
    Image.fromarray(np.zeros((30, 40, 3), np.uint8)).save(path, exif=exif)


def test_camera_traps_paired_by_capture_time(tmp_path):
    # Two events (10:00:05 and 10:07:30) that fired both cameras; cam b's clock runs 60 s fast,
    # and b also fired alone at 10:03:00.
    _write_shot(tmp_path / "a" / "IMG_0001.jpg", "2026:05:01 10:00:05", "25")
    _write_shot(tmp_path / "a" / "IMG_0002.jpg", "2026:05:01 10:07:30")
    _write_shot(tmp_path / "b" / "PICT001.jpg", "2026:05:01 10:01:04", "9")
    _write_shot(tmp_path / "b" / "PICT002.jpg", "2026:05:01 10:04:00")
    _write_shot(tmp_path / "b" / "PICT003.jpg", "2026:05:01 10:08:31")
    with pytest.raises(InputError, match="within 2 s \\(nearest: 59.*--time-offset"):
        list_image_folder(tmp_path, align="time")
    paths, names = list_image_folder(tmp_path, align="time", time_offsets_s={"b": 60.0})
    assert [[p.name for p in row] for row in paths] == [["IMG_0001.jpg", "PICT001.jpg"],
                                                         ["IMG_0002.jpg", "PICT003.jpg"]]
    assert exif_capture_time_s(tmp_path / "a" / "IMG_0001.jpg") % 60 == pytest.approx(5.25)
    with pytest.raises(InputError, match="unknown camera.*z"):
        list_image_folder(tmp_path, align="time", time_offsets_s={"z": 1.0})
    _write(tmp_path / "b" / "PICT004.png", 0)  # no EXIF
    with pytest.raises(InputError, match="PICT004.png has no EXIF capture time"):
        list_image_folder(tmp_path, align="time", time_offsets_s={"b": 60.0})


def test_sixteen_bit_files_keep_their_contrast(tmp_path):
    """A 12-bit machine-vision frame saved as 16-bit PNG and TIFF reads as the 8-bit image."""
    rgb8 = np.random.default_rng(1).integers(0, 256, (30, 40, 3)).astype(np.uint8)
    twelve = rgb8.astype(np.uint16) << 4
    for name in ("a.png", "b.tif"):
        assert cv2.imwrite(str(tmp_path / name), twelve[..., ::-1])
        assert np.array_equal(read_image(tmp_path / name), rgb8)
    assert cv2.imwrite(str(tmp_path / "g.png"), twelve[..., 0])  # 16-bit gray -> RGB
    assert np.array_equal(read_image(tmp_path / "g.png"), np.repeat(rgb8[..., :1], 3, axis=2))


def test_exif_orientation_is_applied(tmp_path):
    """A phone photo stored landscape with 'rotate 90' in its EXIF is read upright."""
    exif = Image.Exif()
    exif[0x0112] = 6  # Orientation: rotate 90 deg clockwise to view
    Image.fromarray(np.zeros((30, 40, 3), np.uint8)).save(tmp_path / "p.jpg", exif=exif)
    assert read_image(tmp_path / "p.jpg").shape == (40, 30, 3)


def _trap_times(rng, events, rate_s=600.0):
    """Capture times of `events` animal passes (bursts of 1-3 shots 1 s apart) over the days."""
    starts = np.cumsum(rng.exponential(rate_s, events))
    return [t + k for t in starts for k in range(int(rng.integers(1, 4)))]


def test_camera_trap_clock_offsets_found_from_capture_times():
    """Three traps: b's clock runs an hour and 7.5 s fast (daylight saving and drift), c's was
    reset to its factory date; each also fires alone on what only it sees."""
    from densecalib_ros.core.io.clock_offsets import estimate_clock_offsets

    rng = np.random.default_rng(4)
    shared = _trap_times(rng, 12)
    truth = {"a": 0.0, "b": 3607.5, "c": -8.3e8}
    times = {}
    for name, offset in truth.items():
        jitter = rng.uniform(-0.6, 0.6, len(shared))  # trigger delays differ per camera
        own = _trap_times(rng, 6)
        times[name] = np.concatenate([np.asarray(shared) + jitter, own]) + offset
    estimates = estimate_clock_offsets(times, gap_s=2.0)
    for name, offset in truth.items():
        assert estimates[name].offset_s == pytest.approx(offset, abs=0.5)
        assert estimates[name].paired_shots >= len(shared) - 2
    # a time-lapse every 5 minutes in both cameras pairs equally at every multiple: refused
    lapse = {"a": np.arange(50) * 300.0, "b": np.arange(50) * 300.0 + 1234.0}
    with pytest.raises(InputError, match="do not settle the clock offset of b.*--time-offset"):
        estimate_clock_offsets(lapse, gap_s=2.0)


def test_time_offset_auto_pairs_the_traps_files(tmp_path, capsys):
    """--align time --time-offset auto on real EXIF files: b's clock runs 60 s fast."""
    import argparse

    from densecalib_ros.commands.inputs import add_input_arguments, read_input

    for i, (hh_mm_ss, alone) in enumerate([("10:00:05", False), ("10:07:30", False),
                                           ("10:20:10", False), ("10:33:00", True),
                                           ("11:02:44", False)]):
        _write_shot(tmp_path / "a" / f"IMG_{i:04d}.jpg", f"2026:05:01 {hh_mm_ss}")
        if not alone:
            h, m, s = map(int, hh_mm_ss.split(":"))
            t = h * 3600 + m * 60 + s + 60 + (i % 2)  # 60 s fast, triggered up to 1 s later
            _write_shot(tmp_path / "b" / f"PICT{i:03d}.jpg",
                        f"2026:05:01 {t // 3600:02d}:{t // 60 % 60:02d}:{t % 60:02d}")
    parser = argparse.ArgumentParser()
    add_input_arguments(parser)
    args = parser.parse_args(["--images", str(tmp_path), "--align", "time", "--time-offset",
                              "auto"])
    frame_sets, names, record, paths = read_input(args)
    assert names == ["a", "b"] and len(frame_sets) == 4
    assert record["time_offsets_s"]["b"] == pytest.approx(60.5, abs=0.6)
    assert record["time_offsets_estimated"]["b"]["paired_shots"] == 4
    assert [p.name for p in paths[3]] == ["IMG_0004.jpg", "PICT004.jpg"]
    from densecalib_ros.cli import main
    assert main(["sync", "--images", str(tmp_path)]) == 0  # the offsets alone
    assert "4 shots paired" in capsys.readouterr().out


def test_a_dropped_frame_leaves_out_that_moment_only(tmp_path, caplog):
    """Camera b lost frame 0002 and has an extra 0009: by default the sets are the names every
    camera has (pairing by position would put b's 0003 beside a's 0002), and the warning names
    what was left out."""
    for i in range(6):
        _write(tmp_path / "a" / f"{i:04d}.png", 10 * i)
    for i in (0, 1, 3, 4, 5, 9):
        _write(tmp_path / "b" / f"{i:04d}.png", 10 * i)
    with caplog.at_level(logging.WARNING):
        paths, names = list_image_folder(tmp_path)
    assert [[p.name for p in row] for row in paths] == [
        [f"{i:04d}.png"] * 2 for i in (0, 1, 3, 4, 5)]
    assert "5 with every camera" in caplog.text
    assert "a: 0002" in caplog.text and "b: 0009" in caplog.text
    paths, _ = list_image_folder(tmp_path, align="order")  # asked for: position, 6 sets
    assert [p.name for p in paths[2]] == ["0002.png", "0003.png"]


def test_a_hidden_image_file_is_named_when_skipped(tmp_path, caplog):
    """`...png` (a name that is all dots and the suffix) is a hidden file: not read, as before,
    but no longer silently: its camera would vanish from the rig unnoticed (issue 40)."""
    for name, value in (("cam0.png", 10), ("cam1.png", 20), ("...png", 30), (".DS_Store", 0)):
        if name.endswith(".png"):
            _write(tmp_path / name, value)
        else:
            (tmp_path / name).write_bytes(b"\x00")
    with caplog.at_level(logging.WARNING):
        _, names = list_image_folder(tmp_path)
    assert names == ["cam0", "cam1"]
    assert "...png (a hidden file: rename it without the leading '.')" in caplog.text
    assert ".DS_Store" not in caplog.text
