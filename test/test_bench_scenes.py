"""The bench's scene sets: the held-out set must stay disjoint from the bench it checks."""
from densecalib_ros.core.bench import full_scenes, heldout_scenes, quick_scenes


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
