"""The calibration pipeline end to end: frame sets -> matches -> sampled tracks -> two-view
geometry, F_err filter, initial focals -> SfM (incremental or global) -> RigCalibration.

Rig frame: the reference camera is the first camera of `camera_names` that was registered, so the
rig frame stays the same camera across recalibrations (unless that camera fails). Translations
are scaled so that the median distance of the other cameras from the reference camera is 1
(the reconstruction has no metric scale).
"""
from __future__ import annotations

import copy
import logging
import time
from dataclasses import dataclass, field, replace
from typing import Callable, Optional, Sequence

import numpy as np
import pycolmap

from .all_matches import keypoint_tracks, refine_on_tracks
from .config import PipelineConfig, resolve_camera_lenses
from .errors import (CalibrationError, FocalInitError, InputError, NotEnoughCamerasError,
                     NotEnoughOverlapError, TooFewCamerasGivenError)
from .focal import estimate_initial_focals
from .focal_determination import weak_focal_warning
from .incremental import MULTISTART_MAX_TRACKS, initial_intrinsics, run_incremental
from .known_intrinsics import (check_known_intrinsics, describe as describe_known,
                               given_intrinsics_fit, given_intrinsics_warnings)
from .frame_checks import check_frame_sets
from .masks import ignored_regions, info_strips
from .placement import repair_placements
from .progress import Progress, say_progress
from .reconstruction import (SfMState, build_reconstruction, camera_quality, colour_points,
                             reprojection_errors)
from .scale import move_model_to_rig_frame
from .twoview import (F_THRESHOLD_PX, MIN_CORRESPONDENCES, estimate_fundamental, pair_weights,
                      symmetric_epipolar_distance_px)
from .types import CameraIntrinsics, RigCalibration, RigCamera, Tracks
from .uncertainty import HELD_PP_STD_FRACTION, calibration_uncertainty

log = logging.getLogger(__name__)


@dataclass
class CalibrationResult:
    """A calibrated rig plus what produced it.

    reconstruction: the final pycolmap Reconstruction (one image per registered camera, named by
    camera), in the rig frame and the rig's units (its image poses are the cameras' cam_from_rig),
    for export as a COLMAP model."""

    rig: RigCalibration
    reconstruction: pycolmap.Reconstruction
    tracks: Tracks  # the tracks SfM ran on (after the F_err filter)
    focal_init_px: np.ndarray  # (C,) initial focal lengths
    stats: dict = field(default_factory=dict)
    # The final SfM state (on the keypoint-match tracks when the rig was refined on them): what
    # a later search (core.focal_hops) continues from.
    state: Optional[SfMState] = None


def fundamental_matrices(tracks: Tracks, seed: int = 0) -> dict:
    """{(i, j): TwoViewGeometry} for every camera pair i < j sharing >= 15 tracks (F_ji with
    x_j^T F_ji x_i = 0 on COLMAP px)."""
    obs = tracks.observed()
    out = {}
    for i in range(tracks.num_cameras):
        for j in range(i + 1, tracks.num_cameras):
            rows = np.flatnonzero(obs[:, i] & obs[:, j])
            if len(rows) >= MIN_CORRESPONDENCES:
                geom = estimate_fundamental(tracks.xy_px[rows, i], tracks.xy_px[rows, j],
                                            F_THRESHOLD_PX, seed=seed)
                if geom.F_ji is not None:
                    out[(i, j)] = geom
    return out


def epipolar_filter(tracks: Tracks, two_view: dict,
                    f_err_px: Callable[[int, int], Optional[float]]) -> Tracks:
    """Drop tracks with any observation pair (i, j) farther than f_err_px(i, j) from its epipolar
    line (symmetric point-to-line distance, the paper's F_err; None: that pair is not tested).
    Tracks are cycle-consistent, so a pair that fails the test makes the whole track suspect."""
    obs = tracks.observed()
    bad = np.zeros(tracks.num_tracks, dtype=bool)
    for (i, j), geom in two_view.items():
        threshold = f_err_px(i, j)
        if geom.F_ji is None or threshold is None:
            continue
        rows = np.flatnonzero(obs[:, i] & obs[:, j])
        d = symmetric_epipolar_distance_px(geom.F_ji, tracks.xy_px[rows, i], tracks.xy_px[rows, j])
        bad[rows[d > threshold]] = True
    return tracks.subset(~bad) if bad.any() else tracks


def initial_focals(tracks: Tracks, two_view: dict, image_sizes: Sequence[tuple[int, int]]
                   ) -> np.ndarray:
    """(C,) focal px from the pairs' fundamental matrices (paper eq. 2), pair weight = number of
    common tracks / the largest number."""
    obs = tracks.observed()
    counts = {k: int(np.sum(obs[:, k[0]] & obs[:, k[1]])) for k, g in two_view.items()
              if g.F_ji is not None}
    F = {k: two_view[k].F_ji for k in counts}
    return estimate_initial_focals(F, pair_weights(counts), list(image_sizes))


