"""n-cycle closure on site matches (paper Sec. 3.1) by vectorised integer index composition.

A 2-cycle i -> j -> i closes at site s of i when target_ji[target_ij[s]] == s. The paper's strict
rule for n > 2: an n-cycle counts only if it closes and all of its (n-1)-subcycles close
(recursively). For n = 3 the 2-subcycles are the three pairs; for n = 4 the 3-subcycles skip one
camera and so use the direct maps between non-adjacent cameras. Unrolled, the rule says that the
n sites are mutually consistent under all n(n-1) ordered pair maps of the n cameras. Two
consequences
used here:
- the result does not depend on the cyclic order: for cameras {a, b, c, d} the three distinct cyclic
  orders (and their rotations/reflections) close on exactly the same site tuples, so each camera
  subset gives one set of cycles, and a closed cycle starting at a site of its lowest camera is one
  track (no duplicates from rotations or reflections);
- n-cycles are the (n-1)-cycles of a subset extended by one camera e with every map to and from e
  consistent. Cycles are therefore built order by order, each step costing O(number of
  (n-1)-cycles * n): linear in the number of sites.
For detector matchers whose (j, i) map is the inverse of (i, j) (mutual matches) every matched site
pair is a closed 2-cycle; that is expected (their 3- and 4-cycles are still real tests).
"""
from __future__ import annotations

from dataclasses import dataclass
from itertools import combinations

import numpy as np

from ..types import SiteMatchSet


@dataclass
class CycleSet:
    """The closed cycles of one camera subset.

    cameras: sorted camera indices (length n = cycle order).
    sites: int64 (M, n), column k holds the site index (into SiteMatchSet.sites[cameras[k]]) of
      each of the M closed cycles; rows are unique.
    """

    cameras: tuple[int, ...]
    sites: np.ndarray

    @property
    def order(self) -> int:
        return len(self.cameras)

    def __len__(self) -> int:
        return int(self.sites.shape[0])


def _mutual(match_set: SiteMatchSet, i: int, j: int) -> CycleSet:
    fwd = match_set.pairs[(i, j)].target
    bwd = match_set.pairs[(j, i)].target
    s_i = np.flatnonzero(fwd >= 0)
    s_j = fwd[s_i].astype(np.int64)
    keep = bwd[s_j] == s_i
    return CycleSet((i, j), np.stack([s_i[keep], s_j[keep]], axis=1).astype(np.int64))


def _extend(match_set: SiteMatchSet, base: CycleSet, e: int) -> CycleSet:
    """Extend the cycles of `base` (cameras all < e) by camera e: keep those whose site in e,
    reached from the first camera, is consistent with every camera of the subset both ways."""
    cams = base.cameras
    sites = base.sites
    s_e = match_set.pairs[(cams[0], e)].target[sites[:, 0]].astype(np.int64)
    keep = s_e >= 0
    for k, c in enumerate(cams):
        idx = np.flatnonzero(keep)
        s_c, s_ce = sites[idx, k], s_e[idx]
        ok = (match_set.pairs[(c, e)].target[s_c] == s_ce) & (
            match_set.pairs[(e, c)].target[s_ce] == s_c)
        keep[idx[~ok]] = False
    return CycleSet(cams + (e,), np.concatenate([sites[keep], s_e[keep, None]], axis=1))


def close_cycles(match_set: SiteMatchSet, max_order: int = 4) -> dict[int, list[CycleSet]]:
    """All closed cycles of order 2..max_order under the strict rule.

    Returns {n: [CycleSet per camera subset of size n that has at least one closed cycle]}, with
    subsets in lexicographic order. A subset needs every ordered pair map between its cameras;
    subsets with a missing pair have no cycles.
    """
    if max_order < 2:
        raise ValueError(f"max_order must be >= 2, got {max_order}")
    num_cams = len(match_set.sites)
    have = set(match_set.pairs)
    out: dict[int, list[CycleSet]] = {n: [] for n in range(2, max_order + 1)}
    by_subset: dict[tuple[int, ...], CycleSet] = {}
    for i, j in combinations(range(num_cams), 2):
        if (i, j) in have and (j, i) in have:
            cs = _mutual(match_set, i, j)
            if len(cs):
                by_subset[cs.cameras] = cs
                out[2].append(cs)
    for n in range(3, max_order + 1):
        for subset in combinations(range(num_cams), n):
            base = by_subset.get(subset[:-1])
            e = subset[-1]
            if base is None or any((c, e) not in have or (e, c) not in have for c in subset[:-1]):
                continue
            cs = _extend(match_set, base, e)
            if len(cs):
                by_subset[subset] = cs
                out[n].append(cs)
    return out
