"""Accuracy benchmark: our pipelines and the peers (COLMAP incremental, GLOMAP global) on the same
images in the same process, scored against exact or reference cameras (core.metrics).

Scenes are generated rigs (deterministic from their seeds; the seeds are the benchmark's own, not
those used in development tests) and real photographs with reference cameras (Strecha entry-P10).
Every method gets the scene's images as RGB uint8 arrays; peers use the first time step only.

Resources per method: wall-clock runtime and its ratio to COLMAP's on the same images, and peak
resident memory of the process and its worker processes while the method ran (Linux: each one's
VmHWM high-water mark is reset through /proc/PID/clear_refs before each method and read after;
this counts C++ allocations that tracemalloc misses; the peaks are summed, an upper bound, since
pages the workers share count once per process; a peer's is its own process's: it runs there
alone). The bench process holds every scene's images, so a peak is the bench's, not what the
method would need by itself. Where the reset is not possible the peak is reported as None.
"""
from __future__ import annotations

import logging
import os
import platform
import time
import traceback
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Callable, Optional, Sequence

import numpy as np

from ..core.colmap_logging import quiet_colmap
from ..core.errors import CalibrationError, InputError
from ..core.json_text import json_text
from ..core.metrics import evaluate_calibration
from .datasets import (Scene, default_data_dir, load_nerf_transforms, load_strecha,
                       scene_from_synthetic)
from .peers import PEER_METHODS, run_peer

log = logging.getLogger(__name__)

OUR_METHODS = {"densecalib-incremental": "incremental", "densecalib-global": "global"}
# Recalibration: the previous calibration is the reference with every camera rotated by
# RECAL_ROTATION_DEG about a random axis and moved by RECAL_MOVE_FRACTION of the mean distance
# between cameras (a bumped rig), then `core.recalibration.recalibrate` runs on the images.
RECAL_METHOD = "densecalib-recal"
RECAL_ROTATION_DEG = 2.0
RECAL_MOVE_FRACTION = 0.05
# Extrinsics only: our incremental pipeline given the reference intrinsics of every camera and
# holding them (PipelineConfig.known_intrinsics), as a rig of lab-calibrated cameras would be.
# Not in the default run: it answers what given intrinsics add, not how the product compares.
GIVEN_INTRINSICS_METHOD = "densecalib-given-intrinsics"
METHODS = (*PEER_METHODS, *OUR_METHODS, RECAL_METHOD)
ALL_METHODS = (*METHODS, GIVEN_INTRINSICS_METHOD)
WIDE_GAP_DEG = 35.0  # the wide-baseline rigs' azimuth between neighbouring cameras


@dataclass
class SceneSpec:
    """A benchmark scene. kind "synthetic": generated from (num_cameras, camera_model, width,
    height, seed, gap_deg: azimuth between neighbouring cameras, max_arc_deg: the cameras' arc at
    most; see synthetic.RigSpec); kind "strecha": the Strecha
    folder `folder` under the data dir, long side `max_side_px`; kind "nerf": `num_cameras`
    evenly spaced frames of the NeRF capture in `folder`, long side `max_side_px`."""

    name: str
    kind: str
    num_cameras: int = 0
    camera_model: str = "RADIAL"
    width: int = 1024
    height: int = 768
    seed: int = 0
    folder: str = ""
    max_side_px: int = 1024
    gap_deg: float = 20.0
    max_arc_deg: float = 140.0
    fisheye_cameras: tuple = ()  # a rig mixing lenses: these cameras are OPENCV_FISHEYE
    layout: str = "arc"  # synthetic.RigSpec.layout: "bar" = cameras side by side, one direction
    bar_spacing_m: float = 0.3
    lenses: str = "real"  # synthetic.RigSpec.lenses
    # One physical camera moved between shots: calibrated with shared intrinsics (ours:
    # --share-intrinsics; COLMAP: its single-camera mode).
    share_intrinsics: bool = False
    fov_range_deg: Optional[tuple] = None  # synthetic.RigSpec.fov_range_deg


