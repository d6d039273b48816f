"""A COLMAP model damaged on disk (a full disk cut a file short) is refused by its size before
pycolmap reads it: `densecalib export --format ply` on a cut points3D.bin or images.bin exits 2
naming the file, with no more memory than reading the whole model takes (pycolmap took 17 GB on
such a file, issue 85 item 1); `calibrate` under a file-size limit that cuts the model it writes
leaves the last good output and does not balloon either."""
import os
import shutil
import subprocess
import sys

import numpy as np
import pytest

from densecalib_ros.core.io.colmap_files import model_problem
from densecalib_ros.core.io.export import read_saved_model, write_calibration_files
from densecalib_ros.core.synthetic import RigSpec, generate_rig, write_rig

import pycolmap  # noqa: E402  after densecalib_ros (cv2 first: both bundle zlib)

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
# The most address space a child may take: far above what these commands need (a few hundred
# MB), far below what pycolmap takes on a damaged model (17 GB), so that the test fails without
# the fix instead of exhausting a shared machine.
CHILD_ADDRESS_SPACE = 6 * 2 ** 30


def _model(rig, num_points=6000, seed=0):
    """A COLMAP model of `rig`'s true cameras (rig frame = the first camera's) with num_points
    scene points seen by every camera that images them: what calibrate saves, without a
    calibration."""
    rng = np.random.default_rng(seed)
    rig_from_world = rig.cam_from_world[0]
    xy = rng.uniform([0, 0], [rig.cameras[0].width, rig.cameras[0].height], (num_points, 2))
    world = rig.world_points(0, 0, xy)
    world = world[np.isfinite(world).all(axis=1)]
    rec = pycolmap.Reconstruction()
    seen = []
    for c, camera in enumerate(rig.cameras):
        rec.add_camera_with_trivial_rig(camera.to_pycolmap(camera_id=c + 1))
        xy_c, valid = rig.project(c, world)
        seen.append((np.flatnonzero(valid), xy_c[valid]))
        image = pycolmap.Image(name=rig.names[c], keypoints=xy_c[valid], camera_id=c + 1,
                               image_id=c + 1)
        cam_from_rig = rig.cam_from_world[c] @ np.linalg.inv(rig_from_world)
        rec.add_image_with_trivial_frame(image, pycolmap.Rigid3d(cam_from_rig[:3, :4]))
    position = [dict(zip(rows.tolist(), range(len(rows)))) for rows, _ in seen]
    xyz_rig = world @ rig_from_world[:3, :3].T + rig_from_world[:3, 3]
    for p in range(len(world)):
        elements = [pycolmap.TrackElement(c + 1, position[c][p])
                    for c in range(len(rig.cameras)) if p in position[c]]
        if len(elements) >= 2:
            rec.add_point3D(xyz_rig[p], pycolmap.Track(elements), np.array([200, 100, 50]))
    return rec


@pytest.fixture(scope="module")
def calibration(tmp_path_factory):
    rig = generate_rig(RigSpec(lenses="ideal", num_cameras=3, camera_model="RADIAL", width=320,
                               height=240, seed=3))
    folder = tmp_path_factory.mktemp("cal") / "cal"
    write_calibration_files(rig.ground_truth(), folder, _model(rig))
    return folder


def _start(command, file_size=None, env=()):
    """`command` (a list) in a child process limited to CHILD_ADDRESS_SPACE bytes (and
    file_size bytes per file written), this checkout importable; stdout and stderr together."""
    limits = [f"--as={CHILD_ADDRESS_SPACE}"] + ([f"--fsize={file_size}"] if file_size else [])
    env = {**os.environ, "PYTHONPATH": REPO + os.pathsep + os.environ.get("PYTHONPATH", ""),
           **dict(env)}
    return subprocess.Popen(["prlimit", *limits, sys.executable, *map(str, command)],
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)


def _finish(proc):
    """(exit code, peak resident memory in bytes, output) of a child _start started."""
    output = proc.stdout.read()
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    return proc.returncode, usage.ru_maxrss * 1024, output


def _run(args, file_size=None):
    """(exit code, peak resident memory in bytes, output) of `densecalib args`."""
    return _finish(_start(["-m", "densecalib_ros.cli", *args], file_size))


def _cut(calibration, tmp_path, name, keep_fraction):
    """A copy of the calibration with colmap/<name> cut to keep_fraction of its bytes."""
    copy = tmp_path / f"cut_{name}_{keep_fraction}"
    shutil.copytree(calibration, copy)
    path = copy / "colmap" / name
    os.truncate(path, int(path.stat().st_size * keep_fraction))
    return copy


@pytest.mark.parametrize("name, keep_fraction", [("points3D.bin", 0.93), ("points3D.bin", 0.5),
                                                 ("images.bin", 0.97), ("cameras.bin", 0.6)])
def test_a_model_cut_short_is_refused_with_no_more_memory_than_a_whole_read(
        calibration, tmp_path, name, keep_fraction):
    """The counts that are still whole at the file's start (points3D.bin's point count passes
    any header check at 93 %) made pycolmap read garbage counts past the end and grow a track
    until std::bad_alloc (here: until the address-space limit)."""
    assert model_problem(calibration / "colmap") is None
    whole_rc, whole_rss, _ = _run(["export", calibration, "--format", "ply",
                                   "--out", tmp_path / "whole.ply"])
    assert whole_rc == 0
    cut = _cut(calibration, tmp_path, name, keep_fraction)
    size = (cut / "colmap" / name).stat().st_size
    rc, rss, stderr = _run(["export", cut, "--format", "ply", "--out", tmp_path / "cut.ply"])
    assert rc == 2, stderr
    assert f"The COLMAP model in {cut / 'colmap'} is damaged ({name}" in stderr
    assert "calibrate again, or restore the folder" in stderr and "Traceback" not in stderr
    # the damaged read takes at most a small multiple of the file beyond the whole read
    assert rss <= whole_rss + 4 * size + 16 * 2 ** 20, (rss, whole_rss, size)
    assert not (tmp_path / "cut.ply").exists()


