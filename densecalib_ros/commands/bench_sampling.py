"""`densecalib bench-sampling`: matcher + cycle-sampling quality per backend on generated rigs.

For each generated 6-camera rig (pinhole RADIAL and fisheye OPENCV_FISHEYE, 1024x768) and each
matcher backend it reports:
- raw inliers: fraction of the matcher's raw matches (every ordered pair; the target at its
  refined sub-pixel position where the matcher gives one) within 2 px of the true correspondence
  (the pixel's surface point, from the analytic scene, projected into the other camera;
  occluded/out-of-view counts as wrong);
- track inliers: the same for the sampled tracks' observations (each observation against the
  track's first observation);
- coverage: mean over cameras of the fraction of 10x10 image cells holding a track observation;
- the track-length histogram (cycle orders 2/3/4), and the time per 6-camera set (matching and
  sampling). Writes OUT/bench_sampling.json and prints a table.

With `--angles 20 35 50 65 80` it measures instead how the matches hold up as the viewpoint
changes: per angle, lens and seed a 3-camera rig whose neighbours stand that far apart on their
arc (3 cameras span at least 45 deg, so the smallest step is 22.5), and for its two neighbouring
pairs the angle between their optical axes, the raw matches per pair, their fraction within 2 px
of the true correspondence, the correct ones per pair, and the sampled tracks' inlier fraction
over the rig; written to OUT/bench_sampling_angles.json.
"""
from __future__ import annotations

import argparse
import json
import logging
import os
import time

import numpy as np

from ..core.errors import CalibrationError

log = logging.getLogger("densecalib.bench_sampling")

INLIER_PX = 2.0
COVERAGE_GRID = 10


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--quick", action="store_true",
                        help="one rig per camera type (default: two seeds each)")
    parser.add_argument("--matchers", default="sift,xfeat-lighterglue",
                        help="comma-separated backends (see `densecalib calibrate --help`)")
    parser.add_argument("--out", default=None, help="folder for bench_sampling.json")
    parser.add_argument("--cameras", type=int, default=6)
    parser.add_argument("--width", type=int, default=1024)
    parser.add_argument("--height", type=int, default=768)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--angles", type=float, nargs="+", default=None, metavar="DEG",
                        help="measure matches against the viewpoint change instead: 3-camera "
                             "rigs with neighbours this many degrees apart (e.g. 20 35 50 65 80)")


def _true_inliers(rig, t: int, a: int, b: int, xy_a: np.ndarray, xy_b: np.ndarray) -> np.ndarray:
    if len(xy_a) == 0:
        return np.zeros(0, bool)
    true_b, vis = rig.transfer(t, a, b, xy_a)
    err = np.linalg.norm(true_b - xy_b, axis=1)
    return vis & (err <= INLIER_PX)


def _raw_inliers(rig, t: int, ms) -> tuple[int, int]:
    """Inlier count and total over the raw matches of every ordered pair, each judged at the
    position the tracks use: the refined target position where the matcher gives one."""
    from ..core.method.sampling import refined_targets_px

    good = total = 0
    for (i, j), m in ms.pairs.items():
        s = np.flatnonzero(m.target >= 0)
        ok = _true_inliers(rig, t, i, j, ms.sites[i][s], refined_targets_px(ms, i, j, s, m.target[s]))
        good += int(ok.sum())
        total += len(s)
    return good, total


def _track_inliers(rig, tracks) -> tuple[int, int]:
    obs = tracks.observed()
    good = total = 0
    for t in np.unique(tracks.time_index):
        sel = tracks.time_index == t
        first = np.argmax(obs[sel], axis=1)
        for a in range(tracks.num_cameras):
            rows = np.flatnonzero(sel)[first == a]
            for b in range(tracks.num_cameras):
                if b == a:
                    continue
                r = rows[obs[rows, b]]
                ok = _true_inliers(rig, int(t), a, b, tracks.xy_px[r, a], tracks.xy_px[r, b])
                good += int(ok.sum())
                total += len(r)
    return good, total


