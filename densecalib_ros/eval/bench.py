"""Accuracy benchmark: our pipelines and the peers (COLMAP incremental, GLOMAP global) on the same
images in the same process, scored against exact or reference cameras (core.metrics).

Scenes are generated rigs (deterministic from their seeds; the seeds are the benchmark's own, not
those used in development tests) and real photographs with reference cameras (Strecha entry-P10).
Every method gets the scene's images as RGB uint8 arrays, every frame set of them (the peers: all
frames of a camera as one COLMAP camera, peers.py).

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
from .datasets import (Scene, default_data_dir, load_caliscope, load_krtd_stills,
                       load_nerf_transforms, load_qualisys_videos, load_strecha,
                       scene_from_synthetic)
from .peers import PEER_METHODS, run_peer
from .tables import (few_rigs_check, format_error_sigma_ratios, format_few_rigs_check,
                     format_rotation_against_colmap, format_scene_table, format_summary,
                     format_time_against_colmap, rotation_against_colmap, summarize,
                     summarize_error_sigma_ratios, time_against_colmap)

log = logging.getLogger(__name__)

OUR_METHODS = {"densecalib-incremental": "incremental", "densecalib-global": "global"}
# Recalibration: the previous calibration is the reference with every camera rotated by
# RECAL_ROTATION_DEG about a random axis and moved by RECAL_MOVE_FRACTION of the mean distance
# between cameras (a bumped rig), then `core.recalibration.recalibrate` runs on the images.
RECAL_METHOD = "densecalib-recal"
RECAL_ROTATION_DEG = 2.0
RECAL_MOVE_FRACTION = 0.05
# Extrinsics only: our incremental pipeline given the reference intrinsics of every camera and
# holding them (PipelineConfig.cameras.known_intrinsics), as a rig of lab-calibrated cameras
# would be.
# Not in the default run: it answers what given intrinsics add, not how the product compares.
GIVEN_INTRINSICS_METHOD = "densecalib-given-intrinsics"
METHODS = (*PEER_METHODS, *OUR_METHODS, RECAL_METHOD)
ALL_METHODS = (*METHODS, GIVEN_INTRINSICS_METHOD)


@dataclass
class SceneSpec:
    """A benchmark scene. kind "synthetic": generated from (num_cameras, camera_model, width,
    height, seed, gap_deg: azimuth between neighbouring cameras, max_arc_deg: the cameras' arc at
    most; see synthetic.RigSpec); kind "strecha": the Strecha
    folder `folder` under the data dir, long side `max_side_px`; kind "nerf": `num_cameras`
    evenly spaced frames of the NeRF capture in `folder`, long side `max_side_px`; kind
    "caliscope": the videos of a Caliscope session in `folder`, `num_frame_sets` frame sets;
    kind "krtd": one still per camera with KRTD models in `folder`; kind "qualisys": videos with
    a Qualisys calibration in `folder`, `num_frame_sets` frame sets (datasets.py)."""

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
    num_frame_sets: int = 1  # kinds "caliscope", "qualisys": frame sets read from the videos
    # kind "synthetic": further synthetic.RigSpec fields as (name, value) pairs (the rigs users
    # build, few_rigs.py: room, walker, mount, lens_mix, num_time_steps, blur, JPEG).
    rig: tuple = ()


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
    entry-P10 at 1024 px, 6 frames of instant-ngp's fox (a phone walked around an object), each
    of the two also as one camera (share_intrinsics: what they are), and the real rigs
    (rig_scenes)."""
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
    scenes += [SceneSpec("ngp-fox-6view-1024" + ("-one-camera" if one else ""), "nerf",
                         num_cameras=6, folder="ngp_fox", max_side_px=1024,
                         share_intrinsics=one) for one in (False, True)]
    return scenes + rig_scenes()


