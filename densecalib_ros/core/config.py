"""Pipeline configuration: frozen dataclasses with the paper's defaults and named presets.

A configuration is built once (make_config, or `with_options` on one), resolved for the rig's
cameras and checked where a calibration starts (PipelineConfig.for_cameras: COLMAP's options and
their Check()), and read-only from then on: a stage that needs other options (a consensus run's
seed, the second matcher) derives a configuration with `with_options`, never changes one.

Presets follow the paper (Sec. 4 implementation details, ablation best rows):
- "regular": RADIAL per camera, F_err 10 px, B_err 20 px, cell 80 (incremental) / 40 (global),
  top_k 3 (incremental) / 1 (global), principal point fixed until an optional final BA.
- "fisheye": RADIAL_FISHEYE refined to OPENCV_FISHEYE, F_err off, B_err 100 px (off in global),
  cell 80 (incremental) / 40 (global), principal point refined.
"""
from __future__ import annotations

import copy
import math
import numbers
from dataclasses import dataclass, field, fields, is_dataclass, replace
from typing import Optional, Sequence

import numpy as np

from .errors import InputError

# The paper's incremental reprojection outlier threshold B_err per lens kind (px); the global
# pipeline runs without one but starts from an incremental result that needs it.
B_ERR_PX = {"regular": 20.0, "fisheye": 100.0}


@dataclass(frozen=True)
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
    # F_err, which a fit to a handful of matches cannot give: such weak pairs supply most of the
    # wrong 2-view tracks (docs/design-notes.md, Two-view tracks of weak pairs).
    min_two_cycle_pair_inliers: int = 15
    probabilistic_scoring: bool = True  # stage-2 pick proportional to score, else argmax
    score_alpha_deg: float = 30.0
    score_sigma_deg: float = 20.0
    score_p: float = 1.0
    score_boundary_eps: float = 0.03  # boundary-term sharpness (scoring.py); 1.0 = eq. 1 as printed
    seed: int = 0


@dataclass(frozen=True)
class SfMConfig:
    camera_model: str = "RADIAL"  # initial COLMAP model per camera
    # Per camera (the calibration's camera order), a model that replaces camera_model for that
    # camera: a rig mixing lenses (resolve_camera_lenses fills it from PipelineConfig.cameras.lens).
    camera_models: tuple = ()
    # e.g. "OPENCV_FISHEYE": final distortion-only refinement of the cameras of its lens family
    refine_to_model: Optional[str] = None
    f_err_px: Optional[float] = 10.0  # epipolar filter threshold; None = off
    # With f_err_px off (fisheye), 2-cycle tracks still get this epipolar test (ray-based E,
    # pinhole-equivalent px): for mutual matchers a 2-cycle carries no consistency evidence.
    two_cycle_f_err_px: Optional[float] = 10.0
    b_err_px: Optional[float] = B_ERR_PX["regular"]  # incremental outlier threshold; None = off
    # A rig mixing lenses runs with the fisheye B_err; its pinhole cameras' observations are
    # judged by the regular preset's (resolve_camera_lenses). None: b_err_px for every camera.
    pinhole_b_err_px: Optional[float] = None
    # Likewise F_err: a rig mixing lenses runs with it off (fisheye), but a pair of its pinhole
    # cameras is tested as in the regular preset. None: f_err_px for every pair.
    pinhole_f_err_px: Optional[float] = None
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
    # fails on lenses with real distortion (docs/design-notes.md, Distortion stage of the global
    # pipeline).
    global_stage_iterations: dict = field(default_factory=lambda: {
        "extrinsics": 300, "focal": 200, "distortion": 200, "principal_point": 0, "model": 0})
    num_threads: int = -1  # -1 = all cores
    # Cameras (indices) whose intrinsics the user gave (PipelineConfig.cameras.known_intrinsics;
    # resolve_camera_lenses fills it): they start at those values and no step refines them.
    fixed_intrinsics_cameras: tuple = ()
    # Groups of cameras (indices) whose intrinsics the SfM estimates as one (identical units:
    # CameraData.identical_units; resolve_camera_lenses fills it).
    shared_intrinsics_groups: tuple = ()

    def model_of(self, c: int) -> str:
        """Camera c's initial COLMAP model."""
        return self.camera_models[c] if self.camera_models else self.camera_model

    def models(self, num_cameras: int) -> list[str]:
        return [self.model_of(c) for c in range(num_cameras)]

    def mixed_rig_pinhole_cameras(self, num_cameras: int) -> tuple[int, ...]:
        """The pinhole cameras of a rig mixing lenses; () when every camera has one lens."""
        pinhole = tuple(c for c, m in enumerate(self.models(num_cameras))
                        if lens_of_model(m) == "pinhole")
        return pinhole if self.camera_models and len(pinhole) < num_cameras else ()

    def principal_point_cameras(self, num_cameras: int) -> tuple[int, ...]:
        """The cameras whose principal point the final adjustment refines: none under the regular
        preset, the fisheye cameras in a rig mixing lenses, else every camera."""
        if not self.refine_principal_point:
            return ()
        held = set(self.mixed_rig_pinhole_cameras(num_cameras))
        return tuple(c for c in range(num_cameras) if c not in held)

    def pair_f_err_px(self, i: int, j: int) -> Optional[float]:
        """F_err of the camera pair (i, j): f_err_px, or pinhole_f_err_px for two pinhole
        cameras of a rig mixing lenses."""
        if self.f_err_px is not None or self.pinhole_f_err_px is None or not self.camera_models:
            return self.f_err_px
        both_pinhole = all(lens_of_model(self.model_of(c)) == "pinhole" for c in (i, j))
        return self.pinhole_f_err_px if both_pinhole else None

    def outlier_thresholds_px(self, num_cameras: int):
        """B_err: b_err_px (None = off), or per camera (C,) where pinhole_b_err_px applies."""
        if self.b_err_px is None or self.pinhole_b_err_px is None or not self.camera_models:
            return self.b_err_px
        return np.array([self.b_err_px if "FISHEYE" in m else self.pinhole_b_err_px
                         for m in self.models(num_cameras)])