def _coverage(tracks, sizes) -> float:
    cov = []
    for c, (w, h) in enumerate(sizes):
        xy = tracks.xy_px[tracks.observed()[:, c], c]
        cells = set(map(tuple, np.floor(xy / [w / COVERAGE_GRID, h / COVERAGE_GRID]).astype(int)
                        .clip(0, COVERAGE_GRID - 1).tolist()))
        cov.append(len(cells) / COVERAGE_GRID ** 2)
    return float(np.mean(cov))


def _axis_angle_deg(rig, a: int, b: int) -> float:
    """Angle between two generated cameras' optical axes (deg)."""
    axes = [rig.cam_from_world[c][2, :3] for c in (a, b)]  # the camera z axis in world
    return float(np.degrees(np.arccos(np.clip(np.dot(*axes), -1.0, 1.0))))


def _angle_rows(args, loaded: dict, seeds: list) -> list[dict]:
    """The viewpoint sweep (module docstring): one row per angle, lens, seed and matcher."""
    from ..core.config import make_config
    from ..core.method.sampling import refined_targets_px, sample_tracks
    from ..core.synthetic import RigSpec, generate_rig

    rows = []
    for model, preset in (("RADIAL", "regular"), ("OPENCV_FISHEYE", "fisheye")):
        for angle in args.angles:
            for seed in seeds:
                rig = generate_rig(RigSpec(num_cameras=3, camera_model=model, width=args.width,
                                           height=args.height, seed=seed, gap_deg=angle,
                                           max_arc_deg=360.0))
                neighbours = [(0, 1), (1, 2)]
                for name, matcher in loaded.items():
                    t0 = time.perf_counter()
                    ms = matcher.match(rig.images[0])
                    t_match = time.perf_counter() - t0
                    good = total = 0
                    for i, j in neighbours:
                        m = ms.pairs[(i, j)]
                        src = np.flatnonzero(m.target >= 0)
                        ok = _true_inliers(rig, 0, i, j, ms.sites[i][src],
                                           refined_targets_px(ms, i, j, src, m.target[src]))
                        good, total = good + int(ok.sum()), total + len(src)
                    try:
                        res = sample_tracks([ms], make_config(preset, "incremental",
                                                              matcher=name))
                        trk_good, trk_total = _track_inliers(rig, res.tracks)
                    except CalibrationError as exc:  # too few matches to sample from
                        log.info("angle %g, %s, seed %d, %s: no tracks (%s)", angle, model,
                                 seed, name, exc)
                        trk_good = trk_total = 0
                    rows.append({
                        "model": model, "angle_deg": angle, "seed": seed, "matcher": name,
                        "axis_angle_deg": float(np.mean([_axis_angle_deg(rig, i, j)
                                                         for i, j in neighbours])),
                        "raw_matches_per_pair": total / len(neighbours),
                        "raw_inlier_frac": good / max(total, 1),
                        "correct_per_pair": good / len(neighbours),
                        "track_inlier_frac": trk_good / max(trk_total, 1) if trk_total else None,
                        "time_match_s": t_match})
                    log.info("%s", json.dumps(rows[-1]))
    return rows


def _print_angle_rows(rows: list[dict]) -> None:
    print(f"{'model':<15}{'step':>5}{'seed':>5} {'matcher':<18}{'axes deg':>9}{'raw/pair':>9}"
          f"{'raw_in':>8}{'right/pair':>11}{'trk_in':>8}{'match_s':>9}")
    for r in rows:
        trk = "-" if r["track_inlier_frac"] is None else f"{r['track_inlier_frac']:.3f}"
        print(f"{r['model']:<15}{r['angle_deg']:>5g}{r['seed']:>5} {r['matcher']:<18}"
              f"{r['axis_angle_deg']:>9.1f}{r['raw_matches_per_pair']:>9.0f}"
              f"{r['raw_inlier_frac']:>8.3f}{r['correct_per_pair']:>11.0f}{trk:>8}"
              f"{r['time_match_s']:>9.1f}")