def rig_from_state(state: SfMState, camera_names: Sequence[str], failed: Sequence[int],
                   quality: Optional[dict] = None) -> RigCalibration:
    """The registered cameras of `state` as a RigCalibration (module docstring: reference camera
    and scale). Raises NotEnoughCamerasError with fewer than two registered cameras."""
    registered = state.registered()
    if len(registered) < 2:
        raise NotEnoughCamerasError(
            f"Only {len(registered)} camera(s) could be registered "
            f"({', '.join(camera_names[c] for c in registered) or 'none'}): a rig needs two. "
            "Check that the cameras overlap and see textured scene content.")
    ref = registered[0]
    rig_from_world = state.cam_from_world[ref]
    world_from_rig = np.linalg.inv(rig_from_world)
    cam_from_rig = {c: state.cam_from_world[c] @ world_from_rig for c in registered}
    dist = [np.linalg.norm(np.linalg.inv(T)[:3, 3]) for c, T in cam_from_rig.items() if c != ref]
    scale = 1.0 / np.median(dist) if np.median(dist) > 0 else 1.0
    errors = reprojection_errors(state)
    cameras = {}
    for c in registered:
        T = cam_from_rig[c].copy()
        T[:3, 3] *= scale
        cameras[camera_names[c]] = RigCamera(camera_names[c], state.camera(c), T,
                                             camera_quality(state, c, errors))
    finite = errors[np.isfinite(errors)]
    overall = dict(quality or {})
    overall.update(
        reprojection_rms_px=float(np.sqrt(np.mean(finite ** 2))) if len(finite) else float("nan"),
        num_points=int(state.point_mask().sum()), num_observations=int(len(finite)),
        num_registered=len(registered), num_cameras=state.num_cameras)
    return RigCalibration(reference_camera=camera_names[ref], cameras=cameras,
                          failed_cameras=[camera_names[c] for c in sorted(failed)],
                          quality=overall)