@dataclass(frozen=True)
class CameraData:
    """What the user knows about the cameras (camera name -> ...; empty: nothing known), kept
    apart from the options of how to calibrate them."""

    # Focal lengths the user knows [px] (lens datasheet: f_mm / pixel pitch in mm, or
    # (width / 2) / tan(horizontal FOV / 2)): camera name -> px, "*" for every camera not named.
    # They replace the estimate from the fundamental matrices (eq. 2; fisheye: the equidistant
    # assumption) in the sampling and as the base of the SfM's focal multi-start; for perspective
    # models eq. 2's focals stay one more start (stages.runs.sfm_run). The SfM still
    # refines them. Empty: estimated.
    initial_focal_px: dict = field(default_factory=dict)
    # Focal lengths from the images' EXIF [px] (core/io/exif.py; the offline command fills it for
    # image folders): camera name -> px. A start like initial_focal_px but below it and below a
    # previous calibration's; cameras without one start from the estimate.
    exif_focal_px: dict = field(default_factory=dict)
    # Cameras whose lens differs from the preset's: camera name -> "pinhole" | "fisheye" (a rig
    # mixing lenses, e.g. a fisheye overhead camera among pinhole side cameras). Each camera gets
    # its lens's model (LENS_MODELS); a rig with any fisheye camera runs with the fisheye
    # preset's SfM options (resolve_camera_lenses).
    lens: dict = field(default_factory=dict)
    # Regions whose matches are not used (core/method/masks.py): camera name -> bool (H, W), True =
    # ignored (an info strip, the rig's own structure). Cameras not named use the whole image.
    masks: dict = field(default_factory=dict)
    # Intrinsics the user knows and wants kept (core/method/known_intrinsics.py: a lab calibration's
    # camera_info YAML, a previous calibration): camera name -> CameraIntrinsics at the images'
    # size. Those cameras start from them and keep them exactly: only the extrinsics (and the
    # other cameras' intrinsics) are calibrated. Their lens follows from the model.
    known_intrinsics: dict = field(default_factory=dict)
    # Cameras that are units of one camera model (the same make, model, lens and focal length:
    # core.io.exif.identical_unit_groups, or the user's word): ((camera names), why) per group.
    # The SfM estimates one set of intrinsics per group, which makes three or four cameras far
    # apart far better determined; the refinement on the images then estimates each unit's own,
    # as one camera where the images cannot tell them apart (core.method.image_refinement).
    identical_units: tuple = ()
    # Where nothing names the units: whether a calibration whose runs disagree may try the
    # cameras as units of one model, kept where the images bear it out (core/robust/one_model.py).
    # False where the user knows the cameras are of different models.
    units_from_images: bool = True