def _synthetic(num_cameras: int, camera_model: str, seed: int, width: int = 1024,
               height: int = 768, gap_deg: float = 20.0, max_arc_deg: float = 140.0,
               fov_range_deg: Optional[tuple] = None) -> SceneSpec:
    lens = "fisheye" if camera_model == "OPENCV_FISHEYE" else "pinhole"
    wide = "" if gap_deg == 20.0 else f"gap{gap_deg:g}-"
    long_lens = "" if fov_range_deg is None else f"fov{fov_range_deg[0]:g}-{fov_range_deg[1]:g}-"
    return SceneSpec(f"synthetic-{lens}-{long_lens}{wide}{num_cameras}cam-{width}x{height}-s{seed}",
                     "synthetic", num_cameras, camera_model, width, height, seed,
                     gap_deg=gap_deg, max_arc_deg=max_arc_deg, fov_range_deg=fov_range_deg)


# Rigs mixing lenses: (cameras, indices of the fisheye cameras among RADIAL ones, seed); 20 deg
# gaps. Seeds of their own (development used others), peers get each camera's model.
MIXED_RIGS = ((3, (1,), 501), (4, (0,), 502), (5, (2,), 503), (6, (1, 4), 504), (7, (3,), 505),
              (8, (0, 7), 506))


def mixed_scenes() -> list[SceneSpec]:
    """Generated rigs with fisheye cameras among pinhole ones (MIXED_RIGS), 1024x768."""
    return [SceneSpec(f"synthetic-mixed-{n}cam-fisheye{'+'.join(map(str, fish))}-1024x768-s{seed}",
                      "synthetic", n, "RADIAL", seed=seed, fisheye_cameras=tuple(fish))
            for n, fish, seed in MIXED_RIGS]


def quick_scenes() -> list[SceneSpec]:
    """A few minutes on 2 cores: one pinhole rig, one fisheye rig, Strecha at reduced size."""
    return [_synthetic(6, "RADIAL", 101, gap_deg=30.0, max_arc_deg=360.0),
            _synthetic(4, "OPENCV_FISHEYE", 201, 800, 600),
            SceneSpec("strecha-entry-p10-768", "strecha", folder="strecha_entry_p10",
                      max_side_px=768)]


# Generated rigs with the intrinsics real lenses have (synthetic.RigSpec lenses "real": principal
# points up to 2 % of each side off-centre, focal lengths 0.5-2.2x the width, fy != fx by up to
# 0.5 %): (cameras, degrees between neighbours, seed), on arcs up to a full ring.
PINHOLE_RIGS = ((5, 25, 101), (5, 45, 102), (6, 30, 103), (6, 40, 104), (7, 35, 105),
                (8, 20, 106), (8, 30, 107), (10, 20, 108), (10, 35, 109))
# Long lenses (25-35 deg horizontal field of view): (cameras, degrees, seed).
LONG_LENS_RIGS = ((5, 20, 111), (6, 25, 112), (8, 20, 113))
LONG_LENS_FOV_DEG = (25.0, 35.0)
# Few cameras far apart (camera traps, forensic scenes): (cameras, degrees, seed).
FEW_CAMERA_RIGS = ((3, 50, 121), (4, 45, 122), (4, 60, 123))


