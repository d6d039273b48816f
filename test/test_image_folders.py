"""What a rig's image folder can hold that is not what its owner meant (issue 85): a camera folder
left empty (the rig calibrated without it and its files dropped from OUT: now exit 2 naming the
folder, unless --without names it), one camera's folder given as the rig's (its numbered frames
calibrated as cameras, for minutes: now exit 2 suggesting the parent folder), and a camera whose
images differ in size (named by file, W x H)."""
import json
import os
import shutil
import subprocess
import sys

import cv2
import pytest

from densecalib_ros.core.io.export import write_calibration_files
from densecalib_ros.core.io.image_io import list_image_folder
from densecalib_ros.core.synthetic import RigSpec, generate_rig, write_rig

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def _densecalib(*args, timeout_s=300):
    """(exit code, output) of `densecalib args` in a child process."""
    env = {**os.environ, "PYTHONPATH": REPO + os.pathsep + os.environ.get("PYTHONPATH", "")}
    done = subprocess.run([sys.executable, "-m", "densecalib_ros.cli", *map(str, args)],
                          capture_output=True, text=True, env=env, timeout=timeout_s)
    return done.returncode, done.stdout + done.stderr


def _tree(folder):
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*"))
            if p.is_file()}


@pytest.fixture(scope="module")
def rig_dir(tmp_path_factory):
    """rig/cam0..cam3/0000.png..0002.png and rig/out, an earlier calibration of the 4 cameras."""
    rig = generate_rig(RigSpec(lenses="ideal", num_cameras=4, camera_model="RADIAL", width=320,
                               height=240, num_time_steps=3, seed=1))
    root = tmp_path_factory.mktemp("rig")
    write_rig(rig, root / "rig")
    write_calibration_files(rig.ground_truth(), root / "out")
    return root


def test_an_empty_camera_folder_is_refused_unless_left_out_by_name(rig_dir, tmp_path):
    images = tmp_path / "rig"
    shutil.copytree(rig_dir / "rig", images)
    shutil.rmtree(images / "cam3")
    (images / "cam3").mkdir()  # the card not yet copied
    out = tmp_path / "out"
    shutil.copytree(rig_dir / "out", out)
    before = _tree(out)
    rc, said = _densecalib("calibrate", "--images", images, "--out", out, timeout_s=120)
    assert rc == 2, said
    assert (f"Camera folder {images / 'cam3'}/ (empty) without images: the rig would be "
            "calibrated without cam3") in said
    assert "--without cam3" in said and "Traceback" not in said
    assert _tree(out) == before  # cam3.yaml and the 4-camera calibration stay
    rc, said = _densecalib("calibrate", "--images", images, "--out", out, "--without", "cam4",
                           timeout_s=120)
    assert rc == 2 and "--without cam4: " in said and "has no camera cam4" in said, said
    rc, said = _densecalib("calibrate", "--images", images, "--out", out, "--without", "cam3",
                           "--consensus-runs", "1")
    assert rc == 0, said
    assert sorted(json.loads((out / "calibration.json").read_text())["cameras"]) == [
        "cam0", "cam1", "cam2"]


def test_one_cameras_folder_given_as_the_rigs_is_refused_with_the_parent(rig_dir, tmp_path):
    camera = rig_dir / "rig" / "cam0"
    rc, said = _densecalib("calibrate", "--images", camera, "--out", tmp_path / "out",
                           timeout_s=60)
    assert rc == 2, said
    assert (f"{camera} holds numbered images (0000.png, 0001.png, ...) and cam1, cam2, cam3 "
            "beside it hold the same numbers: these are the frames of one camera") in said
    assert f"--images {rig_dir / 'rig'}" in said and not (tmp_path / "out").exists()
    flat = tmp_path / "flat"  # one image per camera, named like cameras: as before
    flat.mkdir()
    for name in ("cam0", "cam1", "cam2", "cam3"):
        shutil.copy(rig_dir / "rig" / name / "0000.png", flat / f"{name}.png")
    shutil.copytree(flat, tmp_path / "flat_day2")  # a second session beside it
    assert list_image_folder(flat)[1] == ["cam0", "cam1", "cam2", "cam3"]


def test_images_of_different_sizes_name_the_file_and_give_width_x_height(rig_dir, tmp_path):
    images = tmp_path / "rig"
    shutil.copytree(rig_dir / "rig", images)
    other = images / "cam1" / "0002.png"
    cv2.imwrite(str(other), cv2.resize(cv2.imread(str(other)), (400, 300)))
    rc, said = _densecalib("calibrate", "--images", images, "--out", tmp_path / "out",
                           timeout_s=120)
    assert rc == 2, said
    assert (f"Images of camera cam1 differ in size: {other} is 400x300, "
            f"{images / 'cam1' / '0000.png'} 320x240") in said, said


def test_a_bag_camera_that_changes_resolution_is_named_with_width_x_height(tmp_path):
    """Frame sets from a bag (or videos, or the library) are checked together: the camera and
    the sets are named, sizes as W x H (they were lists of (w, h) of every camera)."""
    import numpy as np

    from densecalib_ros.core.io.bag import write_image_bag

    rng = np.random.default_rng(0)
    frames = [[rng.integers(0, 256, (240, 320, 3), np.uint8) for _ in range(2)]
              for _ in range(3)]
    frames[2][1] = rng.integers(0, 256, (300, 400, 3), np.uint8)
    topics = ["/cam0/image_raw", "/cam1/image_raw"]
    write_image_bag(tmp_path / "bag", frames, topics, [t * 10 ** 8 for t in range(3)])
    rc, said = _densecalib("calibrate", "--bag", tmp_path / "bag", "--topics", *topics,
                           "--out", tmp_path / "out", timeout_s=120)
    assert rc == 2, said
    assert ("Camera cam1's images change size between frame sets: 320x240 in set 0, 400x300 "
            "in set 2") in said, said