def rig_scenes() -> list[SceneSpec]:
    """Real rigs with a target-based or surveyed reference: Caliscope's four webcams in a room
    and Pose2Sim's four-camera ring in a motion-capture lab (8 frame sets of their videos, as
    `calibrate --videos` takes them), and MEVA's six outdoor surveillance cameras (one still
    each, long lenses, 10-230 m apart)."""
    return [SceneSpec("caliscope-4webcams-8sets", "caliscope", num_cameras=4,
                      folder="caliscope_4webcams", num_frame_sets=8),
            SceneSpec("pose2sim-4cam-ring-8sets", "qualisys", num_cameras=4,
                      folder="pose2sim_4cam_ring", num_frame_sets=8),
            SceneSpec("meva-6cam-stills", "krtd", num_cameras=6,
                      folder="meva_6cam_surveillance")]


# Strecha entry-P10 at these long sides as well (--real): the image size alone moved its focal
# length and principal point by more than their sigmas, so the sigmas are checked at each.
P10_SIZES_PX = (1536, 3072)


def real_scenes() -> list[SceneSpec]:
    """Every real scene of the full set: Strecha and the fox (each as separate cameras and as one
    camera), and the real rigs (rig_scenes); and Strecha entry-P10 at P10_SIZES_PX."""
    scenes = []
    for s in full_scenes():
        if s.kind != "synthetic":
            scenes.append(s)
        if s.name == "strecha-entry-p10-1024":  # the other sizes beside it
            scenes += [SceneSpec(f"strecha-entry-p10-{px}", "strecha",
                                 folder="strecha_entry_p10", max_side_px=px)
                       for px in P10_SIZES_PX]
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
    """The held-out scenes (HELDOUT_* above), pinhole rigs on arcs up to 360 deg; the fox's frame
    subsets as separate cameras and as one camera."""
    scenes = [_synthetic(n, "RADIAL", seed, gap_deg=float(gap), max_arc_deg=360.0)
              for n, gap, seed in HELDOUT_PINHOLE]
    scenes += [_synthetic(n, "OPENCV_FISHEYE", seed) for n, seed in HELDOUT_FISHEYE]
    scenes += [SceneSpec(f"ngp-fox-{n}view-1024" + ("-one-camera" if one else ""), "nerf",
                         num_cameras=n, folder="ngp_fox", max_side_px=1024,
                         share_intrinsics=one)
               for n in HELDOUT_FOX_VIEWS for one in (False, True)]
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
    """The scene's images and reference cameras, calibrated as one camera where the spec says so
    (share_intrinsics). Raises FileNotFoundError when real data is absent."""
    scene = _loaded_scene(spec, data_dir)
    scene.share_intrinsics = spec.share_intrinsics
    return scene


def synthetic_rig_spec(spec: SceneSpec):
    """The core.synthetic.RigSpec a scene of kind "synthetic" is generated from."""
    from ..core.synthetic import RigSpec

    models = tuple("OPENCV_FISHEYE" if c in spec.fisheye_cameras else spec.camera_model
                   for c in range(spec.num_cameras)) if spec.fisheye_cameras else ()
    return RigSpec(num_cameras=spec.num_cameras, camera_model=spec.camera_model,
                   camera_models=models, width=spec.width, height=spec.height, seed=spec.seed,
                   gap_deg=spec.gap_deg, max_arc_deg=spec.max_arc_deg, layout=spec.layout,
                   bar_spacing_m=spec.bar_spacing_m, lenses=spec.lenses,
                   fov_range_deg=spec.fov_range_deg, **dict(spec.rig))


