"""The bench's scene sets: the held-out set must stay disjoint from the bench it checks; what the
tables say of the warnings a result carried."""
import numpy as np
import pytest

from densecalib_ros.eval.bench import (forward_scenes, full_scenes, heldout_scenes, mixed_scenes,
                                       quick_scenes)
from densecalib_ros.eval.tables import (few_rigs_check, format_few_rigs_check,
                                       format_rotation_against_colmap, format_scene_table,
                                       format_summary, format_time_against_colmap,
                                       rotation_against_colmap, summarize, time_against_colmap)


def test_heldout_scenes_share_no_scene_or_generator_seed_with_the_bench():
    bench = full_scenes() + quick_scenes()
    heldout = heldout_scenes()
    assert len({s.name for s in heldout}) == len(heldout)
    assert not {s.name for s in heldout} & {s.name for s in bench}
    bench_seeds = {s.seed for s in bench if s.kind == "synthetic"}
    assert not {s.seed for s in heldout if s.kind == "synthetic"} & bench_seeds
    # Real frames: other subsets of the capture than the bench's.
    bench_views = {s.num_cameras for s in bench if s.kind == "nerf"}
    assert all(s.num_cameras not in bench_views for s in heldout if s.kind == "nerf")


def test_the_real_captures_of_one_camera_are_benched_as_one_camera_as_well():
    """Strecha's DSLR and the fox's phone: each scene also as one camera (shared intrinsics, what
    they are), and build_scene hands that on whatever the scene's kind."""
    import dataclasses
    from pathlib import Path

    from densecalib_ros.eval.bench import build_scene

    for specs in (full_scenes(), heldout_scenes()):
        one = {s.name for s in specs if s.share_intrinsics}
        two_ways = {s.name for s in specs if s.kind in ("strecha", "nerf")} - one
        assert one == {f"{n}-one-camera" for n in two_ways}
    tiny = dataclasses.replace(quick_scenes()[0], num_cameras=3, width=160, height=120)
    assert tiny.kind == "synthetic"
    for share in (False, True):
        scene = build_scene(dataclasses.replace(tiny, share_intrinsics=share), Path("/absent"))
        assert scene.share_intrinsics is share


def test_forward_rigs_are_bar_rigs_of_seeds_no_other_set_uses():
    forward = forward_scenes()
    assert forward and all(s.layout == "bar" and s.kind == "synthetic" for s in forward)
    others = full_scenes() + quick_scenes() + heldout_scenes() + mixed_scenes()
    assert not {s.seed for s in forward} & {s.seed for s in others if s.kind == "synthetic"}
    assert len({s.name for s in forward}) == len(forward)


def _record(method: str, auc3: float, warnings: list) -> dict:
    metrics = dict(num_registered=4, num_cameras=4, auc3=auc3, auc30=100.0,
                   median_focal_err=0.08, median_proj_err_px=3.0)
    return dict(method=method, status="ok", message="", runtime_s=1.0, peak_rss_mib=100.0,
                metrics=metrics, warnings=warnings)


def test_tables_name_the_warnings_a_result_carried_and_count_the_scenes_warned():
    long_warning = "focal lengths weakly determined by these images: " + "x" * 200
    scenes = [dict(scene=f"s{k}", lens="pinhole", num_cameras=4, image_size=[1024, 768],
                   results=[_record("colmap", 50.0, []),
                            _record("densecalib-incremental", 100.0, warnings)])
              for k, warnings in enumerate([[long_warning], [], ["other"]])]
    table = format_scene_table(scenes[0])
    line = [row for row in table.splitlines() if "warned" in row]
    assert line == ["  densecalib-incremental warned: " + long_warning[:97] + "..."]
    assert "warned" not in format_scene_table(scenes[1])
    summary = {s["method"]: s for s in summarize(scenes)}
    assert summary["densecalib-incremental"]["warned"] == 2
    assert summary["colmap"]["warned"] == 0
    rows = format_summary(list(summary.values())).splitlines()
    assert rows[1].split()[-1] == "warned"
    assert [r.split()[-1] for r in rows[2:]] == ["0", "2"]
    assert np.isclose(summary["densecalib-incremental"]["median_focal_err"], 0.08)