def full_scenes() -> list[SceneSpec]:
    """Pinhole rigs of 5-10 cameras 20-45 deg apart (PINHOLE_RIGS), long-lens rigs
    (LONG_LENS_RIGS), 3-4 cameras 45-60 deg apart (FEW_CAMERA_RIGS), fisheye rigs of 4, 6 and 8
    cameras (150-190 deg, 2 seeds each), all 1024x768 with the intrinsics of real lenses, Strecha
    entry-P10 at 1024 px, and 6 frames of instant-ngp's fox (a phone walked around an object)."""
    scenes = [_synthetic(n, "RADIAL", seed, gap_deg=float(gap), max_arc_deg=360.0)
              for n, gap, seed in PINHOLE_RIGS]
    scenes += [_synthetic(n, "RADIAL", seed, gap_deg=float(gap), max_arc_deg=360.0,
                          fov_range_deg=LONG_LENS_FOV_DEG) for n, gap, seed in LONG_LENS_RIGS]
    scenes += [_synthetic(n, "RADIAL", seed, gap_deg=float(gap), max_arc_deg=360.0)
               for n, gap, seed in FEW_CAMERA_RIGS]
    scenes += [_synthetic(n, "OPENCV_FISHEYE", seed) for n in (4, 6, 8) for seed in (201, 202)]
    scenes.append(SceneSpec("strecha-entry-p10-1024", "strecha", folder="strecha_entry_p10",
                            max_side_px=1024))
    scenes.append(SceneSpec("strecha-entry-p10-1024-one-camera", "strecha",
                            folder="strecha_entry_p10", max_side_px=1024, share_intrinsics=True))
    scenes.append(SceneSpec("ngp-fox-6view-1024", "nerf", num_cameras=6, folder="ngp_fox",
                            max_side_px=1024))
    return scenes


# Held-out scenes: never used to develop or tune the method (checked only after a change was
# made), to measure how results carry over to rigs the bench does not contain. Generated pinhole
# rigs with other seeds, camera counts and gaps (set A: seeds 301-310, set B: 401-412), two
# fisheye rigs, and other frame subsets of the fox capture (a fox head on a wall with repeating
# rose wallpaper: planar and repetitive, the hardest real scene we have).
HELDOUT_PINHOLE = ((4, 45, 301), (4, 45, 302), (5, 30, 303), (5, 40, 304), (5, 40, 305),
                   (7, 25, 306), (7, 30, 307), (8, 20, 308), (3, 30, 309), (3, 30, 310),
                   (3, 25, 401), (3, 35, 402), (4, 30, 403), (4, 40, 404), (4, 25, 405),
                   (5, 35, 406), (5, 25, 407), (6, 30, 408), (3, 30, 409), (4, 35, 410),
                   (6, 40, 411), (3, 20, 412))  # (cameras, gap deg, seed)
HELDOUT_FISHEYE = ((5, 311), (7, 312))
HELDOUT_FOX_VIEWS = (5, 8, 10)


def heldout_scenes() -> list[SceneSpec]:
    """The held-out scenes (HELDOUT_* above), pinhole rigs on arcs up to 360 deg."""
    scenes = [_synthetic(n, "RADIAL", seed, gap_deg=float(gap), max_arc_deg=360.0)
              for n, gap, seed in HELDOUT_PINHOLE]
    scenes += [_synthetic(n, "OPENCV_FISHEYE", seed) for n, seed in HELDOUT_FISHEYE]
    scenes += [SceneSpec(f"ngp-fox-{n}view-1024", "nerf", num_cameras=n, folder="ngp_fox",
                         max_side_px=1024) for n in HELDOUT_FOX_VIEWS]
    return scenes


# Forward-facing rigs: cameras side by side on a bar along one wall, looking across the room with
# their optical axes parallel to within a few degrees (a stereo head, a camera array on a shelf).
# Their images leave the focal lengths weakly determined (core.method.focal_determination): this set
# measures how far off they come out and whether the calibration says so. (cameras, spacing m,
# seed); seeds of their own.
FORWARD_RIGS = ((3, 0.12, 601), (4, 0.3, 602), (4, 0.3, 603), (5, 0.2, 604), (6, 0.15, 605),
                (8, 0.1, 606))


def forward_scenes() -> list[SceneSpec]:
    """Generated pinhole rigs of FORWARD_RIGS, 1024x768."""
    return [SceneSpec(f"synthetic-pinhole-bar{spacing:g}m-{n}cam-1024x768-s{seed}", "synthetic",
                      n, "RADIAL", seed=seed, layout="bar", bar_spacing_m=spacing)
            for n, spacing, seed in FORWARD_RIGS]


