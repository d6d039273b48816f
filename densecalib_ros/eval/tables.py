"""The bench's tables: one per scene, the summary over scenes, the check of the sigmas."""
from __future__ import annotations

from typing import Optional

import numpy as np


def _fmt(value, spec: str, missing: str = "-") -> str:
    if value is None or (isinstance(value, float) and not np.isfinite(value)):
        return missing
    return format(value, spec)


_HEADER = (f"{'method':<28}{'reg':>7}{'AUC@3':>8}{'AUC@30':>8}{'rot deg':>8}{'focal%':>8}"
           f"{'pp px':>7}{'proj px':>9}{'time s':>8}{'xCOLMAP':>8}{'peak MiB':>10}  status")


def colmap_time_ratio(entry: dict, record: dict) -> Optional[float]:
    """A method's wall time over COLMAP's on the same scene; None where COLMAP did not run."""
    colmap = next((r for r in entry["results"] if r["method"] == "colmap"), None)
    if colmap is None or not colmap.get("runtime_s") or record.get("runtime_s") is None:
        return None
    return record["runtime_s"] / colmap["runtime_s"]


def format_scene_table(entry: dict) -> str:
    """One scene's results as a fixed-width table."""
    lines = [f"== {entry['scene']} ({entry['lens']}, {entry['num_cameras']} cameras, "
             f"{entry['image_size'][0]}x{entry['image_size'][1]})", _HEADER]
    for r in entry["results"]:
        m = r["metrics"]
        focal = m["median_focal_err"] * 100 if np.isfinite(m["median_focal_err"]) else None
        status = r["status"] if r["status"] == "ok" else f"{r['status']}: {r['message'][:60]}"
        lines.append(f"{r['method']:<28}{m['num_registered']:>3}/{m['num_cameras']:<3}"
                     f"{m['auc3']:>8.1f}{m['auc30']:>8.1f}"
                     f"{_fmt(m.get('median_rot_err_deg'), '8.3f'):>8}{_fmt(focal, '8.2f'):>8}"
                     f"{_fmt(m.get('median_pp_err_px'), '7.1f'):>7}"
                     f"{_fmt(m['median_proj_err_px'], '9.2f'):>9}{_fmt(r['runtime_s'], '8.1f'):>8}"
                     f"{_fmt(colmap_time_ratio(entry, r), '8.2f'):>8}"
                     f"{_fmt(r['peak_rss_mib'], '10.0f'):>10}  {status}")
    for r in entry["results"]:
        for warning in r.get("warnings", []):
            lines.append(f"  {r['method']} warned: {_shorten(warning, 100)}")
    for r in entry["results"]:
        if any(r.get("error_sigma_ratios", {}).values()):
            lines.append(f"  {r['method']} |error| / own sigma: "
                         f"{_error_sigma_parts(r['error_sigma_ratios'])}")
    return "\n".join(lines)


def _error_sigma_parts(ratios: dict) -> str:
    """'focal median 0.70, max 1.80 (n=8); ...' of one scene's error_sigma_ratios lists."""
    return "; ".join(f"{kind.replace('_', ' ')} median {np.median(v):.2f}, max {np.max(v):.2f} "
                     f"(n={len(v)})" for kind, v in ratios.items() if len(v))


def _shorten(text: str, width: int) -> str:
    """The first `width` characters of a one-line text, '...' where cut."""
    return text if len(text) <= width else text[:width - 3] + "..."


def summarize(scenes: list[dict]) -> list[dict]:
    """Per (lens, method): scenes, registered/total cameras, mean AUC@3/@30 (failures count as 0),
    median AUC@3 over scenes,
    median of the per-scene median focal error and projection error (over scenes where the method
    registered cameras), median runtime and median ratio to COLMAP's runtime on the same scene,
    the number of scenes that did not run ok and of those whose result carried a warning."""
    groups: dict[tuple[str, str], list[dict]] = {}
    ratios: dict[tuple[str, str], list[float]] = {}
    for entry in scenes:
        for r in entry["results"]:
            groups.setdefault((entry["lens"], r["method"]), []).append(r)
            ratio = colmap_time_ratio(entry, r)
            if ratio is not None:
                ratios.setdefault((entry["lens"], r["method"]), []).append(ratio)
    out = []
    for (lens, method), records in groups.items():
        ms = [r["metrics"] for r in records]
        focal = [m["median_focal_err"] for m in ms if np.isfinite(m["median_focal_err"])]
        proj = [m["median_proj_err_px"] for m in ms if np.isfinite(m["median_proj_err_px"])]
        # A scene's median pair rotation error (inf where a camera failed: its pairs count).
        rot = [m.get("median_rot_err_deg", float("nan")) for m in ms]
        times = [r["runtime_s"] for r in records if r["status"] == "ok"]
        out.append(dict(
            lens=lens, method=method, num_scenes=len(records),
            registered=sum(m["num_registered"] for m in ms), cameras=sum(m["num_cameras"] for m in ms),
            mean_auc3=float(np.mean([m["auc3"] for m in ms])),
            mean_auc30=float(np.mean([m["auc30"] for m in ms])),
            median_auc3=float(np.median([m["auc3"] for m in ms])),
            median_rot_err_deg=float(np.median(rot)) if rot else float("nan"),
            median_focal_err=float(np.median(focal)) if focal else float("nan"),
            median_proj_err_px=float(np.median(proj)) if proj else float("nan"),
            median_runtime_s=float(np.median(times)) if times else float("nan"),
            median_colmap_time_ratio=(float(np.median(ratios[lens, method]))
                                      if ratios.get((lens, method)) else float("nan")),
            not_ok=sum(r["status"] != "ok" for r in records),
            warned=sum(bool(r.get("warnings")) for r in records)))
    return out


