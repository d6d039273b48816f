"""Pipeline configuration: dataclasses with the paper's defaults and named presets.

Presets follow the paper (Sec. 4 implementation details, ablation best rows):
- "regular": RADIAL per camera, F_err 10 px, B_err 20 px, cell 80 (incremental) / 40 (global),
  top_k 3 (incremental) / 1 (global), principal point fixed until an optional final BA.
- "fisheye": RADIAL_FISHEYE refined to OPENCV_FISHEYE, F_err off, B_err 100 px (off in global),
  cell 80 (incremental) / 40 (global), principal point refined.
"""
from __future__ import annotations

import copy
from dataclasses import dataclass, field, fields, is_dataclass
from typing import Optional

from .errors import InputError


@dataclass
class SamplingConfig:
    max_cycle_order: int = 4  # N: cycles of order 2..N are closed
    fine_cell_px: int = 5  # stage-1 grid, random pick per cell
    cell_size_px: int = 80  # stage-2 grid d
    c_min: float = 0.3  # coverage rule constant (see sampling.py for its interpretation)
    max_grid_iterations: int = 3  # grid levels per cycle order (Alg. 1 max_iter: d, d/2, d/4)
    samples_per_order: dict = field(default_factory=lambda: {4: 6000, 3: 3000, 2: 1000})
    top_k: int = 3  # number of best pair scores summed per cycle; 0 = no scoring
    # A pair's 2-cycles are sampled only if its F (or fisheye E) has at least this many inliers
    # (COLMAP's two-view min_num_inliers). Closure verifies higher cycles; a 2-cycle has only
    # F_err, which a fit to a handful of matches cannot give (measured on 35-deg rigs: pairs with
    # 9-17 inliers of 21-45 matches supplied most of the wrong 2-view tracks).
    min_two_cycle_pair_inliers: int = 15
    probabilistic_scoring: bool = True  # stage-2 pick proportional to score, else argmax
    score_alpha_deg: float = 30.0
    score_sigma_deg: float = 20.0
    score_p: float = 1.0
    score_boundary_eps: float = 0.03  # boundary-term sharpness (scoring.py); 1.0 = eq. 1 as printed
    seed: int = 0


@dataclass
class SfMConfig:
    camera_model: str = "RADIAL"  # initial COLMAP model per camera
    refine_to_model: Optional[str] = None  # e.g. "OPENCV_FISHEYE": final distortion-only refinement
    f_err_px: Optional[float] = 10.0  # epipolar filter threshold; None = off
    # With f_err_px off (fisheye), 2-cycle tracks still get this epipolar test (ray-based E,
    # pinhole-equivalent px): for mutual matchers a 2-cycle carries no consistency evidence.
    two_cycle_f_err_px: Optional[float] = 10.0
    b_err_px: Optional[float] = 20.0  # incremental reprojection outlier threshold; None = off
    refine_principal_point: bool = False  # in the final BA only
    share_intrinsics: bool = False  # one intrinsics block for identical cameras
    brute_force_first_pair: bool = True
    ba_iterations: int = 100
    absolute_pose_refine_iterations: int = 100
    # Global pipeline: staged BA (iterations; 0 disables a stage).
    global_init: str = "rotation_averaging"  # "rotation_averaging" | "previous" | "incremental"
    # With rotation_averaging, also refine from the incremental result and keep the better fit:
    # rotation averaging on few views can leave a camera in a wrong basin that BA cannot leave.
    global_multistart: bool = True
    # Distortion is on for both presets (paper Sec. 3.4 order): without it the global pipeline
    # measured AUC@3 2-7 vs 98-100 with it on generated RADIAL rigs (k1 up to 0.15).
    global_stage_iterations: dict = field(default_factory=lambda: {
        "extrinsics": 300, "focal": 200, "distortion": 200, "principal_point": 0, "model": 0})
    num_threads: int = -1  # -1 = all cores