def calibrate_from_tracks(tracks: Tracks, image_sizes: Sequence[tuple[int, int]],
                          camera_names: Sequence[str], config: PipelineConfig, *,
                          two_view: Optional[dict] = None, focal_px: Optional[np.ndarray] = None,
                          previous: Optional[RigCalibration] = None,
                          match_tracks: Optional[Tracks] = None,
                          known_focals: bool = False,
                          progress: Progress = None) -> CalibrationResult:
    """Calibrate from sampled tracks.

    tracks: (T, C, 2) COLMAP px; image_sizes: (width, height) per camera; two_view: {(i, j):
    TwoViewGeometry} (estimated here from the tracks when None); focal_px: (C,) initial focal
    lengths (estimated from the F's when None); previous: the calibration the global pipeline
    starts from when config.sfm.global_init is "previous" (recalibration); match_tracks: every
    keypoint match as tracks (all_matches.keypoint_tracks), on which the incremental focal
    multi-start and the global pipeline's choice of start are judged (a seeded sample) and the
    found rig is refined last, after cameras the matches contradict are moved (placement.py)
    (None: none of these); known_focals: focal_px are known ones (the user's, EXIF), not eq. 2's.

    Known focals add a start to the SfM's focal multi-start; they do not take the eq. 2 start's
    place. The path SfM takes depends on the start, not only on how close it is: from the true
    focals (no distortion yet) a 3-camera rig 40 deg apart chose another first pair, whose
    relative pose the unmodelled distortion had turned 11 deg, and ended wrong (AUC@3 22); from
    eq. 2's focals, 3-32 % short, it ended right (100), and fitted all matches better."""
    start = time.perf_counter()
    C = len(camera_names)
    config = resolve_camera_lenses(config, camera_names)
    if tracks.num_cameras != C or len(image_sizes) != C:
        raise InputError(f"{C} camera names but tracks for {tracks.num_cameras} cameras and "
                         f"{len(image_sizes)} image sizes.")
    if C < 2:
        raise TooFewCamerasGivenError(f"A rig needs at least two cameras, got {C}.")
    if tracks.num_tracks == 0:
        raise NotEnoughOverlapError(
            "No correspondences survived cycle sampling: the cameras' views do not overlap enough "
            "or the scene lacks texture. Point the cameras at a shared, textured scene or add "
            "frame sets.")
    seed = config.sampling.seed
    if two_view is None or (config.sfm.f_err_px is not None and
                            not any(g.F_ji is not None for g in two_view.values())):
        two_view = fundamental_matrices(tracks, seed)
    _check_one_group(two_view, camera_names)
    filtered = epipolar_filter(tracks, two_view, config.sfm.pair_f_err_px)
    if config.sfm.f_err_px is not None:
        f_err = f"{config.sfm.f_err_px} px"
    elif config.sfm.pinhole_f_err_px is not None and \
            len(config.sfm.mixed_rig_pinhole_cameras(C)) >= 2:
        f_err = f"{config.sfm.pinhole_f_err_px} px between pinhole cameras"
    else:
        f_err = "off"
    say_progress(progress, f"{filtered.num_tracks} of {tracks.num_tracks} tracks pass the epipolar "
                           f"filter (F_err {f_err})")
    if focal_px is None:
        focal_px = initial_focals(filtered, two_view, image_sizes)
    focal_px = np.asarray(focal_px, dtype=np.float64)
    say_progress(progress, "initial focals [px]: " + ", ".join(
        f"{n}={f:.0f}" for n, f in zip(camera_names, focal_px)))
    init = with_known_intrinsics(initial_intrinsics(image_sizes, focal_px, config.sfm.models(C)),
                                 config, camera_names)
    extra_starts = _eq2_start(filtered, two_view, image_sizes, config, camera_names, progress) \
        if known_focals else None
    validation = None
    if match_tracks is not None and match_tracks.num_tracks:
        validation = match_tracks.sample(MULTISTART_MAX_TRACKS, seed)
    if config.pipeline == "global":
        from .global_sfm import run_global
        sfm = run_global(filtered, init, camera_names, config.sfm, seed=seed, progress=progress,
                         previous=previous, validation_tracks=validation,
                         extra_starts=extra_starts)
    else:
        sfm = run_incremental(filtered, init, camera_names, config.sfm, seed=seed,
                              progress=progress, validation_tracks=validation,
                              extra_starts=extra_starts)
    state = sfm.state
    moved: list[str] = []
    if match_tracks is not None and match_tracks.num_tracks:
        state = state.on_tracks(match_tracks)
        moved = repair_placements(state, camera_names, lambda m: say_progress(progress, m))
        state = refine_on_tracks(state, match_tracks, camera_names, config.sfm, seed)
        say_progress(progress, f"refined on all {match_tracks.num_tracks} keypoint-match tracks: "
                               f"{int(state.point_mask().sum())} points")
    fit = given_intrinsics_fit(state, camera_names, config.sfm.num_threads)
    runtime = time.perf_counter() - start
    rig = rig_from_state(state, camera_names, sfm.failed, dict(
        pipeline=config.pipeline, preset=config.preset, sfm_runtime_s=runtime,
        view_order=[camera_names[c] for c in sfm.view_order],
        match_tracks=0 if match_tracks is None else match_tracks.num_tracks,
        moved_cameras=moved))
    if config.pipeline == "global":
        rig.quality.update(sfm.quality)  # init, gauge camera, residuals per BA stage
    if fit:
        rig.quality["given_intrinsics_fit"] = fit  # judged in calibrate_from_matches
    reconstruction = _saved_model(state, camera_names, rig)
    say_progress(progress, f"registered {len(rig.cameras)}/{C} cameras, reprojection RMS "
                   f"{rig.quality['reprojection_rms_px']:.2f} px, {rig.quality['num_points']} "
                   f"points ({runtime:.1f} s)")
    return CalibrationResult(rig=rig, reconstruction=reconstruction, tracks=filtered,
                             focal_init_px=focal_px, state=state)


def _check_one_group(two_view: dict, camera_names: Sequence[str]) -> None:
    """DisconnectedViewGraphError when the cameras form two or more groups of at least two that
    share no two-view geometry: SfM would calibrate one group (which one, by chance) and call the
    others failed. A lone camera without geometry is left to fail on its own (named failed)."""
    from .global_sfm import connected_components, disconnected_error

    edges = [k for k, g in two_view.items() if g.F_ji is not None]
    groups = connected_components(len(camera_names), edges)
    if sum(len(g) >= 2 for g in groups) > 1:
        raise disconnected_error(groups, camera_names, "two-view geometry")


def _eq2_start(tracks: Tracks, two_view: dict, image_sizes: Sequence[tuple[int, int]],
               config: PipelineConfig, camera_names: Sequence[str],
               progress: Progress) -> Optional[dict]:
    """{"eq. 2": intrinsics at the eq. 2 focals} where they can be estimated (every camera
    perspective, not every camera's intrinsics given), else None."""
    models = config.sfm.models(len(image_sizes))
    if any("FISHEYE" in m for m in models) or \
            len(config.sfm.fixed_intrinsics_cameras) == len(image_sizes):
        return None
    try:
        focal = initial_focals(tracks, two_view, image_sizes)
    except FocalInitError as exc:
        say_progress(progress, f"no eq. 2 start beside the known focals: {exc}")
        return None
    return {"eq. 2": with_known_intrinsics(initial_intrinsics(image_sizes, focal, models),
                                           config, camera_names)}