# The uncertainty check's line for the scenes whose reference is itself an SfM estimate: their
# errors are partly the reference's, so they are pooled apart from the scenes with ground truth
# or a target-based reference.
SFM_REFERENCE = " (SfM references)"


def summarize_error_sigma_ratios(scenes: list[dict]) -> dict:
    """Per our method: quantiles over all cameras of actual error / estimated sigma, focal and
    projection (core.method.uncertainty.error_sigma_ratios); a sigma that is only a lower bound
    shows as ratios well above 1. Scenes whose reference is an estimate under the method's name
    + SFM_REFERENCE."""
    pooled: dict[str, dict[str, list]] = {}
    for entry in scenes:
        for r in entry["results"]:
            key = r["method"] + (SFM_REFERENCE if entry.get("reference_is_estimate") else "")
            for kind, ratios in r.get("error_sigma_ratios", {}).items():
                pooled.setdefault(key, {}).setdefault(kind, []).extend(ratios)
    return {method: {kind: dict(n=len(v), median=float(np.median(v)),
                                p90=float(np.percentile(v, 90)), max=float(np.max(v)))
                     for kind, v in kinds.items() if v}
            for method, kinds in pooled.items()}


def format_error_sigma_ratios(check: dict) -> str:
    lines = ["== uncertainty check: actual error / its estimated sigma over cameras (focal length; "
             "principal point: larger axis error / principal_point_std_px; projection: mean "
             "projection-map error / projection_std_px; rotation: angle of the camera's rotation "
             "relative to the reference camera against the truth's / rotation_std_deg)"]
    for method, kinds in check.items():
        parts = [f"{kind} median {q['median']:.2f}, 90% {q['p90']:.2f}, max {q['max']:.2f} "
                 f"(n={q['n']})" for kind, q in kinds.items()]
        lines.append(f"{method:<27} " + ("; ".join(parts) or "no estimated intrinsics"))
    return "\n".join(lines)


def format_summary(summary: list[dict]) -> str:
    lines = ["== summary (mean AUC over scenes, failures = 0; med@3 = median AUC@3 over scenes; "
             "rot deg, focal, proj: medians of per-scene medians; rot deg: pair rotation error; "
             "xCOLMAP: median over scenes of wall time / COLMAP's on the same images)",
             f"{'lens':<9}{'method':<28}{'scenes':>7}{'reg':>10}{'AUC@3':>8}{'med@3':>7}{'AUC@30':>8}"
             f"{'rot deg':>8}{'focal%':>8}{'proj px':>9}{'time s':>8}{'xCOLMAP':>8}{'not ok':>8}"
             f"{'warned':>8}"]
    for s in summary:
        focal = s["median_focal_err"] * 100 if np.isfinite(s["median_focal_err"]) else None
        lines.append(f"{s['lens']:<9}{s['method']:<28}{s['num_scenes']:>7}"
                     f"{s['registered']:>5}/{s['cameras']:<4}{s['mean_auc3']:>8.1f}"
                     f"{s['median_auc3']:>7.1f}{s['mean_auc30']:>8.1f}"
                     f"{_fmt(s.get('median_rot_err_deg'), '8.3f'):>8}{_fmt(focal, '8.2f'):>8}"
                     f"{_fmt(s['median_proj_err_px'], '9.2f'):>9}"
                     f"{_fmt(s['median_runtime_s'], '8.1f'):>8}"
                     f"{_fmt(s.get('median_colmap_time_ratio'), '8.2f'):>8}{s['not_ok']:>8}"
                     f"{s.get('warned', 0):>8}")
    return "\n".join(lines)


