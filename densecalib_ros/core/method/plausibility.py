"""Physical plausibility of self-calibrated intrinsics.

Bundle adjustment can trade a wrong pose against the distortion terms: on weakly constrained
cameras (few, mostly 2-view tracks) RADIAL k1 can run far negative while the reprojection error
stays small (docs/design-notes.md, Plausible intrinsics). Such a lens folds the image over itself
(the radial map is no longer invertible inside the image), so the calibration is unusable whatever
its residuals say. COLMAP guards the same failure with its "bogus camera parameters" test (focal
ratio, |extra| <= 1); we test the property that matters instead: the radial distortion map must
be strictly increasing from the principal point out to the farthest observation the
reconstruction explains. Beyond the observations the images say nothing about the lens and a
low-order polynomial fitted inside may turn anywhere: holding it to the image corner there held
real webcams' intrinsics at their start in adjustment after adjustment (docs/design-notes.md,
Plausible intrinsics). A finished perspective lens that folds before its image corner is warned
(corner_fold_warning): its file does not undistort the corners.

Radial maps (COLMAP models; r = undistorted radius on the normalised plane, theta = angle from
the optical axis):
- SIMPLE_RADIAL / RADIAL / OPENCV / FULL_OPENCV (radial part): r_d = r (1 + k1 r^2 + k2 r^4 [+ ...])
- SIMPLE_RADIAL_FISHEYE / RADIAL_FISHEYE / OPENCV_FISHEYE: r_d = theta (1 + k1 theta^2 + ...)
"""
from __future__ import annotations

import dataclasses
import logging
from typing import Callable, Optional, Sequence

import numpy as np
import pycolmap

from ..errors import FocalInitError
from ..io.calibration_values import runaway_distortion
from ..types import CameraIntrinsics, RigCalibration
from .reconstruction import BAStage, SfMState, bundle_adjust, reprojection_errors

log = logging.getLogger(__name__)

MAX_FOCAL_IMAGE_RATIO = 10.0  # beyond this x the image size a self-calibrated focal has run away
MIN_FOCAL_IMAGE_RATIO = 0.1
WELL_FIT_PX = 4.0  # observations a reconstruction explains (fisheye extent)
_SAMPLES = 4000
_PINHOLE_MAX_RADIUS = 20.0  # tan(87 deg): pinhole models cannot image further out
_FISHEYE_MAX_THETA_RAD = np.pi - 1e-3

# model -> (index of fx, index of fy or None, cx, cy, radial coefficient indices, fisheye?)
_LAYOUT = {
    "SIMPLE_PINHOLE": (0, None, 1, 2, (), False),
    "PINHOLE": (0, 1, 2, 3, (), False),
    "SIMPLE_RADIAL": (0, None, 1, 2, (3,), False),
    "RADIAL": (0, None, 1, 2, (3, 4), False),
    "OPENCV": (0, 1, 2, 3, (4, 5), False),
    "FULL_OPENCV": (0, 1, 2, 3, (4, 5, 8), False),  # k1, k2, k3 (the rational k4-k6 ignored)
    "SIMPLE_RADIAL_FISHEYE": (0, None, 1, 2, (3,), True),
    "RADIAL_FISHEYE": (0, None, 1, 2, (3, 4), True),
    "OPENCV_FISHEYE": (0, 1, 2, 3, (4, 5, 6, 7), True),
}