def with_known_intrinsics(intrinsics: Sequence[CameraIntrinsics], config: PipelineConfig,
                          camera_names: Sequence[str]) -> list[CameraIntrinsics]:
    """`intrinsics` with the cameras of config.known_intrinsics at their given values."""
    known = config.known_intrinsics or {}
    return [known.get(n, cam) for n, cam in zip(camera_names, intrinsics)]


def _known_focals(config: PipelineConfig, camera_names: Sequence[str]) -> dict[str, float]:
    """The mean focal [px] of every camera with given intrinsics."""
    return {n: float(cam.to_pycolmap().mean_focal_length())
            for n, cam in (config.known_intrinsics or {}).items() if n in camera_names}


def start_focals(config: PipelineConfig, previous: Optional[RigCalibration],
                 camera_names: Sequence[str], image_sizes: Sequence[tuple[int, int]]
                 ) -> Optional[np.ndarray]:
    """(C,) focal px the calibration starts from instead of estimating them, or None. Per camera,
    first found: the user's config.initial_focal_px, a previous calibration's focal, the images'
    EXIF focal (config.exif_focal_px). NaN for a camera only EXIF could have named and did not:
    its focal is estimated (sampling.sample_tracks). InputError when the user's focals name
    unknown cameras, are not positive, or leave a camera without a focal. Given intrinsics
    (config.known_intrinsics) override all of these for their cameras."""
    focal = _start_focals(config, previous, camera_names, image_sizes)
    known = _known_focals(config, camera_names)
    if not known:
        return focal
    out = np.full(len(camera_names), np.nan) if focal is None else focal.astype(np.float64)
    for c, name in enumerate(camera_names):
        out[c] = known.get(name, out[c])
    return out


def _start_focals(config: PipelineConfig, previous: Optional[RigCalibration],
                  camera_names: Sequence[str], image_sizes: Sequence[tuple[int, int]]
                  ) -> Optional[np.ndarray]:
    hint = dict(config.initial_focal_px or {})
    exif = {k: v for k, v in (config.exif_focal_px or {}).items() if k in camera_names}
    focal = _previous_focals(previous, camera_names, image_sizes)
    if not hint and not exif:
        return focal
    unknown = sorted(set(hint) - set(camera_names) - {"*"})
    if unknown:
        raise InputError(f"Initial focal lengths given for unknown camera(s) {', '.join(unknown)}: "
                         f"the cameras are {', '.join(camera_names)} (or use '*' for all).")
    bad = {k: v for k, v in hint.items() if not (np.isfinite(float(v)) and float(v) > 0)}
    if bad:
        raise InputError(f"Initial focal lengths must be positive pixel values, got {bad}.")
    from .plausibility import MAX_FOCAL_IMAGE_RATIO, MIN_FOCAL_IMAGE_RATIO
    for name, size in zip(camera_names, image_sizes):
        value = hint.get(name, hint.get("*"))
        if value is not None and not (MIN_FOCAL_IMAGE_RATIO <= float(value) / max(size)
                                      <= MAX_FOCAL_IMAGE_RATIO):
            raise InputError(
                f"The focal length given for camera {name}, {float(value):g} px, is not a lens "
                f"of its {size[0]}x{size[1]} images (a plausible one is "
                f"{MIN_FOCAL_IMAGE_RATIO:g}-{MAX_FOCAL_IMAGE_RATIO:g}x the long side, "
                f"{MIN_FOCAL_IMAGE_RATIO * max(size):.0f}-{MAX_FOCAL_IMAGE_RATIO * max(size):.0f} "
                "px): give it in pixels (focal mm / pixel pitch mm).")
    out = np.full(len(camera_names), np.nan) if focal is None else focal.astype(np.float64)
    for c, name in enumerate(camera_names):
        value = hint.get(name, hint.get("*"))
        if value is not None:
            out[c] = float(value)
        elif not np.isfinite(out[c]) and name in exif:
            out[c] = float(exif[name])
    missing = [n for n, f in zip(camera_names, out) if not np.isfinite(f)]
    missing = [n for n in missing if n not in _known_focals(config, camera_names)]
    if missing and hint:
        raise InputError(f"No initial focal length for camera(s) {', '.join(missing)}: give one "
                         "per camera, or one for all ('*': --focal-px 800, or initial_focal_px "
                         "{'*': 800.0} in PipelineConfig).")
    return out


def _previous_focals(previous: Optional[RigCalibration], camera_names: Sequence[str],
                     image_sizes: Sequence[tuple[int, int]]) -> Optional[np.ndarray]:
    """Focal lengths of a previous calibration when it has every camera at the same size."""
    if previous is None:
        return None
    focals = []
    for name, (w, h) in zip(camera_names, image_sizes):
        cam = previous.cameras.get(name)
        if cam is None or (cam.intrinsics.width, cam.intrinsics.height) != (w, h):
            return None
        p = cam.intrinsics.params
        two_focals = cam.intrinsics.model in ("PINHOLE", "OPENCV", "OPENCV_FISHEYE", "FULL_OPENCV")
        focals.append(0.5 * (p[0] + p[1]) if two_focals else p[0])
    return np.array(focals)


