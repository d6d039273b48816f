"""core.io.calibration_store: the node's output_dir of calibrations over time. New calibrations get
their own folder and `latest` follows them; a failed write leaves `latest` where it was; pruning
keeps the newest N, never the one `latest` points to, never anything it did not make."""
import os

import pytest

from densecalib_ros.core.io.calibration_store import (LATEST, prune_calibrations,
                                                      stored_calibrations, write_new_calibration)


def _write(text):
    def write(folder):
        (folder / "calibration.json").write_text(text)
    return write


def test_each_calibration_gets_a_folder_and_latest_follows(tmp_path):
    root = tmp_path / "out"
    first = write_new_calibration(root, _write("1"))
    second = write_new_calibration(root, _write("2"))  # within the same second: a suffix
    assert first != second and stored_calibrations(root) == [first, second]
    assert (root / LATEST).resolve() == second and os.readlink(root / LATEST) == second.name
    assert (root / LATEST / "calibration.json").read_text() == "2"

    def fails(folder):
        (folder / "calibration.json").write_text("half")
        raise RuntimeError("disk full")

    with pytest.raises(RuntimeError):
        write_new_calibration(root, fails)
    assert stored_calibrations(root) == [first, second] and (root / LATEST).resolve() == second
    assert sorted(p.name for p in root.iterdir()) == sorted([first.name, second.name, LATEST])


def test_pruning_keeps_the_newest_and_latest_and_nothing_else_is_touched(tmp_path):
    root = tmp_path / "out"
    names = ["20261124T090000Z", "20261124T100000Z", "20261124T100000Z_1",
             "20261124T100000Z_2", "20261124T110000Z"]
    for name in reversed(names):  # created out of order: the names give the order
        (root / name).mkdir(parents=True)
    (root / "field_notes").mkdir()  # the user's: not a calibration
    (root / "20261124T080000Z.json").write_text("{}")  # a file with a calibration's name
    os.symlink(names[1], root / LATEST)  # pointed back at an older one (then ~/reload)
    assert [p.name for p in stored_calibrations(root)] == names
    assert prune_calibrations(root, 0) == []  # 0: keep all
    removed = prune_calibrations(root, 2)
    assert [p.name for p in removed] == [names[0], names[2]]  # names[1] is latest's
    assert sorted(p.name for p in root.iterdir()) == sorted(
        [names[1], names[3], names[4], "field_notes", "20261124T080000Z.json", LATEST])
    assert prune_calibrations(root, 1, protected=[root / names[3]]) == []
    assert [p.name for p in prune_calibrations(root, 1)] == [names[3]]
    assert [p.name for p in stored_calibrations(root)] == [names[1], names[4]]
    assert prune_calibrations(tmp_path / "absent", 3) == []


def test_report_history_says_what_changed_between_stored_calibrations(tmp_path, capsys):
    """`densecalib report OUTPUT_DIR --history`: three calibrations of a generated rig, cam2
    turned by 1 deg in the second, cam1's focal 2 % longer in the third; an unreadable folder is
    listed as such."""
    import copy
    import json

    from scipy.spatial.transform import Rotation

    from densecalib_ros.cli import main
    from densecalib_ros.core.io.export import write_calibration_files
    from densecalib_ros.core.synthetic import RigSpec, generate_rig

    truth = generate_rig(RigSpec(lenses="ideal", num_cameras=4, width=320, height=240, seed=5)).ground_truth()
    turned = copy.deepcopy(truth)
    cam2 = turned.cameras["cam2"]
    cam2.cam_from_rig = cam2.cam_from_rig.copy()
    cam2.cam_from_rig[:3, :3] = Rotation.from_euler("x", 1.0, degrees=True).as_matrix() @ \
        cam2.cam_from_rig[:3, :3]
    refocused = copy.deepcopy(turned)
    refocused.cameras["cam1"].intrinsics.params[0] *= 1.02
    root = tmp_path / "out"
    for rig in (truth, turned):
        write_new_calibration(root, lambda folder, rig=rig: write_calibration_files(rig, folder))
    broken = write_new_calibration(root, _write("{not json"))
    write_new_calibration(root, lambda folder: write_calibration_files(refocused, folder))

    assert main(["report", str(root), "--history"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 6 and lines[-1] == "* = latest"
    assert lines[1].endswith("(the first kept)") and " 4/4 " in lines[1]
    assert "rotation up to 1.00 deg (cam2)" in lines[2] and "focal up to +0.00 %" in lines[2]
    assert f"{broken.name:<20} unreadable" in lines[3]
    assert lines[4].startswith("* ") and "focal up to +2.00 % (cam1)" in lines[4]
    assert main(["report", str(root), "--history", "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert [r.get("latest") for r in rows] == [False, False, None, True]
    assert main(["report", str(tmp_path), "--history"]) == 2  # no stored calibrations