def test_a_scene_table_gives_each_methods_errors_over_its_own_sigmas():
    """Issue 82: per scene, how the sigmas compare with the errors (focal, principal point,
    projection), beside the image size in its header; methods without sigmas get no line."""
    ours = _record("densecalib-incremental", 100.0, [])
    ours["error_sigma_ratios"] = {"focal": [0.5, 3.0, 1.0], "principal_point": [],
                                  "projection": [0.25]}
    scene = dict(scene="s0", lens="pinhole", num_cameras=4, image_size=[1536, 1024],
                 results=[_record("colmap", 50.0, []), ours])
    lines = format_scene_table(scene).splitlines()
    assert "1536x1024" in lines[0]
    assert [row for row in lines if "own sigma" in row] == [
        "  densecalib-incremental |error| / own sigma: focal median 1.00, max 3.00 (n=3); "
        "projection median 0.25, max 0.25 (n=1)"]


def test_tables_give_each_methods_time_over_colmaps_on_the_same_scene():
    def scene(k, ours_s, colmap_s):
        records = [_record("colmap", 50.0, []), _record("densecalib-incremental", 90.0, [])]
        records[0]["runtime_s"], records[1]["runtime_s"] = colmap_s, ours_s
        return dict(scene=f"s{k}", lens="pinhole", num_cameras=4, image_size=[1024, 768],
                    results=records)

    scenes = [scene(0, 30.0, 10.0), scene(1, 5.0, 10.0), scene(2, 12.0, 8.0)]
    lines = format_scene_table(scenes[0]).splitlines()
    end = lines[1].index("xCOLMAP") + len("xCOLMAP")  # right-aligned under its header
    assert [r[end - 8:end].strip() for r in lines[2:]] == ["1.00", "3.00"]
    summary = {s["method"]: s for s in summarize(scenes)}
    assert summary["densecalib-incremental"]["median_colmap_time_ratio"] == 1.5
    assert summary["colmap"]["median_colmap_time_ratio"] == 1.0


def test_the_bench_lists_the_scenes_where_our_rotations_are_worse_than_colmaps():
    """Issue 82: no scene worse than COLMAP's rotation error where both register every camera;
    a scene where either leaves a camera out is not compared, one whose reference is an SfM
    estimate is marked so."""
    def scene(k, ours_deg, colmap_deg, registered=4, sfm=False):
        records = [_record("colmap", 50.0, []), _record("densecalib-incremental", 90.0, [])]
        records[0]["metrics"]["median_rot_err_deg"] = colmap_deg
        records[1]["metrics"].update(median_rot_err_deg=ours_deg, num_registered=registered)
        return dict(scene=f"s{k}", reference_is_estimate=sfm, results=records)

    scenes = [scene(0, 0.1, 0.2), scene(1, 0.3, 0.2), scene(2, 0.5, 0.2, registered=3),
              scene(3, 0.44, 0.31, sfm=True)]
    check = rotation_against_colmap(scenes)["densecalib-incremental"]
    assert check["compared"] == 3
    assert [(w["scene"], w["sfm_reference"]) for w in check["worse"]] == [("s1", False),
                                                                          ("s3", True)]
    line = format_rotation_against_colmap({"densecalib-incremental": check}).splitlines()[1]
    assert line.endswith("no worse on 1 of 3; worse on s1 0.300 against 0.200 deg; s3 0.440 "
                         "against 0.310 deg (reference: an SfM estimate)")