def match_frame_sets(frame_sets: Sequence[Sequence[np.ndarray]], config: PipelineConfig, *,
                     matcher=None, progress: Progress = None,
                     camera_names: Optional[Sequence[str]] = None,
                     strips: Optional[dict] = None, ignored: Optional[list] = None) -> list:
    """One SiteMatchSet per frame set. matcher: an already loaded core.matching.Matcher to reuse
    (else config.matcher is created and loaded here). With config.camera_masks (then
    camera_names is needed), matches on masked regions are dropped (core.masks), and on the
    info strips found (`strips` as info_strips gives them; None: looked for here); `ignored`:
    those regions as ignored_regions gives them, when already resolved."""
    from .masks import apply_masks
    from .matching import create_matcher

    if ignored is None:
        if strips is None:
            strips = info_strips(frame_sets, camera_names, config)
        ignored = ignored_regions(frame_sets, camera_names, config, strips)

    if matcher is None:
        matcher = create_matcher(config.matcher, max_image_side_px=config.max_image_side_px)
        matcher.load()
    match_sets = []
    for t, frames in enumerate(frame_sets):
        match_sets.append(matcher.match(list(frames)))
        if ignored:
            log.debug("frame set %d: %d match(es) on masked regions dropped", t,
                      apply_masks(match_sets[-1], ignored))
        say_progress(progress, f"matched frame set {t + 1}/{len(frame_sets)} ({config.matcher})")
    return match_sets


def calibrate_from_matches(match_sets: list, image_sizes: Sequence[tuple[int, int]],
                           camera_names: Sequence[str], config: PipelineConfig, *,
                           previous: Optional[RigCalibration] = None,
                           frame_sets: Optional[Sequence[Sequence[np.ndarray]]] = None,
                           ignored: Sequence = (),
                           progress: Progress = None) -> CalibrationResult:
    """Sample tracks from the matches and calibrate. With config.sfm.global_init == "previous",
    the previous calibration's poses and intrinsics also give the triangulation angles that score
    the samples (paper Sec. 3.2, refinement case); otherwise only its focals are reused.
    config.camera_lens gives cameras another lens than the preset's (config.resolve_camera_lenses).

    A fresh calibration (no previous) with config.consensus_runs > 1 repeats sampling + SfM with
    consecutive seeds and returns the medoid run (core.consensus); its quality records the runs'
    disagreement. Runs that fail are skipped; if all fail, the first run's error is raised.

    With config.refine_on_all_matches and a keypoint matcher, every run's rig is refined last on
    all the matches (core.all_matches). With the images (frame_sets, as matched) and
    config.refine_on_images, the kept rig is refined once more on dense correspondences measured
    in them (core.image_refinement), away from the `ignored` regions (ignored_regions)."""
    config = resolve_camera_lenses(config, camera_names)
    config = replace(config, known_intrinsics=check_known_intrinsics(
        config.known_intrinsics or {}, camera_names, image_sizes))
    match_tracks = None
    if config.refine_on_all_matches:
        match_tracks = keypoint_tracks(match_sets, len(camera_names), seed=config.sampling.seed)
    if previous is None and config.consensus_runs > 1:
        result = _consensus_calibration(match_sets, image_sizes, camera_names, config,
                                        match_tracks, progress)
    else:
        result = _calibrate_once(match_sets, image_sizes, camera_names, config, previous,
                                 match_tracks, progress)
    sigmas = {}
    if frame_sets is not None and config.refine_on_images and result.state is not None:
        result, sigmas = _refined_on_images(result, frame_sets, camera_names, config,
                                            match_tracks, ignored, progress, previous)
    add_uncertainty(result, camera_names, config, sigmas)
    if config.known_intrinsics:
        result.rig.quality["given_intrinsics"] = describe_known(config.known_intrinsics)
        for warning in given_intrinsics_warnings(result.rig.quality.get("given_intrinsics_fit",
                                                                        {})):
            warn_user(result.rig, warning, progress)
    warning = weak_focal_warning(result.rig)
    if warning:
        warn_user(result.rig, warning, progress)
    return result


def warn_user(rig: RigCalibration, warning: str, progress: Progress) -> None:
    """Log a warning, pass it to progress and keep it in rig.quality["warnings"]: the node's
    service reply and `densecalib report` show it to whoever looks at the calibration later."""
    log.warning("%s", warning)
    if progress is not None:
        progress(warning)
    rig.quality.setdefault("warnings", []).append(warning)


