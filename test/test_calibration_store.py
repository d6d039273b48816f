"""core.calibration_store: the node's output_dir of calibrations over time. New calibrations get
their own folder and `latest` follows them; a failed write leaves `latest` where it was; pruning
keeps the newest N, never the one `latest` points to, never anything it did not make."""
import os

import pytest

from densecalib_ros.core.calibration_store import (LATEST, prune_calibrations,
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