def intrinsics_problem(camera: CameraIntrinsics,
                       observed_xy_px: Optional[np.ndarray] = None) -> Optional[str]:
    """None when the intrinsics are physically plausible, else a sentence saying what is wrong:
    a focal outside [MIN, MAX]_FOCAL_IMAGE_RATIO x max(width, height), a distortion
    coefficient a calibration file may not carry (calibration_values.runaway_distortion), or a
    radial distortion that stops increasing before the farthest of `observed_xy_px` ((N, 2)
    COLMAP px) when given, else before the farthest image corner. Models without a known layout
    pass."""
    size = max(camera.width, camera.height)
    layout = _LAYOUT.get(camera.model)
    params = np.asarray(camera.params, dtype=np.float64)
    if not np.isfinite(params).all():
        return "its parameters are not finite"
    if layout is None:
        return None
    fx_i, fy_i, _, _, k_idx, fisheye = layout
    focal = params[fx_i] if fy_i is None else 0.5 * (params[fx_i] + params[fy_i])
    if not MIN_FOCAL_IMAGE_RATIO * size <= focal <= MAX_FOCAL_IMAGE_RATIO * size:
        return (f"its focal length {focal:.0f} px is outside {MIN_FOCAL_IMAGE_RATIO:g}-"
                f"{MAX_FOCAL_IMAGE_RATIO:g}x the image size")
    runaway = runaway_distortion(camera.parameter_names, params.tolist())
    if runaway:  # a coefficient the images did not hold, which no file of ours may carry
        return f"its {runaway}"
    if not k_idx:
        return None
    observed = observed_xy_px is not None and len(observed_xy_px)
    reach = _normalised_reach(camera, observed_xy_px if observed else None)
    monotone_reach, _ = _monotone_reach(params, k_idx, fisheye)
    if monotone_reach < reach:
        coeffs = ", ".join(f"{params[i]:.3g}" for i in k_idx)
        where = "the farthest observation" if observed else "the image corner"
        return (f"its radial distortion ({coeffs}) folds the image over itself: the distorted "
                f"radius stops increasing at {monotone_reach:.2f} before {where} at "
                f"{reach:.2f} (normalised)")
    return None


def _normalised_reach(camera: CameraIntrinsics, xy_px: Optional[np.ndarray] = None) -> float:
    """The largest normalised (distorted) radius of the pixels xy_px ((N, 2) COLMAP px; None:
    the image corners) from a known-layout camera's principal point."""
    fx_i, fy_i, cx_i, cy_i = _LAYOUT[camera.model][:4]
    params = np.asarray(camera.params, dtype=np.float64)
    if xy_px is None:
        xy_px = [[0, 0], [camera.width, 0], [0, camera.height], [camera.width, camera.height]]
    f_xy = np.array([params[fx_i], params[fx_i if fy_i is None else fy_i]])
    offsets = (np.asarray(xy_px, dtype=np.float64).reshape(-1, 2) - params[[cx_i, cy_i]]) / f_xy
    return float(np.max(np.linalg.norm(offsets, axis=1)))


def _monotone_reach(params: np.ndarray, k_idx: Sequence[int], fisheye: bool
                    ) -> tuple[float, bool]:
    """(the distorted radius (normalised) at which a radial map first stops increasing, or the
    largest one sampled where it does not; whether it does)."""
    x = np.linspace(0.0, _FISHEYE_MAX_THETA_RAD if fisheye else _PINHOLE_MAX_RADIUS, _SAMPLES)
    poly = np.ones_like(x)
    for power, i in enumerate(k_idx, start=1):
        poly += params[i] * x ** (2 * power)
    r_d = x * poly
    falling = np.flatnonzero(np.diff(r_d) <= 0)
    return float(r_d[falling[0]] if falling.size else r_d[-1]), bool(falling.size)


def perspective_fold_radius(camera: CameraIntrinsics) -> Optional[float]:
    """The distorted radius (normalised: pixels over the focal length) at which a perspective
    model's radial distortion stops increasing, where it does before tan(87 deg); None for
    fisheye and unknown models and lenses that do not fold. No pixel beyond it has a ray."""
    layout = _LAYOUT.get(camera.model)
    if layout is None or layout[5] or not layout[4]:
        return None
    reach, folds = _monotone_reach(np.asarray(camera.params, dtype=np.float64), layout[4], False)
    return reach if folds else None


# Real lenses put the principal point within about 2 % of the image's long side from its centre
# and their pixels are square to within 0.5 % (docs/design-notes.md, Real cameras' principal
# points). Five of the image refinement's prior sigmas (1 % and 0.3 %) out, a self-calibrated value
# is one the images moved where they do not determine it, not a lens.
UNLIKE_PP_OFFSET_FRACTION = 0.05
UNLIKE_ASPECT_DEVIATION = 0.015
UNLIKE_LENS_PREFIX = "intrinsics no real lens has"