def _refined_on_images(result: CalibrationResult, frame_sets, camera_names: Sequence[str],
                       config: PipelineConfig, match_tracks: Optional[Tracks],
                       ignored: Sequence, progress: Progress,
                       previous: Optional[RigCalibration] = None
                       ) -> tuple[CalibrationResult, dict]:
    """(result refined by core.image_refinement, its sigmas per camera name); the result as it
    was and no sigmas where the stage does not apply. A previous calibration's principal points
    that its images determined centre this one's priors."""
    from .image_refinement import PP_PRIOR_STD_FRACTION, refine_on_images

    seeds = match_tracks if match_tracks is not None and match_tracks.num_tracks \
        else result.tracks
    refinement = refine_on_images(result.state, frame_sets, seeds, camera_names, ignored or None,
                                  config.sampling.seed, lambda m: say_progress(progress, m),
                                  estimated_principal_points(previous))
    if refinement is None:
        return result, {}
    # Whether given intrinsics fit the scene was judged on the keypoint matches; the dense
    # correspondences were gated against them already.
    given_fit = result.rig.quality.get("given_intrinsics_fit")
    result = _with_state(result, refinement.state, camera_names, config)
    if given_fit is not None:
        result.rig.quality["given_intrinsics_fit"] = given_fit
    result.rig.quality.update(
        image_refinement_tracks=refinement.num_tracks,
        image_refinement_noise_px=round(refinement.adjustment.noise_px, 4),
        principal_point_prior_std_fraction=PP_PRIOR_STD_FRACTION)
    for name, cam in result.rig.cameras.items():
        if name in refinement.estimated and cam.quality is not None:
            cam.quality.estimated_intrinsics = refinement.estimated[name]
    return result, refinement.uncertainty


def estimated_principal_points(rig: Optional[RigCalibration]) -> dict:
    """Camera name -> (cx, cy, width, height) px of the cameras of `rig` whose principal point
    its images determined (quality.estimated_intrinsics), in COLMAP pixels of images of that
    size; {} without a rig."""
    from .metrics import principal_point_px

    out = {}
    for name, cam in (rig.cameras.items() if rig is not None else ()):
        estimated = cam.quality.estimated_intrinsics if cam.quality is not None else None
        if estimated and "cx" in estimated:
            cx, cy = principal_point_px(cam.intrinsics)
            out[name] = (float(cx), float(cy), cam.intrinsics.width, cam.intrinsics.height)
    return out


def add_uncertainty(result: CalibrationResult, camera_names: Sequence[str],
                    config: PipelineConfig, sigmas: Optional[dict] = None) -> None:
    """Record each camera's standard deviations in its quality, in place: `sigmas` (camera name
    -> core.uncertainty.CameraUncertainty, from the image refinement) where given, else
    core.uncertainty's."""
    rig = result.rig
    sigmas = dict(sigmas or {})
    if set(sigmas) >= set(rig.cameras):
        _record_sigmas(rig, sigmas)
        return
    pp_refined = [camera_names[c] for c in config.sfm.principal_point_cameras(len(camera_names))]
    given = sorted(config.known_intrinsics or {})
    # The RMS is over 2D error vectors; the noise of one pixel coordinate is RMS / sqrt(2).
    noise_px = float(rig.quality["reprojection_rms_px"]) / np.sqrt(2.0)
    try:
        sigmas = {**calibration_uncertainty(result.reconstruction, rig.reference_camera,
                                            noise_px, pp_refined, given), **sigmas}
    except (RuntimeError, ValueError) as exc:  # a diagnostic: never a reason to lose the result
        log.warning("no standard deviations for this calibration: %s", exc)
        return
    rig.quality["held_pp_std_fraction"] = HELD_PP_STD_FRACTION  # in the held points' sigmas
    _record_sigmas(rig, sigmas)


def _record_sigmas(rig: RigCalibration, sigmas: dict) -> None:
    for name, cam in rig.cameras.items():
        if name in sigmas and cam.quality is not None:
            cam.quality.focal_std_px = sigmas[name].focal_std_px
            cam.quality.principal_point_std_px = sigmas[name].principal_point_std_px
            cam.quality.projection_std_px = sigmas[name].projection_std_px


