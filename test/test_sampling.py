"""Hierarchical two-stage grid sampling on fabricated site matches of synthetic pinhole rigs."""
import numpy as np
import pytest

from densecalib_ros.core.config import make_config
from densecalib_ros.core.errors import NotEnoughOverlapError
from densecalib_ros.core.method.grid_sampling import cell_ids
from densecalib_ros.core.method.sampling import sample_tracks
from densecalib_ros.core.method.twoview import symmetric_epipolar_distance_px
from densecalib_ros.core.types import SiteMatches, SiteMatchSet
from test_cycles import make_scene, match_set_from_scene


def config(**overrides):
    return make_config("regular", "incremental", **overrides)


def test_end_to_end_focals_scores_and_track_coordinates():
    scene = make_scene(num_cams=5, num_points=3000, seed=0)
    ms, pos, _ = match_set_from_scene(scene)
    res = sample_tracks([ms], config(sampling__cell_size_px=40))
    tracks = res.tracks
    assert tracks.num_tracks > 200 and tracks.num_cameras == 5
    assert set(np.unique(tracks.cycle_order)) == {4} or 4 in tracks.cycle_order
    np.testing.assert_allclose(res.focal_px, scene["focals"], rtol=0.03)
    assert np.all(tracks.score >= 0) and tracks.score.max() > 0
    # Every observation is the exact projection of one 3D point in every observing camera.
    obs = tracks.observed()
    for k in range(tracks.num_tracks):
        cams = np.flatnonzero(obs[k])
        assert len(cams) == tracks.cycle_order[k]
        points = {int(np.flatnonzero(np.all(scene["xy"][c] == tracks.xy_px[k, c], axis=1))[0])
                  for c in cams}
        assert len(points) == 1
    for (i, j), geo in res.two_view.items():
        assert i < j and geo.R_ji is not None
        R_true = scene["R"][j] @ scene["R"][i].T
        angle = np.degrees(np.arccos(np.clip((np.trace(geo.R_ji.T @ R_true) - 1) / 2, -1, 1)))
        assert angle < 0.5


def test_deterministic_per_seed():
    scene = make_scene(num_cams=4, num_points=2000, seed=1)
    ms, _, _ = match_set_from_scene(scene)
    a = sample_tracks([ms], config()).tracks
    b = sample_tracks([ms], config()).tracks
    c = sample_tracks([ms], config(sampling__seed=7)).tracks
    np.testing.assert_array_equal(a.xy_px, b.xy_px)
    np.testing.assert_array_equal(a.score, b.score)
    assert a.xy_px.shape != c.xy_px.shape or not np.array_equal(a.xy_px, c.xy_px, equal_nan=True)


def test_filled_cell_not_refilled_by_lower_order():
    """Camera 2 sees only the left half of camera 0's view: 3-cycles fill cells there, 2-cycles
    (0, 1) may only fill cells that no 3-cycle holds."""
    scene = make_scene(num_cams=3, num_points=4000, seed=2)
    extra = [np.ones(4000, bool), np.ones(4000, bool), scene["xy"][0][:, 0] < 320]
    ms, _, _ = match_set_from_scene(scene, extra)
    cfg = config(sampling__max_grid_iterations=1, sampling__cell_size_px=40)
    tracks = sample_tracks([ms], cfg).tracks
    obs = tracks.observed()
    three = tracks.cycle_order == 3
    two01 = (tracks.cycle_order == 2) & obs[:, 0] & obs[:, 1]
    assert three.sum() > 30 and two01.sum() > 30
    cells3 = set(cell_ids(tracks.xy_px[three, 0], 40, (640, 480)).tolist())
    cells2 = cell_ids(tracks.xy_px[two01, 0], 40, (640, 480))
    assert not cells3 & set(cells2.tolist())
    assert len(set(cells2.tolist())) == len(cells2)  # one track per cell
    assert np.median(tracks.xy_px[two01, 0, 0]) > 320  # 2-cycles went where 3-cycles could not


def test_coverage_rule_halves_cells_for_concentrated_matches():
    scene = make_scene(num_cams=3, num_points=6000, seed=3)
    spread, _, _ = match_set_from_scene(scene)
    x0 = scene["xy"][0]
    small = (np.abs(x0[:, 0] - 320) < 70) & (np.abs(x0[:, 1] - 240) < 70)
    concentrated, _, _ = match_set_from_scene(scene, [small, np.ones(6000, bool),
                                                      np.ones(6000, bool)])
    cfg = config(sampling__cell_size_px=80, sampling__top_k=0)
    res_spread = sample_tracks([spread], cfg)
    res_conc = sample_tracks([concentrated], cfg)
    assert res_spread.stats["halvings"][3] == 0
    assert res_conc.stats["halvings"][3] >= 1
    n3 = (res_conc.tracks.cycle_order == 3).sum()
    # The 140x140 px region spans 2x2 cells of 80 px; n_min = 0.3 * 8 * 6 = 14.4 cells needs
    # the 40 px grid (4x4 cells there).
    assert n3 >= 15
    cfg_no_halving = config(sampling__cell_size_px=80, sampling__top_k=0,
                            sampling__max_grid_iterations=1)
    assert (sample_tracks([concentrated], cfg_no_halving).tracks.cycle_order == 3).sum() <= 9