def rotation_against_colmap(scenes: list[dict]) -> dict:
    """Per our method (the records named densecalib-*): on how many scenes it and COLMAP both
    registered every camera, and those of them where its median pair rotation error is larger
    than COLMAP's (scene, both errors in deg, whether the reference is an SfM estimate: the fox's
    is COLMAP's own solution on more frames, which COLMAP on a few of them agrees with by
    construction). Issue 82's promise: no scene worse than COLMAP where both place every camera."""
    def placed_all(record: Optional[dict]) -> bool:
        metrics = (record or {}).get("metrics") or {}
        return (record is not None and record["status"] == "ok"
                and metrics.get("num_registered") == metrics.get("num_cameras")
                and metrics.get("median_rot_err_deg") is not None
                and np.isfinite(metrics["median_rot_err_deg"]))

    out: dict[str, dict] = {}
    for entry in scenes:
        by_method = {r["method"]: r for r in entry["results"]}
        colmap = by_method.get("colmap")
        if not placed_all(colmap):
            continue
        for method, record in by_method.items():
            if not method.startswith("densecalib") or not placed_all(record):
                continue
            check = out.setdefault(method, dict(compared=0, worse=[]))
            check["compared"] += 1
            ours = record["metrics"]["median_rot_err_deg"]
            theirs = colmap["metrics"]["median_rot_err_deg"]
            if ours > theirs:
                check["worse"].append(dict(scene=entry["scene"], ours_deg=ours,
                                           colmap_deg=theirs,
                                           sfm_reference=bool(entry.get("reference_is_estimate"))))
    return out


def format_rotation_against_colmap(check: dict) -> str:
    lines = ["== rotation against COLMAP on the scenes where both registered every camera (median "
             "pair rotation error; issue 82: no worse on any)"]
    for method, c in check.items():
        worse = "; ".join(f"{w['scene']} {w['ours_deg']:.3f} against {w['colmap_deg']:.3f} deg"
                          + (" (reference: an SfM estimate)" if w["sfm_reference"] else "")
                          for w in c["worse"])
        lines.append(f"{method:<27} no worse on {c['compared'] - len(c['worse'])} of "
                     f"{c['compared']}" + (f"; worse on {worse}" if worse else ""))
    return "\n".join(lines)


# Issue 84's bounds on our time against COLMAP's on the same images: the median ratio over the
# rigs of MEDIAN_CAMERAS cameras (at most 1), and no rig of at most TAIL_MAX_CAMERAS cameras and
# TAIL_MAX_SIDE_PX beyond TAIL_RATIO times COLMAP's time or TAIL_S, whichever is larger.
MEDIAN_CAMERAS = (6, 10)
TAIL_MAX_CAMERAS = 10
TAIL_MAX_SIDE_PX = 1536
TAIL_RATIO = 3.0
TAIL_S = 60.0


def time_against_colmap(scenes: list[dict]) -> dict:
    """Per our method (the records named densecalib-*) on the scenes COLMAP ran on: the median of
    its time over COLMAP's over the rigs of MEDIAN_CAMERAS cameras (median_ratio, None without
    such a rig; median_rigs: how many), how many rigs the tail bound covers (timed) and those
    beyond it (scene, our and COLMAP's seconds, the bound)."""
    out: dict[str, dict] = {}
    for entry in scenes:
        for record in entry["results"]:
            ratio = colmap_time_ratio(entry, record)
            if not record["method"].startswith("densecalib") or ratio is None:
                continue
            check = out.setdefault(record["method"], dict(ratios=[], timed=0, beyond=[]))
            cameras = entry.get("num_cameras", 0)
            if MEDIAN_CAMERAS[0] <= cameras <= MEDIAN_CAMERAS[1]:
                check["ratios"].append(ratio)
            long_side_px = max(entry.get("image_size") or [0])
            if cameras > TAIL_MAX_CAMERAS or long_side_px > TAIL_MAX_SIDE_PX:
                continue
            check["timed"] += 1
            ours_s = record["runtime_s"]
            colmap_s = ours_s / ratio
            bound_s = max(TAIL_RATIO * colmap_s, TAIL_S)
            if ours_s > bound_s:
                check["beyond"].append(dict(scene=entry["scene"], ours_s=ours_s,
                                            colmap_s=colmap_s, bound_s=bound_s))
    for check in out.values():
        ratios = check.pop("ratios")
        check["median_rigs"] = len(ratios)
        check["median_ratio"] = float(np.median(ratios)) if ratios else None
    return out