def test_counts_a_damaged_file_cannot_hold_are_named(calibration, tmp_path):
    cut = _cut(calibration, tmp_path, "points3D.bin", 1.0)
    path = cut / "colmap" / "points3D.bin"
    path.write_bytes((10 ** 9).to_bytes(8, "little") + bytes(100))
    assert model_problem(cut / "colmap") == ("points3D.bin claims 1000000000 points at byte 8; "
                                             "the 100 bytes left hold at most 1")
    path.write_bytes(b"")
    assert model_problem(cut / "colmap") == "points3D.bin is empty"
    whole = (calibration / "colmap" / "images.bin").read_bytes()
    (cut / "colmap" / "images.bin").write_bytes(whole + b"\x00")  # a count damaged downward
    path.write_bytes((calibration / "colmap" / "points3D.bin").read_bytes())
    assert model_problem(cut / "colmap") == (f"images.bin holds 1 bytes after its last record "
                                             f"(of {len(whole) + 1})")
    assert read_saved_model(calibration).num_points3D() > 1000  # the whole model still reads


@pytest.fixture(scope="module")
def images(tmp_path_factory):
    folder = tmp_path_factory.mktemp("rig") / "images"
    write_rig(generate_rig(RigSpec(lenses="ideal", num_cameras=3, camera_model="RADIAL",
                                   width=480, height=360, num_time_steps=2, seed=1)), folder)
    return folder


def test_calibrate_whose_model_is_cut_by_a_full_disk_keeps_the_last_output(images, tmp_path):
    """`prlimit --fsize` cuts points3D.bin as it is written (pycolmap's writer does not notice);
    the read-back refuses it by its sizes: exit 2, OUT as it was, and the run's peak memory that
    of a whole calibration (the read-back took 17 GB on such a file)."""
    out = tmp_path / "out"
    rc, whole_rss, stderr = _run(["calibrate", "--images", images, "--out", out,
                                  "--consensus-runs", "1"])
    assert rc == 0, stderr
    sizes = {p.name: p.stat().st_size for p in (out / "colmap").iterdir()}
    before = {p.name: p.read_bytes() for p in out.rglob("*") if p.is_file()}
    # every file but points3D.bin fits; its point count (51 bytes each at least) stays in it
    limit = max(max(s for n, s in sizes.items() if n != "points3D.bin") + 1,
                int(sizes["points3D.bin"] * 0.93))
    assert limit < sizes["points3D.bin"], sizes
    rc, rss, stderr = _run(["calibrate", "--images", images, "--out", out,
                            "--consensus-runs", "1"], file_size=limit)
    assert rc == 2, stderr
    assert f"Cannot write the COLMAP model" in stderr and "points3D.bin" in stderr
    assert "Traceback" not in stderr
    assert {p.name: p.read_bytes() for p in out.rglob("*") if p.is_file()} == before
    assert rss <= 1.2 * whole_rss + 64 * 2 ** 20, (rss, whole_rss)


def _node_start_up(output_dir, names):
    """(peak resident memory in bytes, output) of the node started on output_dir and stopped
    with SIGTERM once it is ready."""
    import signal

    topics = "[" + ",".join(f"'/{n}/image_raw'" for n in names) + "]"
    node = _start(["-c", "import sys; from densecalib_ros.ros.main import main; sys.exit(main())",
                   "--ros-args", "-p", f"image_topics:={topics}",
                   "-p", f"output_dir:={output_dir}"],
                  env={"ROS_DOMAIN_ID": str(30 + (os.getpid() + 35) % 70)})
    lines = []
    for line in node.stdout:
        lines.append(line)
        if "ready:" in line:
            break
    node.send_signal(signal.SIGTERM)
    _, rss, rest = _finish(node)
    return rss, "".join(lines) + rest


def test_the_node_starting_on_a_cut_model_publishes_the_calibration_without_its_points(
        calibration, tmp_path):
    """The node publishes the scene points of `latest`'s model at start-up: a cut points3D.bin
    took it to 4.3 GB. Now the calibration is published, the points are not, and it says why;
    its start-up takes the memory of one on the whole model."""
    pytest.importorskip("rclpy", reason="the node needs rclpy (ROS 2 Jazzy)")
    names = sorted(p.stem for p in calibration.glob("*.yaml"))
    rss = {}
    for kind, keep in (("whole", 1.0), ("cut", 0.93)):
        output_dir = tmp_path / kind
        output_dir.mkdir()
        shutil.copytree(_cut(calibration, tmp_path, "points3D.bin", keep),
                        output_dir / "20260101T000000Z")
        os.symlink("20260101T000000Z", output_dir / "latest")
        rss[kind], said = _node_start_up(output_dir, names)
        assert "published" in said and "ready:" in said, said
    assert "no scene points published: The COLMAP model" in said and "points3D.bin" in said
    size = (output_dir / "latest" / "colmap" / "points3D.bin").stat().st_size
    assert rss["cut"] <= rss["whole"] + 4 * size + 32 * 2 ** 20, rss