@dataclass(frozen=True)
class PipelineConfig:
    preset: str = "regular"
    pipeline: str = "incremental"  # "incremental" | "global"
    matcher: str = "sift"
    # Where perspective cameras matched with sift come out undetermined (a camera not
    # registered, no calibration, runs that disagree, focal lengths looser than the aim), match
    # again with this one and keep the better-determined calibration
    # (core/robust/second_matcher.py); None: keep sift's.
    second_matcher: Optional[str] = "asift"
    max_image_side_px: int = 1024  # images are matched at most at this size (coordinates rescaled)
    # Fresh calibrations run the sampling + SfM up to this many times (seeds seed, seed+1, ...) and
    # keep the medoid run (consensus.py): on weakly connected rigs one sample's outcome is a
    # lottery. They stop after 2 runs that agree (multistart.agreement_deg), after 1 where its
    # focal multi-start settled and it registered every camera (pipeline._consensus_runs).
    # 1 = a single run.
    consensus_runs: int = 5
    # With these matchers, frame sets after the first are matched only where a camera's image
    # shows what its earlier frame sets did not (core/method/new_content.py): asift costs tens of
    # times sift per frame set and its first set already holds about ten times sift's matches of
    # the static scene; sift matches every frame set whole, as its repeated detections of the
    # static scene average their noise (docs/design-notes.md, Later frame sets: only what is new).
    new_content_matchers: tuple = ("asift",)
    # Refine the found rig once more on every keypoint match (all_matches.py; keypoint matchers
    # only): the sampled tracks find the rig, all the matches it agrees with refine it.
    refine_on_all_matches: bool = True
    # Refine the kept rig last on dense correspondences measured in the images, with priors on
    # the principal point and pixel aspect (core.method.image_refinement; perspective lenses).
    refine_on_images: bool = True
    # Find burnt-in info strips (a trail camera's bar of date and temperature along the top or
    # bottom edge) and ignore their rows, for the cameras without a mask (CameraData.masks)
    # (core/method/info_strip.py): their glyphs match across cameras and fit no geometry.
    detect_info_strips: bool = True
    # What the user knows about the cameras, apart from how to calibrate them.
    cameras: CameraData = field(default_factory=CameraData)
    sampling: SamplingConfig = field(default_factory=SamplingConfig)
    sfm: SfMConfig = field(default_factory=SfMConfig)
    # The cameras the configuration was resolved for (for_cameras); () before: then the per-camera
    # options (sfm.camera_models, sfm.fixed_intrinsics_cameras) are not filled in yet.
    camera_names: tuple = ()

    def with_options(self, **options) -> "PipelineConfig":
        """A copy with `options` set: `section__field=value` (sampling__seed=1) or top-level
        fields (matcher="asift"); InputError naming an unknown option."""
        return _with_options(self, options)

    def for_cameras(self, camera_names: Sequence[str]) -> "PipelineConfig":
        """This configuration resolved for these cameras (resolve_camera_lenses: each camera's
        model, the cameras with given intrinsics) and checked (check): what a calibration reads
        from its start on. A configuration resolved for these cameras already is returned as it
        is. InputError on unknown cameras, lenses or invalid values."""
        names = tuple(camera_names)
        if self.camera_names == names:
            return self
        if self.camera_names:
            raise InputError(f"This configuration was resolved for the cameras "
                             f"{', '.join(self.camera_names)}, not {', '.join(names)}: resolve "
                             "the one made by make_config for these cameras instead.")
        resolved = resolve_camera_lenses(self, names)
        resolved = replace(resolved, camera_names=names, sfm=replace(
            resolved.sfm, shared_intrinsics_groups=_unit_groups(resolved, names)))
        resolved.check()
        return resolved

    def check(self) -> None:
        """InputError naming the first option whose value no calibration can run with (COLMAP's
        options' Check())."""
        _check_config(self)