def unlike_a_real_lens(camera: CameraIntrinsics) -> Optional[str]:
    """What about a perspective camera's principal point or pixel aspect no real lens has (an
    offset from the image centre beyond UNLIKE_PP_OFFSET_FRACTION of the long side, fy / fx
    beyond 1 +- UNLIKE_ASPECT_DEVIATION), else None. Fisheye and unknown models: None (a fisheye's
    principal point is the images' to place)."""
    layout = _LAYOUT.get(camera.model)
    if layout is None or layout[5]:
        return None
    fx_i, fy_i, cx_i, cy_i = layout[:4]
    params = np.asarray(camera.params, dtype=np.float64)
    size = max(camera.width, camera.height)
    problems = []
    offset_px = float(np.hypot(params[cx_i] - camera.width / 2.0,
                               params[cy_i] - camera.height / 2.0))
    if offset_px > UNLIKE_PP_OFFSET_FRACTION * size:
        problems.append(f"principal point {offset_px:.0f} px ({100 * offset_px / size:.0f} % "
                        "of the long side) off the image centre")
    if _unlike_aspect(camera):
        problems.append(f"pixel aspect fy/fx {params[fy_i] / params[fx_i]:.3f}")
    return ", ".join(problems) or None


def _unlike_aspect(camera: CameraIntrinsics) -> bool:
    """Whether a perspective camera with fx and fy has an fy / fx beyond 1 +-
    UNLIKE_ASPECT_DEVIATION (fisheye and one-focal models: False)."""
    layout = _LAYOUT.get(camera.model)
    if layout is None or layout[5] or layout[1] is None:
        return False
    return abs(camera.params[layout[1]] / camera.params[layout[0]] - 1.0) > UNLIKE_ASPECT_DEVIATION


def unlike_aspect_blocks(state: SfMState, blocks: Sequence[int]) -> list[int]:
    """The intrinsics blocks among `blocks` whose pixel aspect no real lens has (fy / fx beyond
    1 +- UNLIKE_ASPECT_DEVIATION)."""
    return [b for b in blocks if _unlike_aspect(state.intrinsics[b])]


def make_pixels_square(state: SfMState, blocks: Sequence[int]) -> None:
    """In place: fx = fy = their geometric mean, for the intrinsics blocks `blocks` (models with
    both; the others as they are)."""
    for b in blocks:
        cam = state.intrinsics[b]
        layout = _LAYOUT.get(cam.model)
        if layout is None or layout[1] is None:
            continue
        params = np.array(cam.params, dtype=np.float64)
        params[[layout[0], layout[1]]] = np.sqrt(params[layout[0]] * params[layout[1]])
        state.intrinsics[b] = CameraIntrinsics(cam.model, cam.width, cam.height, params)


def unlike_lens_warning(rig: RigCalibration) -> Optional[str]:
    """The warning for a calibration whose self-calibrated cameras (those whose intrinsics were
    given left out) include one unlike_a_real_lens, else None."""
    given = set(rig.quality.given_intrinsics or ())
    problems = {name: problem for name, cam in rig.cameras.items()
                if name not in given and (problem := unlike_a_real_lens(cam.intrinsics))}
    if not problems:
        return None
    # Given intrinsics that contradict the scene push the other cameras there too.
    fix = "Check the given intrinsics (are they these cameras', at this image size?)" \
        if given else ("Give one camera's intrinsics from a lab calibration (--intrinsics "
                       "NAME=PATH; node: intrinsics_files; library: "
                       "PipelineConfig.cameras.known_intrinsics)")
    return (f"{UNLIKE_LENS_PREFIX}: " + "; ".join(f"{n} {p}" for n, p in problems.items())
            + ". The images leave these open and the adjustment moved them there, so this "
            f"calibration is likely wrong. {fix}, or add views of the scene from other "
            "directions.")


