"""The bench's few-camera rooms (eval/few_rigs.py, `densecalib bench --few`): what issue 81 asks
of them, seeds of their own, every frame set handed on."""
import dataclasses
from pathlib import Path

import numpy as np

from densecalib_ros.cli import main as cli_main
from densecalib_ros.eval.bench import (build_scene, forward_scenes, full_scenes, heldout_scenes,
                                       mixed_scenes, quick_scenes)
from densecalib_ros.eval.few_rigs import few_scenes


def test_the_bench_few_camera_rooms_cover_the_issue_and_use_seeds_of_their_own():
    few = few_scenes()
    assert len(few) >= 6 and len({s.name for s in few}) == len(few)
    rigs = [dict(s.rig) for s in few]
    assert {s.num_cameras for s in few} == {3, 4}
    assert {s.camera_model for s in few} == {"RADIAL", "OPENCV_FISHEYE"}
    assert {r["lens_mix"] for r in rigs} == {"mixed", "identical"}
    assert {r["walker"] for r in rigs} == {"person", "animal"}
    assert all(r["room"] == "plain" and 20 <= r["num_time_steps"] <= 100 for r in rigs)
    assert all(45 <= s.gap_deg <= 140 for s in few)
    # fisheye lenses beyond 180 deg facing out, neighbours sharing their images' rims
    assert any(s.layout == "outward" and r.get("fov_deg", 0) > 180 for s, r in zip(few, rigs))
    others = full_scenes() + quick_scenes() + heldout_scenes() + mixed_scenes() + forward_scenes()
    assert not {s.seed for s in few} & {s.seed for s in others if s.kind == "synthetic"}
    # A scene hands every frame set on (the methods, COLMAP included, get them all).
    tiny = dataclasses.replace(few[0], width=96, height=54,
                               rig=tuple((k, 3 if k == "num_time_steps" else v)
                                         for k, v in few[0].rig))
    scene = build_scene(tiny, Path("/absent"))
    assert len(scene.frame_sets) == 3 and all(len(f) == few[0].num_cameras
                                              for f in scene.frame_sets)
    assert not np.array_equal(scene.frame_sets[0][0], scene.frame_sets[2][0])


def test_bench_lists_the_few_camera_rooms_and_keeps_the_full_set(capsys):
    assert cli_main(["bench", "--few", "--list"]) == 0
    assert capsys.readouterr().out.split() == [s.name for s in few_scenes()]
    assert cli_main(["bench", "--list"]) == 0
    assert capsys.readouterr().out.split() == [s.name for s in full_scenes()]
