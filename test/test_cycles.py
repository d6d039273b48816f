"""n-cycle closure on fabricated site matches with exact synthetic correspondences."""

import numpy as np

from densecalib_ros.core.method.cycles import close_cycles
from densecalib_ros.core.types import SiteMatches, SiteMatchSet


def look_at(centre, target, rng, jitter=0.3):
    z = np.asarray(target, float) - centre + rng.normal(scale=jitter, size=3)
    z /= np.linalg.norm(z)
    x = np.cross([0, 1.0, 0], z)
    x /= np.linalg.norm(x)
    return np.stack([x, np.cross(z, x), z])


def make_scene(num_cams=4, num_points=400, seed=0, size=(640, 480), focals=None, box=None,
               arc_deg=50.0):
    """Cameras on an arc around a box of random points. Returns dict with K, R, t per camera, the
    points X (P, 3) and per camera the (P, 2) projections and (P,) visibility."""
    rng = np.random.default_rng(seed)
    w, h = size
    focals = rng.uniform(0.8, 1.3, num_cams) * w if focals is None else np.asarray(focals, float)
    lo, hi = box if box is not None else ([-3, -2, 6], [3, 2, 10])
    X = rng.uniform(lo, hi, size=(num_points, 3))
    Ks, Rs, ts, xy, vis = [], [], [], [], []
    for c in range(num_cams):
        yaw = np.radians(-arc_deg / 2 + arc_deg * c / max(num_cams - 1, 1))
        centre = np.array([8 * np.sin(yaw), rng.uniform(-0.3, 0.3), 8 - 8 * np.cos(yaw)])
        R = look_at(centre, [0, 0, 8], rng)
        t = -R @ centre
        K = np.array([[focals[c], 0, w / 2], [0, focals[c], h / 2], [0, 0, 1]])
        Xc = X @ R.T + t
        uv = Xc @ K.T
        p = uv[:, :2] / uv[:, 2:3]
        Ks.append(K), Rs.append(R), ts.append(t), xy.append(p)
        vis.append((Xc[:, 2] > 0) & (p[:, 0] > 0) & (p[:, 0] < w) & (p[:, 1] > 0) & (p[:, 1] < h))
    return dict(K=Ks, R=Rs, t=ts, X=X, xy=xy, vis=vis, size=size, focals=focals)


def match_set_from_scene(scene, extra_vis=None):
    """Exact site matches: camera c's sites are the projections of the points it sees, in point
    order; (i, j) maps a site to the site of the same point. Returns (SiteMatchSet, point_of_site
    per camera, site_of_point per camera (-1 = unseen))."""
    num_cams = len(scene["xy"])
    vis = [scene["vis"][c] & (extra_vis[c] if extra_vis is not None else True)
           for c in range(num_cams)]
    point_of_site = [np.flatnonzero(v) for v in vis]
    site_of_point = []
    for c in range(num_cams):
        m = np.full(len(scene["X"]), -1, np.int64)
        m[point_of_site[c]] = np.arange(len(point_of_site[c]))
        site_of_point.append(m)
    sites = [scene["xy"][c][point_of_site[c]] for c in range(num_cams)]
    pairs = {}
    for i in range(num_cams):
        for j in range(num_cams):
            if i != j:
                target = site_of_point[j][point_of_site[i]].astype(np.int32)
                pairs[(i, j)] = SiteMatches(target, (target >= 0).astype(np.float32))
    ms = SiteMatchSet(sites, pairs, [scene["size"]] * num_cams)
    return ms, point_of_site, site_of_point


def test_exact_matches_close_at_every_order():
    scene = make_scene(num_cams=4, num_points=300, seed=1)
    ms, pos, sop = match_set_from_scene(scene)
    cycles = close_cycles(ms, 4)
    all_vis = np.all(scene["vis"], axis=0)
    assert len(cycles[4]) == 1 and cycles[4][0].cameras == (0, 1, 2, 3)
    assert len(cycles[4][0]) == all_vis.sum() > 100
    assert len(cycles[3]) == 4 and len(cycles[2]) == 6
    for cs in cycles[2] + cycles[3] + cycles[4]:
        points = [pos[c][cs.sites[:, k]] for k, c in enumerate(cs.cameras)]
        for p in points[1:]:
            np.testing.assert_array_equal(p, points[0])  # every column is the same 3D point
        assert len(cs) == np.all([scene["vis"][c] for c in cs.cameras], axis=0).sum()