def test_argmax_picks_best_score_and_top_k_zero_is_unscored():
    scene = make_scene(num_cams=3, num_points=3000, seed=4)
    ms, _, _ = match_set_from_scene(scene)
    res = sample_tracks([ms], config(sampling__probabilistic_scoring=False,
                                     sampling__max_grid_iterations=1))
    res_prob = sample_tracks([ms], config(sampling__max_grid_iterations=1))
    res_none = sample_tracks([ms], config(sampling__top_k=0, sampling__max_grid_iterations=1))
    assert np.all(res_none.tracks.score == 0)
    three = res.tracks.cycle_order == 3
    assert res.tracks.score[three].mean() >= res_prob.tracks.score[
        res_prob.tracks.cycle_order == 3].mean()
    assert res.tracks.score[three].mean() > res_none.tracks.score.mean()


def test_f_err_filter_removes_geometrically_wrong_but_consistent_cycles():
    scene = make_scene(num_cams=4, num_points=3000, seed=5)
    ms, _, sop = match_set_from_scene(scene)
    rng = np.random.default_rng(0)
    moved = np.flatnonzero(sop[2] >= 0)
    moved = rng.choice(moved, 300, replace=False)
    ms.sites[2] = ms.sites[2].copy()
    ms.sites[2][sop[2][moved]] += rng.choice([-1, 1], size=(300, 2)) * 25.0  # consistent, wrong
    res = sample_tracks([ms], config(sampling__cell_size_px=20))
    assert sum(res.stats["f_err_removed"].values()) > 100
    tracks = res.tracks
    obs = tracks.observed()
    for (i, j), geo in res.two_view.items():
        m = obs[:, i] & obs[:, j]
        d = symmetric_epipolar_distance_px(geo.F_ji, tracks.xy_px[m, i], tracks.xy_px[m, j])
        assert d.max() <= 10.0
    # F_err off (fisheye preset): only 2-cycles, which closure does not verify, are still tested.
    off = make_config("regular", "incremental", sfm__f_err_px=None, sampling__cell_size_px=20)
    removed = sample_tracks([ms], off).stats["f_err_removed"]
    assert removed[2] > 0 and removed[3] == 0 and removed[4] == 0
    none = make_config("regular", "incremental", sfm__f_err_px=None,
                       sfm__two_cycle_f_err_px=None, sampling__cell_size_px=20)
    assert sum(sample_tracks([ms], none).stats["f_err_removed"].values()) == 0


def test_budget_and_time_steps():
    scenes = [make_scene(num_cams=4, num_points=2000, seed=10 + t) for t in range(2)]
    sets = [match_set_from_scene(s)[0] for s in scenes]
    for s in sets:  # same rig, different scenes: use the first scene's cameras
        s.image_sizes = [(640, 480)] * 4
    cfg = config(sampling__samples_per_order={4: 50, 3: 20, 2: 10}, sampling__cell_size_px=40)
    tracks = sample_tracks(sets[:1], cfg, focal_px=np.full(4, 700.0)).tracks
    assert (tracks.cycle_order == 4).sum() == 50
    assert (tracks.cycle_order == 3).sum() <= 20 and (tracks.cycle_order == 2).sum() <= 10
    both = sample_tracks(sets[:1] * 2, cfg, focal_px=np.full(4, 700.0)).tracks
    assert set(np.unique(both.time_index)) == {0, 1}
    assert (both.cycle_order == 4).sum() == 50


def test_given_poses_and_intrinsics_score_without_estimation():
    scene = make_scene(num_cams=3, num_points=2000, seed=6)
    ms, _, _ = match_set_from_scene(scene)
    from densecalib_ros.core.types import CameraIntrinsics
    intr = [CameraIntrinsics("RADIAL", 640, 480, np.array([K[0, 0], K[0, 2], K[1, 2], 0.0, 0.0]))
            for K in scene["K"]]
    poses = []
    for R, t in zip(scene["R"], scene["t"]):
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R, t
        poses.append(T)
    res = sample_tracks([ms], config(), cam_from_rig=poses, intrinsics=intr)
    assert res.stats["focal_source"] == "intrinsics"
    np.testing.assert_allclose(res.focal_px, scene["focals"])
    assert res.tracks.score.max() > 0


def test_no_overlap_raises():
    sites = [np.random.default_rng(0).uniform(0, 100, (50, 2)) for _ in range(2)]
    none = np.full(50, -1, np.int32)
    ms = SiteMatchSet(sites, {(0, 1): SiteMatches(none, np.zeros(50, np.float32)),
                              (1, 0): SiteMatches(none, np.zeros(50, np.float32))},
                      [(100, 100)] * 2)
    with pytest.raises(NotEnoughOverlapError):
        sample_tracks([ms], config())