def test_the_bench_checks_our_time_against_colmaps_as_issue_84_bounds_it():
    """The median ratio over rigs of 6-10 cameras only, and the rigs of at most 10 cameras at up
    to 1536 px beyond 3x COLMAP's time or 60 s, whichever is larger; a scene COLMAP did not run
    on is not counted."""
    def scene(k, cameras, ours_s, colmap_s, side=1024):
        records = [_record("colmap", 50.0, []), _record("densecalib-incremental", 90.0, [])]
        records[0]["runtime_s"], records[1]["runtime_s"] = colmap_s, ours_s
        if colmap_s is None:
            records = records[1:]
        return dict(scene=f"s{k}", num_cameras=cameras, image_size=[side, side * 3 // 4],
                    results=records)

    scenes = [scene(0, 6, 4.0, 5.0), scene(1, 8, 12.0, 6.0), scene(2, 10, 70.0, 30.0),
              scene(3, 4, 65.0, 3.0), scene(4, 5, 50.0, 2.0), scene(5, 6, 90.0, 20.0),
              scene(6, 6, 200.0, 5.0, side=1920), scene(7, 11, 300.0, 5.0), scene(8, 6, 99.0, None)]
    check = time_against_colmap(scenes)["densecalib-incremental"]
    assert check["median_rigs"] == 5 and check["median_ratio"] == pytest.approx(70.0 / 30.0)
    assert check["timed"] == 6
    assert [(b["scene"], b["bound_s"]) for b in check["beyond"]] == [("s3", 60.0), ("s5", 60.0)]
    line = format_time_against_colmap({"densecalib-incremental": check}).splitlines()[1]
    assert line.endswith("median 2.33x over 5 rigs; 4 of 6 within the bound; beyond it: s3 65.0 s "
                         "(COLMAP 3.0 s); s5 90.0 s (COLMAP 20.0 s)")


def test_the_bench_checks_the_rigs_users_build_as_issue_81_bounds_them():
    """Generated rigs of 3-4 cameras over several frame sets only: each at AUC@3 >= 90, refused,
    or kept below it with or without a warning; the time of those of 4 cameras x 20 frame sets
    at 1280x720 against 2 minutes."""
    def scene(k, cameras, auc3, status="ok", warnings=(), sets=20, kind="synthetic", s=60.0):
        records = [_record("colmap", 0.0, []), _record("densecalib-incremental", auc3,
                                                        list(warnings))]
        records[1].update(status=status, runtime_s=s,
                          message="UndeterminedRigError: the runs disagree\nmore" if status != "ok"
                          else "")
        return dict(scene=f"s{k}", num_cameras=cameras, image_size=[1280, 720],
                    num_time_steps=sets, spec=dict(kind=kind), results=records)

    scenes = [scene(0, 3, 100.0), scene(1, 4, 88.9, warnings=["loose"], s=130.0),
              scene(2, 4, 0.0, status="failed"), scene(3, 3, 50.0), scene(4, 4, 90.0, s=90.0),
              scene(5, 4, 10.0, sets=1), scene(6, 5, 10.0), scene(7, 4, 10.0, kind="real")]
    check = few_rigs_check(scenes)["densecalib-incremental"]
    assert check["rigs"] == 5 and check["reached"] == ["s0", "s4"]
    assert check["refused"] == [dict(scene="s2", message="UndeterminedRigError: the runs disagree")]
    assert check["short"] == [dict(scene="s1", auc3=88.9, warned=True),
                              dict(scene="s3", auc3=50.0, warned=False)]
    assert [t["scene"] for t in check["timed"]] == ["s1", "s2", "s4"]
    line = format_few_rigs_check({"densecalib-incremental": check}).splitlines()[1]
    assert line.endswith("2 of 5 at AUC@3 >= 90, 1 refused (s2: UndeterminedRigError); below "
                         "it: s1 88.9 warned; s3 50.0 NOT WARNED; timed 2 of 3 within 120 s "
                         "(slowest 130.0 s); over it: s1 130.0 s")


def test_peak_memory_counts_the_worker_processes():
    """A child process that holds 200 MiB shows in the bench's peak memory of this process."""
    import subprocess
    import sys

    from densecalib_ros.eval.bench import _peak_rss_mib, _reset_peak_rss

    assert _reset_peak_rss()
    alone = _peak_rss_mib()
    child = subprocess.Popen([sys.executable, "-c", "import sys; b = bytearray(200 << 20); "
                              "b[::4096] = b'x' * len(b[::4096]); print(1, flush=True); "
                              "sys.stdin.read()"], stdin=subprocess.PIPE, stdout=subprocess.PIPE)
    try:
        assert child.stdout.readline().strip() == b"1"
        assert _peak_rss_mib() - alone > 190
    finally:
        child.communicate(b"")
