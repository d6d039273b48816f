"""Where a calibration's focal lengths start, per camera, first found: the user's
(PipelineConfig.cameras.initial_focal_px), a previous calibration's, the images' EXIF; given
intrinsics (config.cameras.known_intrinsics) override these for their cameras; else eq. 2 on the
tracks' two-view geometry (core.method.focal). The focal multi-start then explores around this start
(core.method.multistart.focal_starts)."""
from __future__ import annotations

from typing import Optional, Sequence

import numpy as np

from ..config import PipelineConfig
from ..errors import FocalInitError, InputError
from ..progress import Progress
from ..types import CameraIntrinsics, RigCalibration, Tracks
from .focal import estimate_initial_focals
from .incremental import initial_intrinsics
from .twoview import pair_weights


def start_focals(config: PipelineConfig, previous: Optional[RigCalibration],
                 camera_names: Sequence[str], image_sizes: Sequence[tuple[int, int]]
                 ) -> Optional[np.ndarray]:
    """(C,) focal px the calibration starts from instead of estimating them, or None. Per camera,
    first found: the user's config.cameras.initial_focal_px, a previous calibration's focal, the
    images' EXIF focal (config.cameras.exif_focal_px). NaN for a camera only EXIF could have named
    and did not: its focal is estimated (sampling.sample_tracks). InputError when the user's focals
    name unknown cameras, are not positive, or leave a camera without a focal. Given intrinsics
    (config.cameras.known_intrinsics) override all of these for their cameras."""
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
    hint = dict(config.cameras.initial_focal_px or {})
    exif = {k: v for k, v in (config.cameras.exif_focal_px or {}).items() if k in camera_names}
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


def _known_focals(config: PipelineConfig, camera_names: Sequence[str]) -> dict[str, float]:
    """The mean focal [px] of every camera with given intrinsics."""
    return {n: float(cam.to_pycolmap().mean_focal_length())
            for n, cam in (config.cameras.known_intrinsics or {}).items() if n in camera_names}


def with_known_intrinsics(intrinsics: Sequence[CameraIntrinsics], config: PipelineConfig,
                          camera_names: Sequence[str]) -> list[CameraIntrinsics]:
    """`intrinsics` with the cameras of config.cameras.known_intrinsics at their given values."""
    known = config.cameras.known_intrinsics or {}
    return [known.get(n, cam) for n, cam in zip(camera_names, intrinsics)]


def initial_focals(tracks: Tracks, two_view: dict, image_sizes: Sequence[tuple[int, int]]
                   ) -> np.ndarray:
    """(C,) focal px from the pairs' fundamental matrices (paper eq. 2), pair weight = number of
    common tracks / the largest number."""
    obs = tracks.observed()
    counts = {k: int(np.sum(obs[:, k[0]] & obs[:, k[1]])) for k, g in two_view.items()
              if g.F_ji is not None}
    F = {k: two_view[k].F_ji for k in counts}
    return estimate_initial_focals(F, pair_weights(counts), list(image_sizes))


def eq2_start(tracks: Tracks, two_view: dict, image_sizes: Sequence[tuple[int, int]],
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
        Progress.of(progress).say(f"no eq. 2 start beside the known focals: {exc}")
        return None
    return {"eq. 2": with_known_intrinsics(initial_intrinsics(image_sizes, focal, models),
                                           config, camera_names)}
