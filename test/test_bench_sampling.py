"""`densecalib bench-sampling --angles`: the viewpoint sweep measures what it says (the angle
between the generated cameras' axes, matches judged against the true correspondences)."""
import json

from densecalib_ros.cli import main


def test_the_angle_sweep_measures_matches_against_the_true_viewpoint_change(tmp_path, capsys):
    assert main(["bench-sampling", "--angles", "30", "70", "--quick", "--matchers", "sift",
                 "--width", "640", "--height", "480", "--out", str(tmp_path)]) == 0
    rows = json.loads((tmp_path / "bench_sampling_angles.json").read_text())
    assert {(r["model"], r["angle_deg"]) for r in rows} == {
        (m, a) for m in ("RADIAL", "OPENCV_FISHEYE") for a in (30.0, 70.0)}
    for r in rows:
        # Cameras aim at points near the scene centre: axes about the arc step apart.
        assert abs(r["axis_angle_deg"] - r["angle_deg"]) < 12
        assert 0 <= r["raw_inlier_frac"] <= 1
        assert r["correct_per_pair"] <= r["raw_matches_per_pair"]
    fisheye = {r["angle_deg"]: r for r in rows if r["model"] == "OPENCV_FISHEYE"}
    # A small step matches well, and more of its matches are right than at a wide one.
    assert fisheye[30.0]["raw_inlier_frac"] > 0.8
    assert fisheye[30.0]["correct_per_pair"] > fisheye[70.0]["correct_per_pair"]
    printed = capsys.readouterr().out
    assert "axes deg" in printed and "right/pair" in printed