def build_scene(spec: SceneSpec, data_dir: Path) -> Scene:
    """The scene's images and reference cameras. Raises FileNotFoundError when real data is
    absent."""
    if spec.kind == "synthetic":
        from ..core.synthetic import RigSpec, generate_rig

        models = tuple("OPENCV_FISHEYE" if c in spec.fisheye_cameras else spec.camera_model
                       for c in range(spec.num_cameras)) if spec.fisheye_cameras else ()
        rig = generate_rig(RigSpec(num_cameras=spec.num_cameras, camera_model=spec.camera_model,
                                   camera_models=models, width=spec.width, height=spec.height,
                                   seed=spec.seed, gap_deg=spec.gap_deg,
                                   max_arc_deg=spec.max_arc_deg, layout=spec.layout,
                                   bar_spacing_m=spec.bar_spacing_m, lenses=spec.lenses,
                                   fov_range_deg=spec.fov_range_deg))
        return scene_from_synthetic(rig, spec.name)
    if spec.kind == "strecha":
        folder = Path(data_dir) / spec.folder
        if not (folder / "gt_dense_cameras").is_dir():
            raise FileNotFoundError(f"{folder} not found (set --data-dir or $DENSECALIB_DATA)")
        scene = load_strecha(folder, max_side_px=spec.max_side_px, name=spec.name)
        scene.share_intrinsics = spec.share_intrinsics
        return scene
    if spec.kind == "nerf":
        folder = Path(data_dir) / spec.folder
        if not (folder / "transforms.json").is_file():
            raise FileNotFoundError(f"{folder} not found (set --data-dir or $DENSECALIB_DATA)")
        return load_nerf_transforms(folder, spec.num_cameras, spec.max_side_px, name=spec.name)
    raise InputError(f"Unknown scene kind {spec.kind!r}: choose synthetic, strecha or nerf.")


def _own_processes() -> list[int]:
    """This process and its descendants (core.parallel's fork server and workers)."""
    from ..core.parallel import descendant_pids

    return [os.getpid(), *descendant_pids(os.getpid())]


def _reset_peak_rss() -> bool:
    try:
        for pid in _own_processes():
            with open(f"/proc/{pid}/clear_refs", "w") as f:
                f.write("5")
        return True
    except OSError:
        return False


def _peak_rss_mib(with_workers: bool = True) -> Optional[float]:
    """Peak resident memory since _reset_peak_rss, MiB: this process's, plus its workers' where
    with_workers (a peer runs in this process alone; our idle workers are not its memory)."""
    total_kib = 0
    try:
        for pid in (_own_processes() if with_workers else [os.getpid()]):
            with open(f"/proc/{pid}/status") as f:
                total_kib += next((int(line.split()[1]) for line in f
                                   if line.startswith("VmHWM:")), 0)
    except OSError:
        return None
    return total_kib / 1024.0