def _consensus_calibration(match_sets: list, image_sizes: Sequence[tuple[int, int]],
                           camera_names: Sequence[str], config: PipelineConfig,
                           match_tracks: Optional[Tracks], progress: Progress
                           ) -> CalibrationResult:
    from .consensus import (AGREEMENT_DEG, EARLY_STOP_RUNS, choose_run, disagreement_warning,
                            medoid, rig_disagreement_deg)
    from .focal_hops import hop_focals
    from .incremental import cost_truncation_px

    results, seeds, failed, first_error, run_s = [], [], 0, None, None
    for k in range(config.consensus_runs):
        if k == EARLY_STOP_RUNS and len(results) == k and \
                medoid([r.rig for r in results], camera_names)[1].max() < AGREEMENT_DEG:
            break  # a well-determined rig: more runs would only repeat the answer
        seed = config.sampling.seed + k
        run_config = copy.deepcopy(config)
        run_config.sampling.seed = seed
        took = f"; about {run_s:.0f} s each" if run_s else ""  # what this run will take
        say_progress(progress, f"consensus run {k + 1} of up to {config.consensus_runs} "
                               f"(sampling seed {seed}{took})")
        started = time.perf_counter()
        try:
            results.append(_calibrate_once(match_sets, image_sizes, camera_names, run_config,
                                           None, match_tracks, progress if k == 0 else None))
            seeds.append(seed)
            run_s = time.perf_counter() - started
        except CalibrationError as exc:
            log.info("consensus run %d (seed %d) failed: %s", k + 1, seed, exc)
            failed += 1
            first_error = first_error or exc
    if not results:
        raise first_error
    choice = choose_run([r.rig for r in results], [r.tracks for r in results], camera_names,
                        cost_truncation_px(config.sfm, len(camera_names)), config.sampling.seed,
                        refined_on=match_tracks)
    best, D, costs = choice.best, choice.disagreement_deg, choice.costs_px
    if choice.worse_fit:
        say_progress(progress, "consensus: the runs with seeds " + ", ".join(
            f"{seeds[k]} ({costs[k]:.2f} px)" for k in choice.worse_fit) + " fit the common "
            f"tracks clearly worse than seed {seeds[int(np.nanargmin(costs))]} "
            f"({np.nanmin(costs):.2f} px) and are not kept")
    result = results[best]
    why = (f"fits the keypoint-match tracks best ({costs[best]:.3f} px on a common sample)"
           if choice.by_fit else "agrees best with the others")
    say_progress(progress, f"consensus: kept the run with seed {seeds[best]}, which {why}")
    others = np.delete(D[best], best)
    if D.max() >= AGREEMENT_DEG and match_tracks is not None and match_tracks.num_tracks \
            and result.state is not None:
        # The runs found different minima: search around the kept one (core.focal_hops).
        state, hops = hop_focals(result.state, match_tracks, camera_names, config.sfm,
                                 config.sampling.seed, lambda m: say_progress(progress, m))
        if hops:
            result = _with_state(result, state, camera_names, config)
            result.rig.quality["focal_hops"] = hops
            others = np.array([rig_disagreement_deg(result.rig, r.rig, camera_names)
                               for k, r in enumerate(results) if k != best])
    result.rig.quality.update(
        consensus_runs=len(results), consensus_failed_runs=failed, consensus_seed=seeds[best],
        consensus_worse_fit_runs=len(choice.worse_fit), consensus_kept_by_fit=choice.by_fit,
        consensus_disagreement_deg=float(np.median(others)) if len(others) else 0.0)
    say_progress(progress, f"consensus: median disagreement of the result with the other "
                           f"{len(results) - 1} runs "
                           f"{result.rig.quality['consensus_disagreement_deg']:.2f} deg")
    few_wide = (config.matcher == "sift" and len(camera_names) <= 4
                and not any("FISHEYE" in m for m in config.sfm.models(len(camera_names))))
    warning = disagreement_warning(result.rig.quality["consensus_disagreement_deg"], len(results),
                                   few_wide)
    if warning:
        warn_user(result.rig, warning, progress)
    return result


def _with_state(result: CalibrationResult, state: SfMState, camera_names: Sequence[str],
                config: PipelineConfig) -> CalibrationResult:
    """`result` with its rig and reconstruction rebuilt from another state of the same cameras
    (the quality's per-run records kept, the fit figures recomputed)."""
    failed = [camera_names.index(n) for n in result.rig.failed_cameras]
    quality = dict(result.rig.quality)
    rig = rig_from_state(state, camera_names, failed, quality)
    if "given_intrinsics_fit" in quality:
        rig.quality["given_intrinsics_fit"] = given_intrinsics_fit(state, camera_names,
                                                                   config.sfm.num_threads)
    return replace(result, rig=rig, reconstruction=_saved_model(state, camera_names, rig),
                   state=state)


def _saved_model(state: SfMState, camera_names: Sequence[str], rig: RigCalibration):
    """The pycolmap.Reconstruction of `state` (what OUT/colmap holds) in `rig`'s frame and units,
    so its points and cameras combine with calibration.json as they are."""
    reconstruction, _ = build_reconstruction(state, camera_names)
    move_model_to_rig_frame(reconstruction, rig)
    return reconstruction


def _calibrate_once(match_sets: list, image_sizes: Sequence[tuple[int, int]],
                    camera_names: Sequence[str], config: PipelineConfig,
                    previous: Optional[RigCalibration], match_tracks: Optional[Tracks],
                    progress: Progress) -> CalibrationResult:
    try:
        sampled, given = _sampled_tracks(match_sets, image_sizes, camera_names, config, previous)
    except FocalInitError as exc:  # it knows the cameras by index only
        raise exc.named(camera_names) from exc
    say_progress(progress, f"sampled {sampled.tracks.num_tracks} tracks")
    # Focals the user or EXIF gave (a previous calibration's are calibrated, not guessed).
    known = previous is None and given is not None
    return calibrate_from_tracks(sampled.tracks, image_sizes, camera_names, config,
                                 two_view=sampled.two_view, focal_px=sampled.focal_px,
                                 previous=previous, match_tracks=match_tracks,
                                 known_focals=known, progress=progress)