PRESETS = ("regular", "fisheye")
# Lens -> the initial COLMAP model of a camera with it (the presets' models).
LENS_MODELS = {"pinhole": "RADIAL", "fisheye": "RADIAL_FISHEYE"}
PIPELINES = ("incremental", "global")
GLOBAL_INITS = ("rotation_averaging", "previous", "incremental")
# The pipeline the CLI, node and demo use unless told otherwise: the incremental one measured more
# accurate on pinhole rigs and repeatable run to run (docs/design-notes.md, Default pipeline).
DEFAULT_PIPELINE = "incremental"


# What each pipeline sets on the defaults (section__field: value): the global pipeline samples
# on a finer grid, scoring the best pair only, probabilistically, and has no B_err.
PIPELINE_OPTIONS = {
    "incremental": {},
    "global": {"sampling__cell_size_px": 40, "sampling__top_k": 1,
               "sampling__probabilistic_scoring": True, "sfm__b_err_px": None},
}


def preset_options(preset: str, pipeline: str) -> dict:
    """What a preset sets on the defaults for a pipeline (section__field: value; a dict value
    updates the default dict). fisheye: the fisheye lens model refined to OPENCV_FISHEYE, F_err
    off (a fisheye pair breaks the pinhole epipolar constraint), the principal point refined,
    B_err 100 px in the incremental pipeline (room for the rough early distortion), more global
    BA iterations for the distortion, principal point and model stages."""
    if preset != "fisheye":
        return {}
    return {"sfm__camera_model": LENS_MODELS["fisheye"], "sfm__refine_to_model": "OPENCV_FISHEYE",
            "sfm__f_err_px": None, "sfm__refine_principal_point": True,
            "sfm__b_err_px": B_ERR_PX["fisheye"] if pipeline == "incremental" else None,
            "sfm__global_stage_iterations": {"distortion": 200, "principal_point": 100,
                                             "model": 100}}


def make_config(preset: str = "regular", pipeline: str = "incremental",
                matcher: Optional[str] = None, **overrides) -> PipelineConfig:
    """Build the configuration of a named preset and pipeline (PIPELINE_OPTIONS, then
    preset_options, on the defaults); `overrides` are `section__field=value` (e.g.
    sampling__cell_size_px=40) or top-level fields."""
    if preset not in PRESETS:
        raise InputError(f"Unknown preset {preset!r}: choose one of {', '.join(PRESETS)}.")
    if pipeline not in PIPELINES:
        raise InputError(f"Unknown pipeline {pipeline!r}: choose one of {', '.join(PIPELINES)}.")
    cfg = PipelineConfig(preset=preset, pipeline=pipeline)
    if matcher is not None:
        cfg = replace(cfg, matcher=matcher)
    cfg = _with_options(cfg, _merged_dicts(cfg, {**PIPELINE_OPTIONS[pipeline],
                                                 **preset_options(preset, pipeline)}))
    return _with_options(cfg, overrides)


def _merged_dicts(cfg: PipelineConfig, options: dict) -> dict:
    """A preset's or pipeline's options, a dict option merged into the dict it names."""
    out = {}
    for key, value in options.items():
        if isinstance(value, dict):
            section, name = key.split("__", 1)
            value = {**getattr(getattr(cfg, section), name), **value}
        out[key] = value
    return out


def _with_options(cfg: PipelineConfig, options: dict) -> PipelineConfig:
    """cfg with `options` (section__field or top-level names) set, each value a deep copy."""
    top, sections = {}, {}
    for key, value in options.items():
        section, _, name = key.rpartition("__")
        target = getattr(cfg, section, None) if section else cfg
        if section and not is_dataclass(target):
            raise InputError(f"Unknown configuration section {section!r} in {key!r}.")
        valid = {f.name for f in fields(target)}
        if name not in valid:
            raise InputError(f"Unknown option {key!r}: valid options are "
                             f"{', '.join(sorted(valid))}.")
        (sections.setdefault(section, {}) if section else top)[name] = copy.deepcopy(value)
    for section, values in sections.items():
        top[section] = replace(top.get(section, getattr(cfg, section)), **values)
    return replace(cfg, **top) if top else cfg