def run_method(method: str, scene: Scene, num_threads: int = -1) -> dict:
    """Run one method on one scene and score it. Never raises for a method's own failure: the
    record's status is "ok", "failed" (CalibrationError / peer registered nothing), "unavailable"
    (a module of our pipeline is missing: ImportError) or "error" (an unexpected exception, with its
    traceback)."""
    record = dict(method=method, status="ok", message="", runtime_s=None, peak_rss_mib=None)
    share = scene.share_intrinsics
    can_measure_memory = _reset_peak_rss()
    start = time.perf_counter()
    try:
        if method in PEER_METHODS:
            peer = run_peer(method, scene.frame_sets[0], scene.camera_names,
                            lens=[scene.camera_lens.get(n, scene.lens) for n in scene.camera_names],
                            num_threads=num_threads, single_camera=share)
            calib = peer.to_rig_calibration(scene.camera_names)
            record["message"] = peer.message
        elif method in OUR_METHODS or method == GIVEN_INTRINSICS_METHOD:
            from ..core.config import make_config
            from ..core.pipeline import calibrate_rig

            given = {}
            if method == GIVEN_INTRINSICS_METHOD:
                given = {n: c.intrinsics for n, c in scene.gt.cameras.items()}
            config = make_config("fisheye" if scene.lens == "fisheye" else "regular",
                                 OUR_METHODS.get(method, "incremental"),
                                 camera_lens={} if given else dict(scene.camera_lens),
                                 known_intrinsics=given)
            config.sfm.share_intrinsics = share
            config.sfm.num_threads = num_threads
            # Ceres/COLMAP warnings (e.g. failed LM steps) would bury the tables; errors still show.
            with quiet_colmap(min_level=2):
                calib = calibrate_rig(scene.frame_sets, scene.camera_names, config)
        elif method == RECAL_METHOD:
            from ..core.config import make_config
            from ..core.recalibration import recalibrate

            config = make_config("fisheye" if scene.lens == "fisheye" else "regular", "global",
                                 camera_lens=dict(scene.camera_lens))
            config.sfm.num_threads = num_threads
            previous = perturbed_calibration(scene.gt, RECAL_ROTATION_DEG, RECAL_MOVE_FRACTION)
            start = time.perf_counter()  # the perturbation is set-up, not recalibration time
            with quiet_colmap(min_level=2):
                calib = recalibrate(scene.frame_sets, scene.camera_names, config, previous).rig
            record["message"] = f"started from {calib.quality.get('init')}"
        else:
            raise InputError(f"Unknown method {method!r}: choose from {', '.join(ALL_METHODS)}.")
    except CalibrationError as exc:
        record.update(status="failed", message=f"{type(exc).__name__}: {exc}")
        calib = None
    except ImportError as exc:  # a pipeline stage that is not part of this installation
        record.update(status="unavailable", message=f"{type(exc).__name__}: {exc}")
        calib = None
    except Exception as exc:  # keep benchmarking the other methods; the record says what broke
        record.update(status="error", message=f"{type(exc).__name__}: {exc}",
                      traceback=traceback.format_exc())
        calib = None
    record["runtime_s"] = time.perf_counter() - start
    record["peak_rss_mib"] = (_peak_rss_mib(with_workers=method not in PEER_METHODS)
                              if can_measure_memory else None)
    if calib is None:
        from ..core.types import RigCalibration

        calib = RigCalibration(scene.camera_names[0], {}, failed_cameras=list(scene.camera_names))
    elif not calib.cameras and record["status"] == "ok":
        record["status"] = "failed"
    record["metrics"] = evaluate_calibration(calib, scene.gt)
    if method not in PEER_METHODS and calib.cameras:
        from ..core.method.uncertainty import error_sigma_ratios
        record["error_sigma_ratios"] = error_sigma_ratios(calib, scene.gt)
        # What the user would have been told about this result (consensus disagreement, focal
        # lengths left open, ...): a warning on a right result is a false alarm, none on a wrong
        # one a miss.
        record["warnings"] = list(calib.quality.get("warnings", []))
    return record


def perturbed_calibration(calibration, rotation_deg: float, move_fraction: float, seed: int = 0):
    """A copy of `calibration` with every camera rotated by rotation_deg about a random axis and
    its centre moved by move_fraction of the mean distance between camera centres (seeded)."""
    import copy

    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(seed)
    out = copy.deepcopy(calibration)
    centres = np.array([-c.cam_from_rig[:3, :3].T @ c.cam_from_rig[:3, 3]
                        for c in out.cameras.values()])
    spacing = np.mean([np.linalg.norm(a - b) for k, a in enumerate(centres) for b in centres[k + 1:]])
    for cam, centre in zip(out.cameras.values(), centres):
        axis = rng.normal(size=3)
        R = Rotation.from_rotvec(np.radians(rotation_deg) * axis / np.linalg.norm(axis)).as_matrix()
        move = rng.normal(size=3)
        new_centre = centre + move_fraction * spacing * move / np.linalg.norm(move)
        R_new = R @ cam.cam_from_rig[:3, :3]
        cam.cam_from_rig = np.eye(4)
        cam.cam_from_rig[:3, :3], cam.cam_from_rig[:3, 3] = R_new, -R_new @ new_centre
    return out