@dataclass
class PipelineConfig:
    preset: str = "regular"
    pipeline: str = "incremental"  # "incremental" | "global"
    matcher: str = "sift"
    max_image_side_px: int = 1024  # images are matched at most at this size (coordinates rescaled)
    # Fresh calibrations run the sampling + SfM up to this many times (seeds seed, seed+1, ...) and
    # keep the medoid run (consensus.py): on weakly connected rigs one sample's outcome is a
    # lottery. They stop after 3 runs that agree (consensus.AGREEMENT_DEG). 1 = a single run.
    consensus_runs: int = 5
    # Refine the found rig once more on every keypoint match (all_matches.py; keypoint matchers
    # only): the sampled tracks find the rig, all the matches it agrees with refine it.
    refine_on_all_matches: bool = True
    # Focal lengths the user knows [px] (lens datasheet: f_mm / pixel pitch in mm, or
    # (width / 2) / tan(horizontal FOV / 2)): camera name -> px, "*" for every camera not named.
    # They replace the estimate from the fundamental matrices (eq. 2; fisheye: the equidistant
    # assumption) in the sampling and as the base of the SfM's focal multi-start; for perspective
    # models eq. 2's focals stay one more start (pipeline.calibrate_from_tracks). The SfM still
    # refines them. Empty: estimated.
    initial_focal_px: dict = field(default_factory=dict)
    # Focal lengths from the images' EXIF [px] (core/exif.py; the offline command fills it for
    # image folders): camera name -> px. A start like initial_focal_px but below it and below a
    # previous calibration's; cameras without one start from the estimate.
    exif_focal_px: dict = field(default_factory=dict)
    sampling: SamplingConfig = field(default_factory=SamplingConfig)
    sfm: SfMConfig = field(default_factory=SfMConfig)


PRESETS = ("regular", "fisheye")
PIPELINES = ("incremental", "global")
# The pipeline the CLI, node and demo use unless told otherwise. Incremental since its final
# re-triangulation: in `densecalib bench` (2026-11-21) mean pinhole AUC@3 90.0 vs 84.6 for global
# over the synthetic rigs, no run-to-run variation (global positioning is not deterministic), and
# the closer focal on the real fisheye bag; global keeps lower fisheye focal errors.
DEFAULT_PIPELINE = "incremental"


def make_config(preset: str = "regular", pipeline: str = "incremental",
                matcher: Optional[str] = None, **overrides) -> PipelineConfig:
    """Build the configuration of a named preset and pipeline; `overrides` are
    `section__field=value` (e.g. sampling__cell_size_px=40) or top-level fields."""
    if preset not in PRESETS:
        raise InputError(f"Unknown preset {preset!r}: choose one of {', '.join(PRESETS)}.")
    if pipeline not in PIPELINES:
        raise InputError(f"Unknown pipeline {pipeline!r}: choose one of {', '.join(PIPELINES)}.")
    cfg = PipelineConfig(preset=preset, pipeline=pipeline)
    if matcher is not None:
        cfg.matcher = matcher
    s, b = cfg.sampling, cfg.sfm
    if pipeline == "global":
        s.cell_size_px, s.top_k, s.probabilistic_scoring = 40, 1, True
        b.b_err_px = None
    if preset == "fisheye":
        b.camera_model, b.refine_to_model = "RADIAL_FISHEYE", "OPENCV_FISHEYE"
        b.f_err_px = None
        b.refine_principal_point = True
        if pipeline == "incremental":
            b.b_err_px = 100.0
        b.global_stage_iterations.update(distortion=200, principal_point=100, model=100)
    for key, value in overrides.items():
        _apply_override(cfg, key, value)
    return cfg


def _apply_override(cfg: PipelineConfig, key: str, value) -> None:
    target, name = cfg, key
    if "__" in key:
        section, name = key.split("__", 1)
        target = getattr(cfg, section, None)
        if not is_dataclass(target):
            raise InputError(f"Unknown configuration section {section!r} in {key!r}.")
    valid = {f.name for f in fields(target)}
    if name not in valid:
        raise InputError(f"Unknown option {key!r}: valid options are {', '.join(sorted(valid))}.")
    setattr(target, name, copy.deepcopy(value))