def _point_seen_by_all(scene, sop, k=0):
    return np.flatnonzero(np.all([s >= 0 for s in sop], axis=0))[k]


def test_inconsistent_match_rejected_in_3_and_4_cycles():
    scene = make_scene(num_cams=4, num_points=300, seed=2)
    ms, pos, sop = match_set_from_scene(scene)
    p = _point_seen_by_all(scene, sop)
    q = _point_seen_by_all(scene, sop, 1)
    # Dense-matcher style error: 1 -> 2 maps p to q's site, 2 -> 1 is still right.
    ms.pairs[(1, 2)].target[sop[1][p]] = sop[2][q]
    cycles = close_cycles(ms, 4)
    for n in (3, 4):
        for cs in cycles[n]:
            if 1 in cs.cameras and 2 in cs.cameras:
                col = cs.cameras.index(1)
                assert sop[1][p] not in cs.sites[:, col]
    # ... while p still forms the 3-cycle that avoids the broken pair.
    cs013 = next(cs for cs in cycles[3] if cs.cameras == (0, 1, 3))
    assert sop[0][p] in cs013.sites[:, 0]
    # The 2-cycle 1<->2 at p is open too.
    cs12 = next(cs for cs in cycles[2] if cs.cameras == (1, 2))
    assert sop[1][p] not in cs12.sites[:, 0]


def test_4_cycle_rejected_when_a_3_subcycle_fails():
    """The chain 0->1->2->3->0 closes exactly, but the direct maps 0<->2 agree on a wrong site, so
    the 3-subcycle 0-1-2 (skipping 3) fails and the strict rule rejects the 4-cycle."""
    scene = make_scene(num_cams=4, num_points=300, seed=3)
    ms, pos, sop = match_set_from_scene(scene)
    p = _point_seen_by_all(scene, sop)
    q = _point_seen_by_all(scene, sop, 1)
    ms.pairs[(0, 2)].target[sop[0][p]] = sop[2][q]
    ms.pairs[(2, 0)].target[sop[2][q]] = sop[0][p]  # mutual, so the 2-cycle 0<->2 closes (wrongly)
    chain = sop[0][p]
    for a, b in [(0, 1), (1, 2), (2, 3), (3, 0)]:
        chain = ms.pairs[(a, b)].target[chain]
    assert chain == sop[0][p]  # the 4-cycle itself closes
    cycles = close_cycles(ms, 4)
    assert sop[0][p] not in cycles[4][0].sites[:, 0]
    assert len(cycles[4][0]) == np.all([s >= 0 for s in sop], axis=0).sum() - 2  # p and q
    cs02 = next(cs for cs in cycles[2] if cs.cameras == (0, 2))
    assert [sop[0][p], sop[2][q]] in cs02.sites.tolist()


def test_missing_pair_and_unmatched_sites():
    scene = make_scene(num_cams=3, num_points=200, seed=4)
    ms, _, _ = match_set_from_scene(scene)
    del ms.pairs[(2, 0)]
    cycles = close_cycles(ms, 4)
    assert [cs.cameras for cs in cycles[2]] == [(0, 1), (1, 2)]
    assert cycles[3] == [] and cycles[4] == []


def test_large_consistent_permutations_close_completely():
    """Every site of a consistent 4-camera permutation closes in 2-, 3- and 4-cycles at 400k
    sites (the vectorised composition's scale; its speed is measured by `densecalib
    bench-sampling`, not asserted here: timed assertions fail on a loaded machine)."""
    rng = np.random.default_rng(0)
    n_sites = 400_000
    perm = [np.arange(n_sites)] + [rng.permutation(n_sites) for _ in range(3)]
    inv = [np.argsort(p) for p in perm]
    pairs = {(i, j): SiteMatches(perm[j][inv[i]].astype(np.int32), np.ones(n_sites, np.float32))
             for i in range(4) for j in range(4) if i != j}
    cycles = close_cycles(SiteMatchSet([np.zeros((n_sites, 2))] * 4, pairs, [(640, 480)] * 4), 4)
    assert len(cycles[4][0]) == n_sites
    assert sum(len(cs) for cs in cycles[3]) == 4 * n_sites  # the four camera triples
    sites = cycles[4][0].sites
    np.testing.assert_array_equal(sites[:, 1], perm[cycles[4][0].cameras[1]][sites[:, 0]])
