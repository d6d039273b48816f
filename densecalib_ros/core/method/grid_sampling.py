"""The two grids of the track sampling (core.method.sampling; paper Alg. 1): stage 1 keeps one
random cycle per fine cell; stage 2 fills coarse cells, orders N down to 2, by score, with the
coverage rule and the budget (the sampling module's docstring says how)."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..types import Tracks
from .cycles import CycleSet


@dataclass
class CycleCandidates:
    """Cycles of one subset at one time step with their pixel positions and scores."""

    t: int
    cycles: CycleSet
    xy: np.ndarray  # float64 (M, n, 2) COLMAP px per camera of the subset
    score: np.ndarray  # float64 (M,)


def cell_ids(xy: np.ndarray, cell_px: float, image_size: tuple) -> np.ndarray:
    """Linear cell index of (M, 2) COLMAP px on a grid of cell_px cells over the image."""
    w, _ = image_size
    cols = int(np.ceil(w / cell_px))
    ij = np.floor(np.asarray(xy) / cell_px).astype(np.int64)
    ij = np.maximum(ij, 0)
    return ij[:, 1] * cols + np.minimum(ij[:, 0], cols - 1)


def _pick_per_cell(cells: np.ndarray, key: np.ndarray) -> np.ndarray:
    """Indices of the candidate with the largest key in each distinct cell (sorted by cell)."""
    if cells.size == 0:
        return np.zeros(0, np.int64)
    order = np.lexsort((-key, cells))
    first = np.ones(order.size, dtype=bool)
    first[1:] = cells[order][1:] != cells[order][:-1]
    return order[first]


def _selection_keys(score: np.ndarray, rng: np.random.Generator, probabilistic: bool,
                    scoring: bool) -> np.ndarray:
    """Keys whose per-cell argmax realises the stage-2 pick: Gumbel-max for a draw proportional to
    score (zero scores lose to any positive one, uniform among themselves), the score itself with
    a random tie-break for argmax, pure noise when scoring is off."""
    gumbel = rng.gumbel(size=score.shape)
    if not scoring:
        return gumbel
    if probabilistic:
        with np.errstate(divide="ignore"):
            return np.where(score > 0, np.log(np.where(score > 0, score, 1.0)), -1e6) + gumbel
    return score + 1e-9 * gumbel


def stage1_pick(cs: CycleSet, sites_xy: np.ndarray, cell_px: float, image_size: tuple,
            rng: np.random.Generator) -> CycleSet:
    cells = cell_ids(sites_xy[cs.sites[:, 0]], cell_px, image_size)
    keep = np.sort(_pick_per_cell(cells, rng.random(cells.size)))
    return CycleSet(cs.cameras, cs.sites[keep])


def stage2_tracks(candidates: dict, sizes: list, s_cfg, rng: np.random.Generator, num_cams: int,
            num_times: int) -> tuple[Tracks, dict]:
    budget = {int(k): int(v) for k, v in s_cfg.samples_per_order.items()}
    scoring = s_cfg.top_k > 0
    # selected[t][cameras] = (M, n, 2) xy of the kept tracks of that subset (for blocking).
    selected: list[dict] = [dict() for _ in range(num_times)]
    parts, halvings = [], {}
    for n in sorted(candidates, reverse=True):
        picked = []  # (t, cameras, xy (M, n, 2), score (M,))
        halvings[n] = 0
        for cand in candidates[n]:
            cams = cand.cycles.cameras
            ref = cams[0]
            blocked = [xy[:, other.index(ref)] for other, xy in selected[cand.t].items()
                       if len(other) > n and set(cams) <= set(other)]
            blocked_xy = np.concatenate(blocked) if blocked else np.zeros((0, 2))
            keys = _selection_keys(cand.score, rng, s_cfg.probabilistic_scoring, scoring)
            d = float(s_cfg.cell_size_px)
            w, h = sizes[ref]
            n_min = s_cfg.c_min * np.ceil(w / d) * np.ceil(h / d)
            chosen = np.zeros(len(cand.score), bool)
            for level in range(max(1, s_cfg.max_grid_iterations)):
                cells = cell_ids(cand.xy[:, 0], d, sizes[ref])
                filled = np.unique(np.concatenate([
                    cell_ids(blocked_xy, d, sizes[ref]), cells[chosen]]))
                free = ~chosen & ~np.isin(cells, filled)
                idx = np.flatnonzero(free)
                chosen[idx[_pick_per_cell(cells[idx], keys[idx])]] = True
                num_filled = filled.size + np.unique(cells[idx]).size
                if num_filled >= n_min or level + 1 == s_cfg.max_grid_iterations:
                    break
                d /= 2.0
                halvings[n] += 1
            if chosen.any():
                picked.append((cand.t, cams, cand.cycles.sites[chosen], cand.xy[chosen],
                               cand.score[chosen]))
        total = sum(len(p[3]) for p in picked)
        cap = budget.get(n, total)
        if total > cap:  # seeded uniform subset over all subsets and time steps
            keep_all = np.zeros(total, bool)
            keep_all[rng.choice(total, cap, replace=False)] = True
            offsets = np.cumsum([0] + [len(p[3]) for p in picked])
            picked = [(t, cams, s[keep_all[a:b]], xy[keep_all[a:b]], sc[keep_all[a:b]])
                      for (t, cams, s, xy, sc), a, b in zip(picked, offsets[:-1], offsets[1:])]
        for t, cams, _, xy, sc in picked:
            if len(sc) == 0:
                continue
            selected[t][cams] = xy
            out = np.full((len(sc), num_cams, 2), np.nan)
            out[:, list(cams)] = xy
            parts.append(Tracks(out, np.full(len(sc), n, np.int32), sc.astype(np.float64),
                                np.full(len(sc), t, np.int32)))
    return Tracks.concatenate(parts, num_cams), halvings
