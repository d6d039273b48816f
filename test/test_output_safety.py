"""Bad paths and damaged files (found by acceptance testing): no command empties a folder it did
not write, replaces its own input or the calibration it reads; written files are readable by
other users as the umask says; a damaged calibration, COLMAP model or JPEG is refused with what
to do, not a traceback (or a 17 GB allocation); out-of-range options are usage errors."""
import json
import logging
import os
import stat

import cv2
import pytest

from densecalib_ros.cli import main
from densecalib_ros.core.errors import FocalInitError, InputError
from densecalib_ros.core.io.export import (calibration_from_dict, calibration_to_dict,
                                           check_output_files, read_calibration, read_saved_model,
                                           write_calibration_files)
from densecalib_ros.core.io.safe_write import check_output_folder, replace_directory_atomic
from densecalib_ros.core.io.image_io import jpeg_truncated, list_image_folder
from densecalib_ros.core.synthetic import RigSpec, generate_rig


@pytest.fixture(scope="module")
def rig():
    return generate_rig(RigSpec(lenses="ideal", num_cameras=3, camera_model="RADIAL", width=320, height=240,
                                seed=2))


@pytest.fixture
def folders(rig, tmp_path):
    """tmp/images (one image per camera) and tmp/cal (the rig's true calibration, written as
    calibrate writes it)."""
    images = tmp_path / "images"
    images.mkdir()
    for name, image in zip(rig.names, rig.images[0]):
        cv2.imwrite(str(images / f"{name}.png"), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
    write_calibration_files(rig.ground_truth(), tmp_path / "cal")
    return images, tmp_path / "cal"


def _tree(folder):
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*"))


def test_calibrate_never_empties_a_folder_it_did_not_write(folders, tmp_path, caplog,
                                                           monkeypatch):
    images, _ = folders
    mine = tmp_path / "thesis"
    (mine / "chapter").mkdir(parents=True)
    (mine / "thesis.txt").write_text("years of work")
    before = _tree(tmp_path)
    for out, said in ((mine, "is not an earlier output of this command"),
                      (images, "is the input"), (tmp_path, "holds the input"),
                      ("", "is empty"), (images / "cam0.png", "is a file")):
        assert main(["calibrate", "--images", str(images), "--out", str(out)]) == 2
        assert said in caplog.text
        caplog.clear()
    monkeypatch.chdir(images)  # `--out .` from inside the images
    assert main(["calibrate", "--images", ".", "--out", "."]) == 2
    assert _tree(tmp_path) == before  # nothing written, nothing removed


def test_an_earlier_output_is_replaced_whole_and_an_input_never(tmp_path):
    out = tmp_path / "out"
    write = lambda text: replace_directory_atomic(  # noqa: E731
        lambda tmp: (tmp / "calibration.json").write_text(text), out, ("calibration.json",))
    write("1")
    (out / "stale.txt").write_text("from the first run")
    write("2")
    assert _tree(out) == ["calibration.json"] and (out / "calibration.json").read_text() == "2"
    with pytest.raises(InputError, match="holds the input"):
        check_output_folder(tmp_path, ("calibration.json",), [out / "calibration.json"])
    assert check_output_folder(tmp_path / "new", ("calibration.json",)) == tmp_path / "new"


def test_exports_and_overlays_do_not_replace_what_they_read(folders):
    images, cal = folders
    calibration = (cal / "calibration.json").read_bytes()
    yaml_file = (cal / "cam0.yaml").read_bytes()
    for fmt, out in (("anipose", cal / "calibration.json"), ("jarvis", cal), ("anipose", cal),
                     ("opencv", "")):
        assert main(["export", str(cal), "--format", fmt, "--out", str(out)]) == 2
    assert (cal / "calibration.json").read_bytes() == calibration
    assert (cal / "cam0.yaml").read_bytes() == yaml_file
    assert main(["export", str(cal), "--format", "anipose", "--out",
                 str(cal / "anipose.toml")]) == 0  # a new file beside them is fine ...
    assert main(["export", str(cal), "--format", "anipose", "--out",
                 str(cal / "anipose.toml")]) == 0  # ... and so is exporting it again
    with pytest.raises(InputError, match="is in the input folder"):  # overlay's drawings
        check_output_files([images / "cam0.png"], calibration_dir=cal, input_dir=images)


def test_written_files_follow_the_umask(folders, tmp_path):
    _, cal = folders
    old = os.umask(0o022)
    try:
        out = tmp_path / "exported.toml"
        assert main(["export", str(cal), "--format", "anipose", "--out", str(out)]) == 0
        fresh = tmp_path / "fresh"
        write_calibration_files(calibration_from_dict(json.loads(
            (cal / "calibration.json").read_text())), fresh)
        replace_directory_atomic(lambda tmp: (tmp / "calibration.json").write_text("{}"),
                                 tmp_path / "swapped")
    finally:
        os.umask(old)
    assert stat.S_IMODE(out.stat().st_mode) == 0o644
    assert stat.S_IMODE((fresh / "calibration.json").stat().st_mode) == 0o644
    assert stat.S_IMODE((tmp_path / "swapped").stat().st_mode) == 0o755


def test_generate_replaces_its_own_rig_and_nothing_else(tmp_path, caplog):
    out = tmp_path / "rig"
    small = ["--cameras", "3", "--width", "160", "--height", "120"]
    assert main(["generate", "--out", str(out), *small, "--time-steps", "2"]) == 0
    assert main(["generate", "--out", str(out), *small, "--time-steps", "1", "--seed", "2"]) == 0
    assert sorted(p.name for p in (out / "cam0").iterdir()) == ["0000.png"]  # no stale frame
    assert main(["generate", "--out", str(tmp_path), *small]) == 2  # holds rig/, not a rig
    assert "not an earlier output" in caplog.text


@pytest.mark.parametrize("damage, said", [
    (lambda c: c["cameras"]["cam1"]["params"].__setitem__(0, float("nan")), "5 finite numbers"),
    (lambda c: c["cameras"]["cam1"].__setitem__("model", "FOOCAM"), "COLMAP does not know"),
    (lambda c: c["cameras"]["cam1"].__setitem__("params", [300.0, 160.0]), "5 finite numbers"),
    (lambda c: c["cameras"]["cam1"]["params"].__setitem__(0, -300.0), "focal length -300"),
    (lambda c: c["cameras"]["cam1"].__setitem__(
        "cam_from_rig", [-1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1]), "not a rotation"),
    (lambda c: c.__setitem__("reference_camera", "camX"), "not among its cameras"),
    (lambda c: c.__setitem__("cameras", {}), "no cameras"),
    (lambda c: c["cameras"].__setitem__("cam1", None), "Not a densecalib calibration"),
])
def test_a_damaged_calibration_is_refused(rig, damage, said):
    data = calibration_to_dict(rig.ground_truth())
    damage(data)
    with pytest.raises(InputError, match=said):
        calibration_from_dict(json.loads(json.dumps(data)))


def test_a_damaged_colmap_model_is_refused_before_it_is_read(tmp_path):
    model = tmp_path / "colmap"
    model.mkdir()
    (model / "points3D.bin").write_bytes(b"")  # pycolmap took 17 GB and 106 s on this
    with pytest.raises(InputError, match="points3D.bin is empty"):
        read_saved_model(tmp_path)
    (model / "points3D.bin").write_bytes((10 ** 9).to_bytes(8, "little") + bytes(100))
    with pytest.raises(InputError, match="claims 1000000000 points at byte 8; the 100 bytes"):
        read_saved_model(tmp_path)


def test_truncated_jpegs_are_refused(rig, tmp_path, caplog):
    ok, data = cv2.imencode(".jpg", rig.images[0][0])
    data = data.tobytes()
    assert not jpeg_truncated(data)
    assert not jpeg_truncated(data + b"\x00" * 64 + b"ftypmp42 a motion photo's video")
    assert jpeg_truncated(data[:len(data) // 3])
    folder = tmp_path / "images"
    folder.mkdir()
    for name, image in zip(rig.names, rig.images[0]):
        cv2.imwrite(str(folder / f"{name}.jpg"), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
    cut = folder / "cam1.jpg"
    cut.write_bytes(cut.read_bytes()[:cut.stat().st_size // 3])
    assert main(["calibrate", "--images", str(folder), "--out", str(tmp_path / "out")]) == 2
    assert "cam1.jpg is a truncated JPEG" in caplog.text


def test_files_a_camera_wrote_but_that_are_not_read_are_named(folders, caplog):
    images, _ = folders
    (images / "cam3.heic").write_bytes(b"\x00")
    (images / "cam4.avi").write_bytes(b"\x00")
    (images / "cam5.png").symlink_to(images / "gone.png")
    (images / "notes.txt").write_text("not a camera")
    with caplog.at_level(logging.WARNING):
        _, names = list_image_folder(images)
    assert names == ["cam0", "cam1", "cam2"]
    assert ("cam3.heic (convert it to JPEG or PNG); cam4.avi (a video: give video folders with "
            "--videos); cam5.png (a broken link)") in caplog.text
    assert "notes.txt" not in caplog.text


def test_a_numeric_camera_name_survives_its_camera_info(rig, tmp_path):
    """camera_name: 0003 loads as the integer 3: the name is quoted, and files written so
    before name their camera by the file's stem."""
    from densecalib_ros.core.io.camera_info import camera_info_yaml
    from densecalib_ros.core.method.known_intrinsics import read_known_intrinsics

    intrinsics = rig.cameras[0]
    text = camera_info_yaml("0003", intrinsics)
    assert "camera_name: '0003'" in text
    (tmp_path / "a.yaml").write_text(text)
    (tmp_path / "0004.yaml").write_text(text.replace("'0003'", "0004"))
    assert sorted(read_known_intrinsics([str(tmp_path / "a.yaml"),
                                         str(tmp_path / "0004.yaml")])) == ["0003", "0004"]


def test_out_of_range_options_are_usage_errors(folders, capsys):
    images, cal = folders
    for args in (["calibrate", "--images", str(images), "--out", "x", "--seed", "-1"],
                 ["calibrate", "--images", str(images), "--out", "x", "--max-side", "8"],
                 ["calibrate", "--images", str(images), "--out", "x", "--consensus-runs", "0"],
                 ["check", str(cal), "--images", str(images), "--tolerance-px", "nan"],
                 ["generate", "--out", "x", "--seed", "99999999999999999"],
                 ["demo", "--offline", "--timeout", "0"]):
        with pytest.raises(SystemExit) as exit_:
            main(args)
        assert exit_.value.code == 2
        assert "out of range" in capsys.readouterr().err


def test_generate_refuses_options_that_ask_for_another_rig(tmp_path, caplog):
    """Each pair was taken and one of them ignored (--lens-mix mixed with --fov-deg 40 gave
    three 40 deg lenses)."""
    for options, said in ((["--lens-mix", "mixed", "--fov-deg", "40"], "give one of them"),
                          (["--layout", "bar", "--gap-deg", "30"], "not --layout bar"),
                          (["--layout", "outward", "--max-arc-deg", "360"], "not --layout outward"),
                          (["--bar-spacing-m", "0.2"], "not --layout arc")):
        caplog.clear()
        with caplog.at_level("ERROR"):
            assert main(["generate", "--out", str(tmp_path / "g"), "--cameras", "3", *options]) \
                == 2
        assert said in caplog.text and not (tmp_path / "g").exists()


def test_scale_refuses_lengths_no_rig_has(folders, caplog):
    _, cal = folders
    before = (cal / "calibration.json").read_bytes()
    for metres in ("inf", "1e308", "1e-320"):
        assert main(["scale", str(cal), "--baseline", "cam0", "cam1", metres]) == 2
    assert (cal / "calibration.json").read_bytes() == before
    assert main(["scale", str(cal), "--baseline", "cam0", "cam1", "0.5", "--dry-run"]) == 0
    assert (cal / "calibration.json").read_bytes() == before


def test_focal_errors_name_the_cameras():
    error = FocalInitError("No fundamental matrix for camera(s) {cameras}: overlap?", [1, 2])
    assert str(error) == "No fundamental matrix for camera(s) [1, 2]: overlap?"
    assert str(error.named(["left", "middle", "right"])) == (
        "No fundamental matrix for camera(s) middle, right: overlap?")


def test_a_calibration_file_that_is_not_text_is_refused_with_what_to_do(rig, tmp_path):
    """Bytes that are not UTF-8 (a damaged disk, another file saved under the name): an
    InputError naming the file, not a UnicodeDecodeError traceback (issue 40)."""
    out = tmp_path / "calib"
    write_calibration_files(rig.ground_truth(), out)
    (out / "calibration.json").write_bytes(b'{"reference_camera": "\xff\xfe"}')
    with pytest.raises(InputError, match=r"calibration.json \(UnicodeDecodeError.*calibrate again"):
        read_calibration(out)
    assert main(["report", str(out)]) == 2