def format_time_against_colmap(check: dict) -> str:
    lines = [f"== time against COLMAP's on the same images (issue 84: median at most 1.0 over the "
             f"rigs of {MEDIAN_CAMERAS[0]}-{MEDIAN_CAMERAS[1]} cameras; none of at most "
             f"{TAIL_MAX_CAMERAS} cameras and {TAIL_MAX_SIDE_PX} px beyond {TAIL_RATIO:g}x "
             f"COLMAP's time or {TAIL_S:g} s, whichever is larger)"]
    for method, c in check.items():
        beyond = "; ".join(f"{b['scene']} {b['ours_s']:.1f} s (COLMAP {b['colmap_s']:.1f} s)"
                           for b in c["beyond"])
        lines.append(f"{method:<27} median {_fmt(c['median_ratio'], '.2f')}x over "
                     f"{c['median_rigs']} rigs; {c['timed'] - len(c['beyond'])} of {c['timed']} "
                     "within the bound" + (f"; beyond it: {beyond}" if beyond else ""))
    return "\n".join(lines)


# Issue 81's bounds on the generated rigs users build (FEW_CAMERAS cameras filmed over several
# frame sets, with motion): each reaches AUC@3 of FEW_AUC3 or is refused, none is wrong without
# a warning, and one of FEW_TIMED (cameras, frame sets, image size) is calibrated within
# FEW_TIME_S.
FEW_CAMERAS = (3, 4)
FEW_AUC3 = 90.0
FEW_TIMED = (4, 20, (1280, 720))
FEW_TIME_S = 120.0


def few_rigs_check(scenes: list[dict]) -> dict:
    """Per our method (the records named densecalib-*) on the generated scenes of FEW_CAMERAS
    cameras over more than one frame set: how many (rigs), those at FEW_AUC3 or above (reached),
    those refused (scene, the refusal's first line), those kept below it (scene, AUC@3, whether
    warned), and the rigs of FEW_TIMED with their time (timed: scene, seconds)."""
    out: dict[str, dict] = {}
    for entry in scenes:
        cameras = entry.get("num_cameras", 0)
        if (entry.get("spec") or {}).get("kind") != "synthetic" or \
                not FEW_CAMERAS[0] <= cameras <= FEW_CAMERAS[1] or \
                entry.get("num_time_steps", 1) < 2:
            continue
        for record in entry["results"]:
            if not record["method"].startswith("densecalib"):
                continue
            check = out.setdefault(record["method"], dict(rigs=0, reached=[], refused=[],
                                                          short=[], timed=[]))
            check["rigs"] += 1
            auc3 = record["metrics"]["auc3"]
            if record["status"] != "ok":
                check["refused"].append(dict(scene=entry["scene"],
                                             message=record["message"].splitlines()[0]))
            elif auc3 >= FEW_AUC3:
                check["reached"].append(entry["scene"])
            else:
                check["short"].append(dict(scene=entry["scene"], auc3=auc3,
                                           warned=bool(record.get("warnings"))))
            if (cameras, entry.get("num_time_steps"),
                    tuple(entry.get("image_size") or ())) == FEW_TIMED:
                check["timed"].append(dict(scene=entry["scene"], s=record["runtime_s"]))
    return out


def format_few_rigs_check(check: dict) -> str:
    """The check's line per method, each rig by its seed (the scene name's last part)."""
    def seed(scene: str) -> str:
        return scene.rsplit("-", 1)[-1]

    cameras, sets, (width, height) = FEW_TIMED
    lines = [f"== the rigs users build (issue 81: each generated rig of {FEW_CAMERAS[0]}-"
             f"{FEW_CAMERAS[1]} cameras over several frame sets at AUC@3 >= {FEW_AUC3:g} or "
             f"refused, none wrong without a warning; {cameras} cameras x {sets} frame sets at "
             f"{width}x{height} within {FEW_TIME_S:g} s)"]
    for method, c in check.items():
        short = "; ".join(f"{seed(s['scene'])} {s['auc3']:.1f}"
                          + (" warned" if s["warned"] else " NOT WARNED") for s in c["short"])
        over = [t for t in c["timed"] if t["s"] > FEW_TIME_S]
        slowest = max((t["s"] for t in c["timed"]), default=None)
        lines.append(f"{method:<27} {len(c['reached'])} of {c['rigs']} at AUC@3 >= "
                     f"{FEW_AUC3:g}, {len(c['refused'])} refused"
                     + (" (" + "; ".join(f"{seed(r['scene'])}: {r['message'].split(':')[0]}"
                                         for r in c["refused"]) + ")" if c["refused"] else "")
                     + (f"; below it: {short}" if short else "")
                     + f"; timed {len(c['timed']) - len(over)} of {len(c['timed'])} within "
                     f"{FEW_TIME_S:g} s (slowest {_fmt(slowest, '.1f')} s)"
                     + ("; over it: " + "; ".join(f"{seed(t['scene'])} {t['s']:.1f} s"
                                                  for t in over)
                        if over else ""))
    return "\n".join(lines)
