"""A calibration.json with values no camera has (hand edits, damage) is refused where it is read,
naming the file, the camera and the field, with exit code 2 and nothing written: a width `true`,
`"640"` or 640.5 (exported as `image_width: true`), a focal of 1e308, a principal point 1e9 px
off, k1 = 1e6, and a width of 10^12 that made `undistort` allocate 7 TiB (issue 85 items 7, 8).
`undistort` makes its maps only once the images are known to be of the calibrated size."""
import json
import os
import subprocess
import sys

import cv2
import pytest

from densecalib_ros.core.io.export import calibration_to_dict, read_calibration
from densecalib_ros.core.synthetic import RigSpec, generate_rig

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
# Far above what these commands take (a few hundred MB), far below what the absurd sizes asked
# for: without the checks the test fails on a MemoryError instead of filling a shared machine.
CHILD_ADDRESS_SPACE = 4 * 2 ** 30


@pytest.fixture(scope="module")
def rig():
    return generate_rig(RigSpec(lenses="ideal", num_cameras=3, camera_model="RADIAL", width=320,
                                height=240, seed=4))


def _calibration(rig, folder, edit=None):
    """folder/calibration.json of the rig's true calibration, edit(cameras dict) applied."""
    data = calibration_to_dict(rig.ground_truth())
    if edit:
        edit(data["cameras"])
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "calibration.json").write_text(json.dumps(data))
    return folder / "calibration.json"


def _densecalib(*args):
    """(exit code, peak resident memory in bytes, output) of `densecalib args` in a child."""
    env = {**os.environ, "PYTHONPATH": REPO + os.pathsep + os.environ.get("PYTHONPATH", "")}
    proc = subprocess.Popen(["prlimit", f"--as={CHILD_ADDRESS_SPACE}", sys.executable, "-m",
                             "densecalib_ros.cli", *map(str, args)], stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True, env=env)
    output = proc.stdout.read()
    _, status, usage = os.wait4(proc.pid, 0)
    return os.waitstatus_to_exitcode(status), usage.ru_maxrss * 1024, output


def _set(field, value, camera="cam1"):
    def edit(cameras):
        if field in ("width", "height"):
            cameras[camera][field] = value
        else:  # RADIAL: f, cx, cy, k1, k2
            cameras[camera]["params"][("f", "cx", "cy", "k1", "k2").index(field)] = value
    return edit


@pytest.mark.parametrize("field, value, said", [
    ("width", True, "camera cam1's width is True: give the image width in pixels, a whole "
                    "number from 1 to 65535"),
    ("width", "640", "camera cam1's width is '640'"),
    ("height", 240.5, "camera cam1's height is 240.5"),
    ("width", 10 ** 12, "camera cam1's width is 1000000000000"),
    ("f", 1e308, "camera cam1's focal length f is 1e+308 px: a 320x240 camera's lies within "
                 "16-32000 px"),
    ("cx", 1e9, "camera cam1's principal point cx is 1e+09 px: a 320x240 camera's lies within "
                "-320-640 px"),
    ("k1", 1e6, "camera cam1's distortion coefficient k1 is 1e+06: a lens's lies within +-100"),
])
def test_values_no_camera_has_are_refused_naming_file_camera_and_field(rig, tmp_path, field,
                                                                       value, said):
    path = _calibration(rig, tmp_path / "cal", _set(field, value))
    rc, _, output = _densecalib("export", path, "--format", "opencv", "--out", tmp_path / "x")
    assert rc == 2, output
    assert f"A damaged calibration file {path}: {said}" in output, output
    assert "Correct it, restore the file or calibrate again." in output
    assert "Traceback" not in output and not (tmp_path / "x").exists()


def test_a_calibration_as_written_reads_back(rig, tmp_path):
    """The bounds keep out no calibration densecalib writes (ideal and fisheye lenses)."""
    fisheye = generate_rig(RigSpec(lenses="real", num_cameras=3, camera_model="OPENCV_FISHEYE",
                                   width=320, height=240, seed=5))
    for r in (rig, fisheye):
        path = _calibration(r, tmp_path / r.cameras[0].model)
        assert read_calibration(path).cameras["cam0"].intrinsics.width == 320


def test_undistort_of_an_absurd_size_is_refused_before_it_allocates(rig, tmp_path):
    """width 10^12 is refused on reading; a size within bounds that the images do not have is
    refused at the first image, before the maps of that size are made (60000x40000 maps are
    19 GB)."""
    images = tmp_path / "images"
    images.mkdir()
    for name, image in zip(rig.names, rig.images[0]):
        cv2.imwrite(str(images / f"{name}.png"), cv2.cvtColor(image, cv2.COLOR_RGB2BGR))
    rc, plain_rss, output = _densecalib("undistort", _calibration(rig, tmp_path / "good"),
                                        "--images", images, "--out", tmp_path / "und")
    assert rc == 0, output
    huge = _calibration(rig, tmp_path / "huge", _set("width", 10 ** 12, "cam0"))
    rc, rss, output = _densecalib("undistort", huge, "--images", images, "--out",
                                  tmp_path / "und2")
    assert rc == 2 and "camera cam0's width is 1000000000000" in output, output
    assert rss <= plain_rss + 64 * 2 ** 20 and not (tmp_path / "und2").exists()

    def large(cameras):
        cameras["cam0"].update(width=60000, height=40000)
        cameras["cam0"]["params"][:3] = [50000.0, 30000.0, 20000.0]
    rc, rss, output = _densecalib("undistort", _calibration(rig, tmp_path / "large", large),
                                  "--images", images, "--out", tmp_path / "und3")
    assert rc == 2, output
    assert (f"{images / 'cam0.png'} is 320x240, but camera cam0 was calibrated at 60000x40000"
            in output), output
    assert "Traceback" not in output and not (tmp_path / "und3").exists()
    assert rss <= plain_rss + 64 * 2 ** 20, (rss, plain_rss)