def _loaded_scene(spec: SceneSpec, data_dir: Path) -> Scene:
    if spec.kind == "synthetic":
        from ..core.synthetic import generate_rig

        return scene_from_synthetic(generate_rig(synthetic_rig_spec(spec)), spec.name)
    if spec.kind == "strecha":
        folder = Path(data_dir) / spec.folder
        if not (folder / "gt_dense_cameras").is_dir():
            raise FileNotFoundError(f"{folder} not found (set --data-dir or $DENSECALIB_DATA)")
        return load_strecha(folder, max_side_px=spec.max_side_px, name=spec.name)
    if spec.kind == "nerf":
        folder = Path(data_dir) / spec.folder
        if not (folder / "transforms.json").is_file():
            raise FileNotFoundError(f"{folder} not found (set --data-dir or $DENSECALIB_DATA)")
        return load_nerf_transforms(folder, spec.num_cameras, spec.max_side_px, name=spec.name)
    loaders = {"caliscope": lambda folder: load_caliscope(folder, spec.num_frame_sets, spec.name),
               "qualisys": lambda folder: load_qualisys_videos(folder, spec.num_frame_sets,
                                                               spec.name),
               "krtd": lambda folder: load_krtd_stills(folder, spec.name)}
    if spec.kind in loaders:
        folder = Path(data_dir) / spec.folder
        if not folder.is_dir():
            raise FileNotFoundError(f"{folder} not found (set --data-dir or $DENSECALIB_DATA)")
        return loaders[spec.kind](folder)
    raise InputError(f"Unknown scene kind {spec.kind!r}: choose synthetic, strecha, nerf, "
                     f"{', '.join(loaders)}.")


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
                            num_threads=num_threads, single_camera=share,
                            later_frames=scene.frame_sets[1:])
            calib = peer.to_rig_calibration(scene.camera_names)
            record["message"] = peer.message
        elif method in OUR_METHODS or method == GIVEN_INTRINSICS_METHOD:
            from ..core import calibrate_rig, make_config

            given = {}
            if method == GIVEN_INTRINSICS_METHOD:
                given = {n: c.intrinsics for n, c in scene.gt.cameras.items()}
            config = make_config("fisheye" if scene.lens == "fisheye" else "regular",
                                 OUR_METHODS.get(method, "incremental"),
                                 cameras__lens={} if given else dict(scene.camera_lens),
                                 cameras__known_intrinsics=given,
                                 sfm__share_intrinsics=share, sfm__num_threads=num_threads)
            # Ceres/COLMAP warnings (e.g. failed LM steps) would bury the tables; errors still show.
            with quiet_colmap(min_level=2):
                calib = calibrate_rig(scene.frame_sets, scene.camera_names, config)
        elif method == RECAL_METHOD:
            from ..core import make_config, recalibrate

            config = make_config("fisheye" if scene.lens == "fisheye" else "regular", "global",
                                 cameras__lens=dict(scene.camera_lens),
                                 sfm__num_threads=num_threads)
            previous = perturbed_calibration(scene.gt, RECAL_ROTATION_DEG, RECAL_MOVE_FRACTION)
            start = time.perf_counter()  # the perturbation is set-up, not recalibration time
            with quiet_colmap(min_level=2):
                calib = recalibrate(scene.frame_sets, scene.camera_names, config, previous).rig
            record["message"] = f"started from {calib.quality.init}"
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
        record["warnings"] = list(calib.quality.warnings)
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
    report["rotation_against_colmap"] = rotation_against_colmap(report["scenes"])
    if report["rotation_against_colmap"]:
        say(format_rotation_against_colmap(report["rotation_against_colmap"]))
    report["time_against_colmap"] = time_against_colmap(report["scenes"])
    if report["time_against_colmap"]:
        say(format_time_against_colmap(report["time_against_colmap"]))
    report["few_rigs_check"] = few_rigs_check(report["scenes"])
    if report["few_rigs_check"]:
        say(format_few_rigs_check(report["few_rigs_check"]))
    _write_json(report, out_dir)
    return report


def _write_json(report: dict, out_dir: Optional[Path]) -> None:
    if out_dir is None:
        return
    from ..core.io.safe_write import write_text_atomic

    Path(out_dir).mkdir(parents=True, exist_ok=True)
    write_text_atomic(Path(out_dir) / "bench.json",
                      json_text(report, indent=1) + "\n")

