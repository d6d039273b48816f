"""Peer baselines (real pycolmap SIFT + incremental / global SfM) on a small generated rig."""
import numpy as np
import pytest

from densecalib_ros.core.errors import InputError
from densecalib_ros.core.metrics import evaluate_calibration
from densecalib_ros.eval.peers import run_peer
from densecalib_ros.core.synthetic import RigSpec, generate_rig


@pytest.fixture(scope="module")
def rig():
    return generate_rig(RigSpec(lenses="ideal", num_cameras=4, camera_model="RADIAL", width=640, height=480,
                                seed=0, supersample=1))


def test_colmap_incremental_registers_and_is_accurate(rig):
    result = run_peer("colmap", rig.images[0], rig.names, lens="pinhole", num_threads=1)
    assert len(result.cam_from_world) >= 3, result.message
    assert result.runtime_s > 0
    for name, cam in result.cameras.items():
        assert cam.model == "SIMPLE_RADIAL" and (cam.width, cam.height) == (640, 480)
        np.testing.assert_allclose(result.cam_from_world[name][3], [0, 0, 0, 1])
    calib = result.to_rig_calibration(rig.names)
    metrics = evaluate_calibration(calib, rig.ground_truth())
    assert metrics["num_registered"] == len(result.cam_from_world)
    # SIFT + BA on a clean synthetic rig: poses well within 30 deg, focal within 5 %.
    assert metrics["auc30"] > 50.0
    assert metrics["median_focal_err"] < 0.05


def test_colmap_on_several_frame_sets_gives_one_camera_per_folder(tmp_path):
    """A rig filmed at two moments: each camera's frames share one COLMAP camera (PER_FOLDER) and
    the camera's pose is that of its first frame; the cameras do not move, so the rig is as
    accurate as from one frame set."""
    twice = generate_rig(RigSpec(lenses="ideal", num_cameras=3, camera_model="RADIAL", width=640,
                                  height=480, seed=0, supersample=1, num_time_steps=2))
    result = run_peer("colmap", twice.images[0], twice.names, lens="pinhole", num_threads=1,
                      later_frames=twice.images[1:], workdir=str(tmp_path))
    assert len(result.cam_from_world) == 3, result.message
    import pycolmap

    database = pycolmap.Database.open(tmp_path / "database.db")
    assert (database.num_images(), database.num_cameras()) == (6, 3)  # one camera per folder
    database.close()
    metrics = evaluate_calibration(result.to_rig_calibration(twice.names),
                                   twice.ground_truth())
    assert metrics["auc30"] > 50.0 and metrics["median_focal_err"] < 0.05
    with pytest.raises(InputError):
        run_peer("colmap", twice.images[0], twice.names, later_frames=[twice.images[1][:2]])


def test_glomap_runs_and_failure_is_an_empty_result(rig):
    result = run_peer("glomap", rig.images[0], rig.names, lens="pinhole", num_threads=1)
    assert len(result.cam_from_world) + len(result.unregistered) == 4
    assert set(result.unregistered).isdisjoint(result.cam_from_world)
    # Textureless images: nothing to match, so nothing registers, and the peer does not raise.
    blank = [np.full((240, 320, 3), 128, np.uint8)] * 4
    empty = run_peer("colmap", blank, rig.names, num_threads=1)
    assert empty.cam_from_world == {} and empty.unregistered == rig.names
    assert "no model" in empty.message
    metrics = evaluate_calibration(empty.to_rig_calibration(rig.names), rig.ground_truth())
    assert metrics["num_registered"] == 0 and metrics["auc30"] == 0.0


def test_unknown_method_is_a_typed_error(rig):
    with pytest.raises(InputError, match="colmap, glomap"):
        run_peer("vggt", rig.images[0], rig.names)


def test_bench_runs_a_scene_and_writes_json(tmp_path, capsys):
    import json

    from densecalib_ros.eval.bench import SceneSpec, run_bench

    spec = SceneSpec("synthetic-pinhole-4cam-480x360-s5", "synthetic", num_cameras=4,
                     width=480, height=360, seed=5)
    lines = []
    report = run_bench([spec, SceneSpec("absent-strecha", "strecha", folder="nope")], ["colmap"],
                       num_threads=1, data_dir=tmp_path, out_dir=tmp_path / "out", say=lines.append)
    assert report["skipped"][0]["scene"] == "absent-strecha"
    (entry,) = report["scenes"]
    (record,) = entry["results"]
    assert record["status"] == "ok" and record["metrics"]["num_registered"] >= 3
    assert record["runtime_s"] > 0
    table = "\n".join(lines)
    assert "colmap" in table and "AUC@30" in table and "summary" in table
    saved = json.loads((tmp_path / "out" / "bench.json").read_text())
    assert saved["summary"][0]["method"] == "colmap"
    assert saved["scenes"][0]["results"][0]["metrics"]["auc30"] == pytest.approx(
        record["metrics"]["auc30"])


def test_peer_survives_pycolmap_imported_before_cv2():
    """Regression: with pycolmap imported first, cv2's PNG encoder aborts the process."""
    import subprocess
    import sys

    code = ("import pycolmap, numpy as np\n"
            "from densecalib_ros.eval.peers import run_peer\n"
            "r = run_peer('colmap', [np.zeros((64, 64, 3), np.uint8)] * 3, ['a', 'b', 'c'],"
            " num_threads=1)\n"
            "print('unregistered', len(r.unregistered))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr[-2000:]
    assert "unregistered 3" in out.stdout