def _sampled_tracks(match_sets: list, image_sizes: Sequence[tuple[int, int]],
                    camera_names: Sequence[str], config: PipelineConfig,
                    previous: Optional[RigCalibration]):
    """(sample_tracks' result, the start focals given to it or None)."""
    from .sampling import sample_tracks

    given = None
    if previous is not None and config.pipeline == "global" and config.sfm.global_init == "previous":
        from .global_sfm import working_models, poses_from_previous

        intrinsics, poses = poses_from_previous(previous, camera_names, image_sizes,
                                                working_models(config.sfm, len(camera_names)))
        intrinsics = with_known_intrinsics(intrinsics, config, camera_names)
        sampled = sample_tracks(match_sets, config, cam_from_rig=poses, intrinsics=intrinsics)
    elif len(config.sfm.fixed_intrinsics_cameras) == len(camera_names):
        # Every camera's intrinsics given: the sampling's rays come from them (distortion
        # included) instead of a pinhole or equidistant guess.
        given = start_focals(config, previous, camera_names, image_sizes)
        sampled = sample_tracks(match_sets, config, focal_px=given, intrinsics=[
            config.known_intrinsics[n] for n in camera_names])
    else:
        given = start_focals(config, previous, camera_names, image_sizes)
        sampled = sample_tracks(match_sets, config, focal_px=given)
    return sampled, given


def run_calibration(frame_sets: Sequence[Sequence[np.ndarray]], camera_names: Sequence[str],
                    config: PipelineConfig, *, matcher=None,
                    previous: Optional[RigCalibration] = None,
                    progress: Progress = None) -> CalibrationResult:
    """Calibrate a rig from synchronised frame sets.

    frame_sets[t][c]: camera c's image at time t, (H, W, 3) uint8 RGB or (H, W) uint8 gray.
    matcher: an already loaded core.matching.Matcher to reuse (else config.matcher is created and
    loaded here). previous: a previous calibration of the same cameras; its focal lengths replace
    the initial-focal estimate (recalibration; see core.recalibration for starting from its
    poses). Raises CalibrationError subclasses."""
    start = time.perf_counter()
    camera_names = list(camera_names)
    image_sizes = check_frame_sets(frame_sets, camera_names)
    strips = info_strips(frame_sets, camera_names, config)
    ignored = ignored_regions(frame_sets, camera_names, config, strips)
    match_sets = match_frame_sets(frame_sets, config, matcher=matcher, progress=progress,
                                  camera_names=camera_names, ignored=ignored)
    result = calibrate_from_matches(match_sets, image_sizes, camera_names, config,
                                    previous=previous, frame_sets=frame_sets, ignored=ignored,
                                    progress=progress)
    with_point_colours(result, frame_sets)
    result.rig.quality.update(matcher=config.matcher, num_frame_sets=len(frame_sets),
                              runtime_s=time.perf_counter() - start)
    if config.camera_lens:
        result.rig.quality["camera_lens"] = dict(config.camera_lens)
    if config.camera_masks:
        result.rig.quality["masked_cameras"] = sorted(config.camera_masks)
    record_info_strips(result, strips)
    if config.exif_focal_px:
        result.rig.quality["exif_focal_px"] = {n: round(float(f), 1)
                                               for n, f in config.exif_focal_px.items()}
    return result


def record_info_strips(result: CalibrationResult, strips: dict) -> None:
    """Note the info strips that were ignored (info_strips) in rig.quality["info_strips"]
    (camera -> what)."""
    if strips:
        result.rig.quality["info_strips"] = {
            n: ", ".join(s.describe() for s in found) for n, found in strips.items()}


def with_point_colours(result: CalibrationResult,
                       frame_sets: Sequence[Sequence[np.ndarray]]) -> None:
    """Colour the result's reconstruction points from the images (reconstruction.colour_points)."""
    if result.reconstruction is None or result.state is None:
        return
    try:
        colour_points(result.reconstruction, result.state, frame_sets)
    except Exception as exc:  # colours are for viewing: they never cost a calibration
        log.warning("scene points left uncoloured: %r", exc)


def calibrate_rig(frame_sets: Sequence[Sequence[np.ndarray]], camera_names: Sequence[str],
                  config: PipelineConfig, *, matcher=None,
                  previous: Optional[RigCalibration] = None,
                  progress: Progress = None) -> RigCalibration:
    """run_calibration(...).rig: the calibrated rig only."""
    return run_calibration(frame_sets, camera_names, config, matcher=matcher, previous=previous,
                           progress=progress).rig