def corner_fold_warning(rig: RigCalibration) -> Optional[str]:
    """The warning for a calibration with a self-calibrated perspective camera whose radial
    distortion folds before its image corner (plausible where the images saw: the guards hold
    the lens to its observations), else None. Fisheye models are left out: a circular fisheye
    images nothing in its corners."""
    given = set(rig.quality.given_intrinsics or ())
    folds = []
    for name, cam in rig.cameras.items():
        fold = perspective_fold_radius(cam.intrinsics) if name not in given else None
        share = fold / _normalised_reach(cam.intrinsics) if fold is not None else 1.0
        if share < 1.0:
            folds.append(f"{name} at {100 * share:.0f} %")
    if not folds:
        return None
    return ("the fitted lens distortion folds over before the image corner (the radius where "
            "it stops increasing, as a share of the principal point's distance to the farthest "
            f"corner): {', '.join(folds)}. The matches do not reach that far out, so the "
            "distortion is known only inside: the calibration stands there, but undistorting "
            "the image beyond it (OpenCV's undistortion maps) folds the corners back in. Add "
            "frame sets with texture in these cameras' corners, or give their intrinsics from a "
            "lab calibration (--intrinsics NAME=PATH).")


def implausible_cameras(state: SfMState) -> dict[int, str]:
    """{camera index: problem} for the registered cameras of a reconstruction whose intrinsics
    fail `intrinsics_problem` to the extent of their observations the reconstruction explains
    (reprojection error <= WELL_FIT_PX), so outlier matches (in a circular fisheye's dark
    corners, say) do not count. Given intrinsics (held, never changed) are the user's to judge."""
    err = reprojection_errors(state)
    out = {}
    for c in state.registered():
        if state.intrinsics_fixed(c):
            continue
        fit = np.isfinite(err[:, c]) & (err[:, c] <= WELL_FIT_PX)
        problem = intrinsics_problem(state.camera(c), state.tracks.xy_px[fit, c])
        if problem is not None:
            out[c] = problem
    return out


def bundle_adjust_plausibly(state: SfMState, camera_names: Sequence[str], stage: BAStage,
                            num_threads: int) -> pycolmap.BundleAdjustmentSummary:
    """`bundle_adjust` guarded for stages that refine intrinsics: a camera whose intrinsics the
    BA drives into implausible values (e.g. a weakly constrained camera trading its pose against
    k1) gets its intrinsics from before this BA back, held fixed while the BA is repeated. Later
    BAs, with more cameras and points, may refine them again. Returns the last BA's summary."""
    before = [CameraIntrinsics(c.model, c.width, c.height, c.params.copy())
              for c in state.intrinsics]
    summary = bundle_adjust(state, camera_names, stage, num_threads)
    bad = implausible_cameras(state)
    if not bad or not (stage.refine_focal or stage.refine_extra or stage.refine_principal_point):
        return summary
    log.debug("BA made intrinsics implausible, repeating with them fixed: %s", bad)
    for c in bad:
        block = int(state.camera_block[c])
        state.intrinsics[block] = before[block]
    fixed = tuple(sorted(set(stage.fixed_intrinsics_cameras) | set(bad)))
    return bundle_adjust(state, camera_names,
                         dataclasses.replace(stage, fixed_intrinsics_cameras=fixed), num_threads)


def drop_implausible_cameras(state: SfMState, failed: list[int], camera_names: Sequence[str],
                             say: Callable[[str], None]) -> None:
    """Unregister the cameras whose intrinsics ran into physically implausible values
    (plausibility.py) and add them to `failed`: their poses and intrinsics are not trustworthy,
    whatever the residuals. Raises FocalInitError when fewer than two cameras remain."""
    problems = implausible_cameras(state)
    for c, problem in problems.items():
        say(f"camera {camera_names[c]} left out: {problem}")
        state.cam_from_world[c] = None
        failed.append(c)
    failed.sort()
    state.drop_weak_points()
    if problems and len(state.registered()) < 2:
        raise FocalInitError(
            "Self-calibration ran into implausible intrinsics (" + "; ".join(
                f"{camera_names[c]}: {p}" for c, p in problems.items()) + "): the scene is "
            "probably too close to planar or the views too similar to fix the focal lengths and "
            "distortion. Add frame sets with depth variation (objects in front of the "
            "background), or try the global pipeline (--pipeline global; node and "
            "PipelineConfig: pipeline).")