def run_bench(specs: Sequence[SceneSpec], methods: Sequence[str], num_threads: int = -1,
              data_dir: Optional[Path] = None, out_dir: Optional[Path] = None,
              say: Callable[[str], None] = print) -> dict:
    """Run every method on every scene, print a table per scene and a summary, and write
    `out_dir/bench.json` (rewritten after each scene so an interrupted run keeps its results)."""
    unknown = [m for m in methods if m not in ALL_METHODS]
    if unknown:
        raise InputError(f"Unknown method(s) {', '.join(unknown)}: choose from "
                         f"{', '.join(ALL_METHODS)}.")
    data_dir = Path(data_dir) if data_dir else default_data_dir()
    report = dict(started=time.strftime("%Y-%m-%dT%H:%M:%S"), host=platform.node(),
                  cpu_count=os.cpu_count(), num_threads=num_threads, methods=list(methods),
                  data_dir=str(data_dir), scenes=[], skipped=[])
    for spec in specs:
        start = time.perf_counter()
        try:
            scene = build_scene(spec, data_dir)
        except (FileNotFoundError, InputError) as exc:
            say(f"\n== {spec.name}: skipped ({exc})")
            report["skipped"].append(dict(scene=spec.name, reason=str(exc)))
            continue
        build_s = time.perf_counter() - start
        size = scene.frame_sets[0][0].shape
        entry = dict(scene=spec.name, spec=asdict(spec), lens=scene.lens,
                     num_cameras=len(scene.camera_names), image_size=[size[1], size[0]],
                     num_time_steps=len(scene.frame_sets),
                     reference_is_estimate=scene.reference_is_estimate, notes=scene.notes,
                     build_s=build_s, results=[])
        for method in methods:
            record = run_method(method, scene, num_threads)
            entry["results"].append(record)
            if record["status"] in ("error", "unavailable"):
                log.info("%s on %s: %s", method, spec.name, record["message"])
        report["scenes"].append(entry)
        say("\n" + format_scene_table(entry))
        _write_json(report, out_dir)
    report["summary"] = summarize(report["scenes"])
    say("\n" + format_summary(report["summary"]))
    report["uncertainty_check"] = summarize_error_sigma_ratios(report["scenes"])
    if report["uncertainty_check"]:
        say(format_error_sigma_ratios(report["uncertainty_check"]))
    _write_json(report, out_dir)
    return report


def _write_json(report: dict, out_dir: Optional[Path]) -> None:
    if out_dir is None:
        return
    from ..core.io.safe_write import write_text_atomic

    Path(out_dir).mkdir(parents=True, exist_ok=True)
    write_text_atomic(Path(out_dir) / "bench.json",
                      json_text(report, indent=1) + "\n")


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
    return "\n".join(lines)


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


def summarize_error_sigma_ratios(scenes: list[dict]) -> dict:
    """Per our method: quantiles over all cameras of actual error / estimated sigma, focal and
    projection (core.method.uncertainty.error_sigma_ratios); a sigma that is only a lower bound
    shows as ratios well above 1."""
    pooled: dict[str, dict[str, list]] = {}
    for entry in scenes:
        for r in entry["results"]:
            for kind, ratios in r.get("error_sigma_ratios", {}).items():
                pooled.setdefault(r["method"], {}).setdefault(kind, []).extend(ratios)
    return {method: {kind: dict(n=len(v), median=float(np.median(v)),
                                p90=float(np.percentile(v, 90)), max=float(np.max(v)))
                     for kind, v in kinds.items() if v}
            for method, kinds in pooled.items()}


def format_error_sigma_ratios(check: dict) -> str:
    lines = ["== uncertainty check: actual error / its estimated sigma over cameras (focal length; "
             "projection: mean projection-map error / projection_std_px)"]
    for method, kinds in check.items():
        parts = [f"{kind} median {q['median']:.2f}, 90% {q['p90']:.2f}, max {q['max']:.2f} "
                 f"(n={q['n']})" for kind, q in kinds.items()]
        lines.append(f"{method:<28}" + ("; ".join(parts) or "no estimated intrinsics"))
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