def lens_of_model(model: str) -> str:
    return "fisheye" if "FISHEYE" in model.upper() else "pinhole"


def resolve_camera_lenses(config: PipelineConfig, camera_names: Sequence[str]) -> PipelineConfig:
    """`config` for these cameras (for_cameras' first step): without config.cameras.lens or given
    intrinsics, itself. Otherwise a copy whose sfm.camera_models gives every camera its lens's
    model (cameras not named keep the preset's lens) and which, when any camera is fisheye, runs
    with the fisheye preset's SfM options: F_err off (a fisheye pair breaks the pinhole epipolar
    constraint), B_err 100 px while the fisheye distortion is still rough, the principal point
    refined and the fisheye cameras refined to OPENCV_FISHEYE; pinhole cameras stay RADIAL, their
    observations judged by the regular preset's B_err, and a pair of two pinhole cameras by its
    F_err (SfMConfig.pinhole_b_err_px, pinhole_f_err_px). InputError on unknown cameras or lenses.

    Cameras of config.cameras.known_intrinsics get their model (a lens differing from the preset's
    makes a rig mixing lenses) and are listed in sfm.fixed_intrinsics_cameras."""
    known = dict(config.cameras.known_intrinsics or {})
    lenses = dict(config.cameras.lens or {})
    if config.sfm.camera_models or (not lenses and not known):
        return config
    unknown = sorted((set(lenses) | set(known)) - set(camera_names))
    if unknown:
        raise InputError(f"Lens or intrinsics given for unknown camera(s) {', '.join(unknown)}: "
                         f"the cameras are {', '.join(camera_names)} (an intrinsics file names "
                         "its camera with NAME=PATH).")
    clash = sorted(n for n in set(lenses) & set(known) if lenses[n] != lens_of_model(known[n].model))
    if clash:
        raise InputError(f"Camera(s) {', '.join(clash)}: the given intrinsics are of another lens "
                         "than --lens says; leave out --lens for cameras with given intrinsics.")
    lenses.update({n: lens_of_model(cam.model) for n, cam in known.items()})
    bad = {k: v for k, v in lenses.items() if v not in LENS_MODELS}
    if bad:
        raise InputError(f"Unknown lens {bad}: use {' or '.join(LENS_MODELS)} "
                         "(e.g. --lens cam3=fisheye).")
    out = config
    preset_lens = lens_of_model(config.sfm.camera_model)
    per_camera = [lenses.get(n, preset_lens) for n in camera_names]
    if "fisheye" in per_camera and preset_lens == "pinhole":
        out = _with_options(out, _merged_dicts(out, preset_options("fisheye", config.pipeline)))
    mixed = {}
    if len(set(per_camera)) > 1:
        # The fisheye B_err (100 px) leaves room for the rough early fisheye models; a pinhole
        # camera's outliers are judged as in the regular preset. (B_err 20 px for every camera
        # also removed the focal drift incremental.final_adjustment describes on a 4-camera rig,
        # but would cut the fisheye cameras' early observations; this alone did not.)
        regular = make_config("regular", config.pipeline).sfm
        mixed = {"sfm__pinhole_b_err_px": regular.b_err_px,
                 "sfm__pinhole_f_err_px": regular.f_err_px}
    # Cameras of the preset's lens keep its (possibly user-set) model; given intrinsics, theirs.
    return _with_options(out, {**mixed, "sfm__camera_models": tuple(
        known[n].model if n in known else
        config.sfm.camera_model if lens == preset_lens else LENS_MODELS[lens]
        for n, lens in zip(camera_names, per_camera)),
        "sfm__fixed_intrinsics_cameras": tuple(c for c, n in enumerate(camera_names)
                                               if n in known)})