def run(args: argparse.Namespace) -> int:
    from ..core.config import make_config
    from ..core.method.matching import create_matcher
    from ..core.method.sampling import sample_tracks
    from ..core.synthetic import RigSpec, generate_rig

    matchers = [m.strip() for m in args.matchers.split(",") if m.strip()]
    seeds = [args.seed] if args.quick else [args.seed, args.seed + 1]
    rows = []
    try:
        loaded = {}
        for name in matchers:
            loaded[name] = create_matcher(name, max_image_side_px=max(args.width, args.height))
            loaded[name].load()
        if args.angles:
            rows = _angle_rows(args, loaded, seeds)
            _print_angle_rows(rows)
            if args.out:
                os.makedirs(args.out, exist_ok=True)
                with open(os.path.join(args.out, "bench_sampling_angles.json"), "w") as fh:
                    json.dump(rows, fh, indent=1)
            return 0
        for model, preset in (("RADIAL", "regular"), ("OPENCV_FISHEYE", "fisheye")):
            for seed in seeds:
                t0 = time.perf_counter()
                rig = generate_rig(RigSpec(num_cameras=args.cameras, camera_model=model,
                                           width=args.width, height=args.height, seed=seed))
                log.info("rig %s seed %d rendered in %.1f s", model, seed, time.perf_counter() - t0)
                sizes = [(c.width, c.height) for c in rig.cameras]
                for name, matcher in loaded.items():
                    t0 = time.perf_counter()
                    ms = matcher.match(rig.images[0])
                    t_match = time.perf_counter() - t0
                    t0 = time.perf_counter()
                    res = sample_tracks([ms], make_config(preset, "incremental", matcher=name))
                    t_sample = time.perf_counter() - t0
                    raw_good, raw_total = _raw_inliers(rig, 0, ms)
                    trk_good, trk_total = _track_inliers(rig, res.tracks)
                    true_f = np.array([c.params[0] for c in rig.cameras])
                    row = {
                        "model": model, "seed": seed, "matcher": name,
                        "raw_matches": raw_total,
                        "raw_inlier_frac": raw_good / max(raw_total, 1),
                        "track_obs_pairs": trk_total,
                        "track_inlier_frac": trk_good / max(trk_total, 1),
                        "tracks": res.tracks.num_tracks,
                        "tracks_per_order": res.stats["tracks_per_order"],
                        "coverage": _coverage(res.tracks, sizes),
                        "halvings": res.stats["halvings"],
                        "f_err_removed": res.stats["f_err_removed"],
                        "focal_rel_err_median": float(np.median(np.abs(res.focal_px / true_f - 1))),
                        "time_match_s": t_match, "time_sample_s": t_sample,
                    }
                    rows.append(row)
                    log.info("%s", json.dumps(row))
    except CalibrationError as exc:
        log.error("%s", exc)
        return 2
    header = (f"{'model':<15}{'seed':>5} {'matcher':<18}{'raw':>7}{'raw_in':>8}{'obs':>7}"
              f"{'trk_in':>8}{'cover':>7}  {'len 2/3/4':<14}{'f_rel':>7}{'match_s':>9}{'samp_s':>8}")
    print(header)
    for r in rows:
        o = r["tracks_per_order"]
        hist = f"{o.get(2, 0)}/{o.get(3, 0)}/{o.get(4, 0)}"
        print(f"{r['model']:<15}{r['seed']:>5} {r['matcher']:<18}{r['raw_matches']:>7}"
              f"{r['raw_inlier_frac']:>8.3f}{r['track_obs_pairs']:>7}{r['track_inlier_frac']:>8.3f}"
              f"{r['coverage']:>7.2f}  {hist:<14}{r['focal_rel_err_median']:>7.3f}"
              f"{r['time_match_s']:>9.1f}{r['time_sample_s']:>8.2f}")
    if args.out:
        os.makedirs(args.out, exist_ok=True)
        with open(os.path.join(args.out, "bench_sampling.json"), "w") as fh:
            json.dump(rows, fh, indent=1)
    return 0