def _with_refined_targets(ms, pos, offset_px, nan_mask=None):
    """Copy of `ms` whose pair (i, j) carries target_xy_px = the site position in j shifted by
    offset_px(i, j) (a pair-specific (2,) shift), NaN where nan_mask(i, j) (S_i,) is set."""
    pairs = {}
    for (i, j), m in ms.pairs.items():
        xy = np.full((len(m.target), 2), np.nan)
        ok = m.target >= 0
        xy[ok] = ms.sites[j][m.target[ok]] + offset_px(i, j)
        if nan_mask is not None:
            xy[nan_mask(i, j)] = np.nan
        pairs[(i, j)] = SiteMatches(m.target, m.certainty, xy)
    return SiteMatchSet(ms.sites, pairs, ms.image_sizes)


def test_track_observations_follow_the_anchor_rule():
    """Cameras other than a track's first (anchor) camera observe the position that pair
    (anchor, c) refined for the anchor's site; unrefined (NaN) entries fall back to the site."""
    scene = make_scene(num_cams=3, num_points=3000, seed=7)
    ms, pos, sop = match_set_from_scene(scene)

    def offset(i, j):  # small (F stays valid), different for every ordered pair
        return np.array([0.01 * (3 * i + j + 1), -0.02 * (i + 1)])

    odd = {c: pos[c] % 2 == 1 for c in range(3)}  # unrefined: sites of odd scene points
    refined = _with_refined_targets(ms, pos, offset, lambda i, j: odd[i])
    cfg = config(sampling__cell_size_px=40)
    tracks = sample_tracks([refined], cfg).tracks
    obs = tracks.observed()
    checked = {True: 0, False: 0}
    for k in range(tracks.num_tracks):
        cams = np.flatnonzero(obs[k])
        anchor = cams[0]
        hits = np.flatnonzero(np.all(scene["xy"][anchor] == tracks.xy_px[k, anchor], axis=1))
        assert len(hits) == 1  # the anchor keeps its exact site position
        p = hits[0]
        for c in cams[1:]:
            expected = scene["xy"][c][p] + (0.0 if p % 2 else offset(anchor, c))
            np.testing.assert_allclose(tracks.xy_px[k, c], expected, atol=1e-9)
            checked[bool(p % 2)] += 1
    assert checked[True] > 50 and checked[False] > 50
    # Without the field, or with nothing refined, observations are the site positions.
    plain = sample_tracks([ms], cfg).tracks
    unrefined = _with_refined_targets(ms, pos, offset, lambda i, j: np.ones(len(pos[i]), bool))
    np.testing.assert_array_equal(sample_tracks([unrefined], cfg).tracks.xy_px, plain.xy_px)


def test_two_cycles_of_unverified_pairs_are_not_sampled():
    """Pair (0, 2) keeps only 10 right matches plus 10 wrong ones: its F has fewer inliers than
    min_two_cycle_pair_inliers, so none of its 2-cycles (which only F_err could verify) is
    sampled; its 3-cycles, verified by closure, still are."""
    scene = make_scene(num_cams=3, num_points=3000, seed=8)
    ms, _, sop = match_set_from_scene(scene)
    rng = np.random.default_rng(1)
    both = np.flatnonzero((sop[0] >= 0) & (sop[2] >= 0))
    right = rng.choice(both, 10, replace=False)
    wrong_src = rng.choice(np.setdiff1d(both, right), 10, replace=False)
    wrong_dst = rng.permutation(wrong_src)  # sites of other points: consistent but wrong
    fwd = np.full(len(ms.sites[0]), -1, np.int32)
    fwd[sop[0][right]] = sop[2][right]
    fwd[sop[0][wrong_src]] = sop[2][wrong_dst]
    bwd = np.full(len(ms.sites[2]), -1, np.int32)
    bwd[fwd[fwd >= 0]] = np.flatnonzero(fwd >= 0)
    ms.pairs[(0, 2)] = SiteMatches(fwd, (fwd >= 0).astype(np.float32))
    ms.pairs[(2, 0)] = SiteMatches(bwd, (bwd >= 0).astype(np.float32))

    def pair_02_only(res):
        obs = res.tracks.observed()
        return int(np.sum(obs[:, 0] & obs[:, 2] & ~obs[:, 1]))

    res = sample_tracks([ms], config(sfm__f_err_px=None, sfm__two_cycle_f_err_px=None))
    assert res.two_view[(0, 2)].num_inliers < 15
    assert res.stats["unverified_pairs"] == ["0-2"]
    assert res.stats["unverified_two_cycles_removed"] > 0
    assert pair_02_only(res) == 0
    assert (res.tracks.cycle_order == 3).sum() > 0
    everything = sample_tracks([ms], config(sfm__f_err_px=None, sfm__two_cycle_f_err_px=None,
                                            sampling__min_two_cycle_pair_inliers=0))
    assert everything.stats["unverified_pairs"] == []
    assert pair_02_only(everything) > 0