def _unit_groups(config: PipelineConfig, camera_names: Sequence[str]) -> tuple:
    """CameraData.identical_units as groups of camera indices of one model each (cameras with
    given intrinsics left out: they keep theirs); InputError on unknown or repeated cameras."""
    groups, seen = [], set()
    for names, _ in config.cameras.identical_units:
        unknown = sorted(set(names) - set(camera_names))
        twice = sorted(set(names) & seen)
        if unknown or twice:
            raise InputError(f"Identical units {', '.join(names)}: "
                             + (f"{', '.join(unknown)} not among the cameras "
                                f"{', '.join(camera_names)}" if unknown else
                                f"{', '.join(twice)} in two groups") + ".")
        seen |= set(names)
        members = tuple(camera_names.index(n) for n in names
                        if n not in config.cameras.known_intrinsics)
        if len({config.sfm.model_of(c) for c in members}) > 1:
            raise InputError(f"Identical units {', '.join(names)} have different lenses (--lens): "
                             "units of one camera model have one lens.")
        if len(members) >= 2:
            groups.append(tuple(sorted(members)))
    return tuple(groups)


def _check_config(cfg: PipelineConfig) -> None:
    """PipelineConfig.check: each option within what the stages can run with."""
    from .types import colmap_model_id  # pycolmap's model names, on use only

    s, m = cfg.sampling, cfg.sfm
    rules = [
        ("preset", cfg.preset in PRESETS, f"one of {', '.join(PRESETS)}"),
        ("pipeline", cfg.pipeline in PIPELINES, f"one of {', '.join(PIPELINES)}"),
        ("max_image_side_px", _int(cfg.max_image_side_px) and cfg.max_image_side_px >= 64,
         "an integer of at least 64 px"),
        ("consensus_runs", _int(cfg.consensus_runs) and cfg.consensus_runs >= 1,
         "an integer of at least 1"),
        ("sampling__max_cycle_order", s.max_cycle_order in (2, 3, 4), "2, 3 or 4"),
        ("sampling__fine_cell_px", _int(s.fine_cell_px) and s.fine_cell_px >= 1, "an integer >= 1"),
        ("sampling__cell_size_px", _int(s.cell_size_px) and s.cell_size_px >= s.fine_cell_px,
         "an integer no smaller than fine_cell_px"),
        ("sampling__c_min", _number(s.c_min) and 0 < s.c_min <= 1, "in (0, 1]"),
        ("sampling__samples_per_order", set(s.samples_per_order) <= {2, 3, 4} and all(
            _int(v) and v >= 0 for v in s.samples_per_order.values()),
         "{order: count} with orders 2-4 and counts >= 0"),
        ("sampling__top_k", _int(s.top_k) and s.top_k >= 0, "an integer >= 0"),
        ("sampling__seed", _int(s.seed) and s.seed >= 0, "an integer >= 0"),
        ("sfm__f_err_px", _positive_or_none(m.f_err_px), "a positive number or None (off)"),
        ("sfm__b_err_px", _positive_or_none(m.b_err_px), "a positive number or None (off)"),
        ("sfm__ba_iterations", _int(m.ba_iterations) and m.ba_iterations >= 1, "an integer >= 1"),
        ("sfm__global_init", m.global_init in GLOBAL_INITS, f"one of {', '.join(GLOBAL_INITS)}"),
        ("sfm__num_threads", _int(m.num_threads) and m.num_threads >= -1,
         "-1 (every core) or a number of cores"),
    ]
    for name, ok, expected in rules:
        if not ok:
            value = _option_value(cfg, name)
            raise InputError(f"Option {name} = {value!r}: expected {expected}.")
    for model in (m.camera_model, *m.camera_models, *([m.refine_to_model] if m.refine_to_model
                                                       else [])):
        colmap_model_id(model)


def _int(value) -> bool:
    return isinstance(value, numbers.Integral) and not isinstance(value, bool)


def _number(value) -> bool:
    return isinstance(value, numbers.Real) and not isinstance(value, bool) and \
        math.isfinite(value)


def _positive_or_none(value) -> bool:
    return value is None or (_number(value) and value > 0)


def _option_value(cfg: PipelineConfig, name: str):
    section, _, field_name = name.rpartition("__")
    return getattr(getattr(cfg, section) if section else cfg, field_name)
