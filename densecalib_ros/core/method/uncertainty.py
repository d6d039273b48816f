"""How well the images pin down each camera's intrinsics: standard deviations of its focal length,
of where a ray projects (the intrinsics as a whole) and, where it was refined, of its principal
point, from the bundle adjustment's information matrix at the final solution
(pycolmap.estimate_ba_covariance: Schur complement over the points, then the camera blocks).

The problem is the final adjustment's: Cauchy loss, the reference camera's pose held and the
scale fixed by COLMAP's two-camera gauge, the principal point free only where the calibration
refined it. The covariance is that of unit pixel noise, scaled by the noise the fit shows
(reprojection RMS / sqrt(2) per pixel coordinate). It treats observations as independent and the
model as right. On tracks with independent Gaussian noise the errors are about 1 sigma
(test_uncertainty).

A principal point the calibration held (the regular preset holds it at the image centre) is
where a real camera's is not: by up to a few percent of the long side (docs/design-notes.md, Real
cameras' principal points). The covariance conditional on the held point cannot see that, and the
other parameters lean on it (a few px of focal per px of principal point): taken as right, it
puts the focal errors at many sigma (docs/design-notes.md, Intrinsics' standard deviations). So
the held point's unknown offset, HELD_PP_STD_FRACTION of the long side per axis, is added: the
others move with it by their regression on the principal point in the same problem with the
points free (cross-camera effects left out; pycolmap gives the covariance per camera block), and
the projection moves with it too. Then the errors are within a few sigma (same section); on tracks
with a 1 % offset about 1 sigma (test_uncertainty).

No rotation sigma is given here (the image refinement gives one: core.method.rotation_spread):
measured the same way it was several times smaller than the rotation errors on generated rigs (a
principal point held at the image centre that is not there turns a camera, which a covariance
conditional on the held point cannot show), and with the principal point marginalised its ratio
to the errors varied from rig to rig (same section): not a number to act on. The consensus
runs' disagreement (quality.consensus_disagreement_deg) is the measured spread of the
extrinsics."""
from __future__ import annotations

import copy
import logging
from dataclasses import dataclass, replace
from typing import Optional, Sequence

import numpy as np
import pycolmap

from ..config import PipelineConfig
from ..metrics import (invertible_pixel_rays, mean_focal_px, projection_map_error,
                       relative_pose_errors)
from ..types import CameraIntrinsics, RigCalibration, colmap_parameter_names
from .prior_adjustment import FISHEYE_MODELS, points_dof_factor

log = logging.getLogger(__name__)


@dataclass
class CameraUncertainty:
    focal_std_px: Optional[float]  # of the mean focal length
    # The larger of cx's and cy's; for a point held fixed, how far a real camera's point may lie
    # from there (principal_point_spread_px), else None where it was held.
    principal_point_std_px: Optional[float]
    # Mean over the image of the standard deviation (px) of where a ray projects: the
    # intrinsics' uncertainty as a whole. A focal that trades off against the distortion (a
    # fisheye seen over part of its field) has a large focal_std_px but a small projection_std_px.
    projection_std_px: Optional[float]
    # The camera's rotation relative to the reference camera (deg, root mean square of the angle;
    # core.method.rotation_spread): None for the reference camera and where not estimated.
    rotation_std_deg: Optional[float] = None
    principal_point_held: bool = False  # held fixed by the final adjustment, not estimated


# Rays sampled on a grid of this many points per image side for projection_std_px.
PROJECTION_GRID = 12
# How far from the image centre a principal point the calibration holds there may be, per axis,
# as a fraction of the image's long side: real cameras' target-based calibrations put it mostly
# within about that, some up to a few percent (docs/design-notes.md, Real cameras' principal
# points).
HELD_PP_STD_FRACTION = 0.01
# A 16:9 video frame is a window the camera's firmware reads out of a taller sensor (4:3 on most
# webcam sensors), placed by the firmware as much as by the lens: the real video cameras with a
# reference here (Caliscope's four webcams, Pose2Sim's four mocap units, the fox's phone) put the
# short axis's coordinate 0.4-4.8 % of that side off-centre, 2.8 % root mean square over the nine,
# the long axis's 0.8 % of the long side. A frame at least VIDEO_FRAME_ASPECT wide (16:9 is 1.78,
# a 1088x1920 portrait 1.76; still cameras' native 3:2 is 1.5) spreads its short axis's point that
# much (principal_point_spread_px): where it was held, its sigma says so. Measured on perspective
# lenses only: fisheye ones keep 1 %.
VIDEO_FRAME_ASPECT = 1.7
CROPPED_FRAME_PP_STD_FRACTION = 0.028


def principal_point_spread_px(width: int, height: int, model: str,
                              fraction: float = HELD_PP_STD_FRACTION) -> tuple[float, float]:
    """(x, y) px: how far from the image centre a real camera's principal point may be, per axis,
    as a standard deviation, for a camera of this COLMAP model name: `fraction` of the long side
    (HELD_PP_STD_FRACTION), on the short axis of a perspective camera's video frame
    (VIDEO_FRAME_ASPECT) at least CROPPED_FRAME_PP_STD_FRACTION of the short side; (0, 0) where
    fraction is 0 (the point taken as right)."""
    long_px, short_px = max(width, height), min(width, height)
    spread = [fraction * long_px] * 2
    video = long_px >= VIDEO_FRAME_ASPECT * short_px and model not in FISHEYE_MODELS
    if fraction > 0.0 and video:
        short_axis = 1 if width >= height else 0
        spread[short_axis] = max(spread[short_axis], CROPPED_FRAME_PP_STD_FRACTION * short_px)
    return float(spread[0]), float(spread[1])


def _covariance(reconstruction: pycolmap.Reconstruction, reference: str,
                refine_principal_point: bool, held_intrinsics: Sequence[str] = ()):
    """(BACovariance, the reconstruction copy it refers to), or (None, None) when it fails.
    held_intrinsics: cameras whose intrinsics are constant (a mixed rig's pinhole cameras while
    the fisheye principal points are refined, as in incremental.final_adjustment)."""
    rec = pycolmap.Reconstruction(reconstruction)  # the adjuster's problem points into it
    options = pycolmap.BundleAdjustmentOptions()
    options.refine_principal_point = refine_principal_point
    options.refine_sensor_from_rig = False  # trivial rigs, as in reconstruction.bundle_adjust
    options.print_summary = False
    options.ceres.loss_function_type = pycolmap.LossFunctionType.CAUCHY
    options.ceres.loss_function_scale = 1.0
    config = pycolmap.BundleAdjustmentConfig()
    for image_id, image in rec.images.items():
        config.add_image(image_id)
        if image.name == reference:
            config.set_constant_rig_from_world_pose(image.frame_id)
        if image.name in held_intrinsics:
            config.set_constant_cam_intrinsics(image.camera_id)
    config.fix_gauge(pycolmap.BundleAdjustmentGauge.TWO_CAMS_FROM_WORLD)
    adjuster = pycolmap.create_default_ceres_bundle_adjuster(options, config, rec)
    cov = pycolmap.estimate_ba_covariance(pycolmap.BACovarianceOptions(), rec, adjuster)
    return (cov, rec) if cov is not None else (None, None)


def _unit_params_cov(cov, camera: pycolmap.Camera, free: Sequence[str]) -> Optional[np.ndarray]:
    """The covariance (unit pixel noise) of the camera's parameters `free`, in params order."""
    unit_cov = cov.get_other_params_cov(camera.params)
    return unit_cov if unit_cov is not None and unit_cov.shape[0] == len(free) else None


def _held_point_sensitivity(cov_free, camera_free: pycolmap.Camera) -> Optional[np.ndarray]:
    """(others, 2): how far the camera's other parameters move per pixel of its principal point,
    from the covariance of the problem with the principal points free (the regression of the
    others on cx, cy)."""
    names = colmap_parameter_names(camera_free)
    unit_cov = _unit_params_cov(cov_free, camera_free, names)
    if unit_cov is None:
        return None
    pp = [names.index("cx"), names.index("cy")]
    others = [i for i in range(len(names)) if i not in pp]
    try:
        return unit_cov[np.ix_(others, pp)] @ np.linalg.inv(unit_cov[np.ix_(pp, pp)])
    except np.linalg.LinAlgError:
        return None


def _camera_uncertainty(cov, rec: pycolmap.Reconstruction, image: pycolmap.Image,
                        noise_px: float, refine_principal_point: bool,
                        held_point: Optional[tuple[np.ndarray, tuple[float, float]]] = None
                        ) -> CameraUncertainty:
    """held_point: (sensitivity, (x, y) std px) of a held principal point
    (_held_point_sensitivity and principal_point_spread_px): its unknown offset is added to the
    others' covariance, enters the projection's, and is the point's own sigma."""
    camera = rec.cameras[image.camera_id]
    names = colmap_parameter_names(camera)
    # The rows of the free parameters, in order (held ones are left out of the covariance).
    free = [n for n in names if refine_principal_point or n not in ("cx", "cy")]
    unit_cov = _unit_params_cov(cov, camera, free)
    if unit_cov is None:
        return CameraUncertainty(None, None, None)
    params_cov = unit_cov * noise_px ** 2
    if held_point is not None:
        # The held estimate is off by sensitivity @ offset, offset ~ N(0, diag(std^2)) per
        # axis; the projection also moves with the offset itself.
        sensitivity, std_px = held_point
        offset_cov = np.diag(np.square(std_px))
        params_cov = params_cov + sensitivity @ offset_cov @ sensitivity.T
        free = free + ["cx", "cy"]
        params_cov = np.block([[params_cov, sensitivity @ offset_cov],
                               [offset_cov @ sensitivity.T, offset_cov]])
    focal_rows = [i for i, n in enumerate(free) if n in ("f", "fx", "fy")]
    # The mean focal's variance: the sum of the focal block over its size squared.
    focal = float(np.sqrt(params_cov[np.ix_(focal_rows, focal_rows)].sum()
                          / len(focal_rows) ** 2))
    pp = (float(np.sqrt(max(params_cov[free.index(n), free.index(n)] for n in ("cx", "cy"))))
          if "cx" in free else None)
    projection = projection_std_px(camera, [names.index(n) for n in free], params_cov)
    return CameraUncertainty(focal, pp, projection,
                             principal_point_held=not refine_principal_point)


def projection_std_px(camera: pycolmap.Camera, free_rows: Sequence[int],
                      params_cov: np.ndarray) -> Optional[float]:
    """Mean over a grid of image points of sqrt(trace) of the 2x2 covariance of where the point's
    ray projects, params_cov being the covariance of camera.params[free_rows] (first-order
    propagation, numerical Jacobian). Grid points whose ray does not map back to them (beyond a
    fisheye model's invertible field) are left out; None when none is left."""
    xs = np.linspace(0.5, camera.width - 0.5, PROJECTION_GRID)
    ys = np.linspace(0.5, camera.height - 0.5, PROJECTION_GRID)
    xy_px = np.stack(np.meshgrid(xs, ys), -1).reshape(-1, 2).astype(np.float64)
    rays, valid = invertible_pixel_rays(camera, xy_px)
    if not valid.any():
        return None
    rays = rays[valid]
    projected = camera.img_from_cam(rays)
    params = np.array(camera.params, dtype=np.float64)
    jacobian = np.zeros((len(rays), 2, len(free_rows)))
    for k, row in enumerate(free_rows):
        step = 1e-6 * max(1.0, abs(params[row]))
        moved = copy.copy(camera)
        shifted = params.copy()
        shifted[row] += step
        moved.params = shifted
        jacobian[:, :, k] = (moved.img_from_cam(rays) - projected) / step
    cov_px = np.einsum("nik,kl,njl->nij", jacobian, params_cov, jacobian)
    std = np.sqrt(np.clip(np.trace(cov_px, axis1=1, axis2=2), 0.0, None))
    return float(std[np.isfinite(std)].mean()) if np.isfinite(std).any() else None


def calibration_uncertainty(reconstruction: pycolmap.Reconstruction, reference: str,
                            noise_px: float, pp_refined: Sequence[str] = (),
                            given: Sequence[str] = (),
                            held_pp_std_fraction: float = HELD_PP_STD_FRACTION
                            ) -> dict[str, CameraUncertainty]:
    """Per camera (image name) of `reconstruction` its CameraUncertainty. reference: the camera
    whose pose is held; noise_px: the standard deviation of one pixel coordinate of an
    observation (reprojection RMS / sqrt(2)); pp_refined:
    the cameras whose principal point the calibration refined; given: the cameras whose
    intrinsics were given and held (constant here too; their values are None);
    held_pp_std_fraction: how far a principal point held at the image centre may be off, per
    axis, as a fraction of the image's long side (principal_point_spread_px; 0: the held point
    is taken as right). Cameras whose covariance cannot be estimated get None values."""
    out = {name: CameraUncertainty(None, None, None) for name in given}
    for refine_pp in (False, True):
        wanted = [im for im in reconstruction.images.values()
                  if (im.name in pp_refined) == refine_pp and im.name not in given]
        if not wanted:
            continue
        held = [im.name for im in reconstruction.images.values()
                if (refine_pp and im.name not in pp_refined) or im.name in given]
        cov, rec = _covariance(reconstruction, reference, refine_pp, held)
        cov_free = rec_free = None
        if not refine_pp and held_pp_std_fraction > 0.0 and cov is not None:
            cov_free, rec_free = _covariance(reconstruction, reference, True, held)
        for image in wanted:
            held_point = None
            if cov_free is not None:
                camera = rec_free.cameras[rec_free.images[image.image_id].camera_id]
                sensitivity = _held_point_sensitivity(cov_free, camera)
                if sensitivity is not None:
                    held_point = (sensitivity, principal_point_spread_px(
                        camera.width, camera.height, camera.model.name, held_pp_std_fraction))
            out[image.name] = (_camera_uncertainty(cov, rec, rec.images[image.image_id], noise_px,
                                                   refine_pp, held_point) if cov is not None
                               else CameraUncertainty(None, None, None))
    if any(u.focal_std_px is None for u in out.values()):
        log.debug("no covariance for some cameras' intrinsics (degenerate bundle adjustment)")
    return out


def error_sigma_ratios(rig, truth) -> dict[str, list[float]]:
    """How the sigmas compare with the actual errors against a ground truth (the benchmark's
    check), per camera with a sigma: "focal": |focal error| / focal_std_px; "principal_point":
    the larger of its |cx| and |cy| errors / principal_point_std_px (the larger of their sigmas,
    so a ratio on the lower side where the larger error lies on the better determined axis);
    "projection": the mean projection-map error (metrics.projection_map_error) /
    projection_std_px; "rotation": the angle (deg) of the camera's rotation relative to the
    reference camera against the truth's / rotation_std_deg."""
    out = intrinsics_error_sigma_ratios(rig, {n: c.intrinsics for n, c in truth.cameras.items()})
    out["rotation"] = rotation_error_sigma_ratios(rig, truth)
    return out


def rotation_error_sigma_ratios(rig, truth) -> list[float]:
    """Per camera with a rotation sigma: the rotation error of its pair with the reference camera
    (metrics.relative_pose_errors, the bench's pair metric) / rotation_std_deg."""
    ref = rig.reference_camera
    if ref not in truth.cameras:
        return []
    out = []
    for name, cam in rig.cameras.items():
        q = cam.quality
        if q is None or name not in truth.cameras or not q.rotation_std_deg:
            continue
        pair = relative_pose_errors({n: rig.cameras[n].cam_from_rig for n in (ref, name)},
                                    {n: truth.cameras[n].cam_from_rig for n in (ref, name)})[0]
        out.append(pair.rot_err_deg / q.rotation_std_deg)
    return out


def intrinsics_error_sigma_ratios(rig, truth: dict[str, CameraIntrinsics]
                                  ) -> dict[str, list[float]]:
    """error_sigma_ratios against reference intrinsics alone (camera name -> intrinsics)."""
    from ..metrics import principal_point_px

    out = {"focal": [], "principal_point": [], "projection": []}
    for name, cam in rig.cameras.items():
        q, true = cam.quality, truth.get(name)
        if q is None or true is None:
            continue
        if q.focal_std_px:
            error = mean_focal_px(cam.intrinsics) - mean_focal_px(true)
            out["focal"].append(abs(error) / q.focal_std_px)
        if q.principal_point_std_px:
            error = np.subtract(principal_point_px(cam.intrinsics), principal_point_px(true))
            out["principal_point"].append(float(np.abs(error).max()) / q.principal_point_std_px)
        if q.projection_std_px:
            error = projection_map_error(true, cam.intrinsics)["mean_px"]
            if np.isfinite(error):
                out["projection"].append(error / q.projection_std_px)
    return out


def in_quadrature(std: Optional[float], extra: float) -> Optional[float]:
    """std widened by an independent `extra` of the same unit: their root sum of squares; std as
    it is where it is None (nothing estimated) or `extra` is not finite (nothing measured)."""
    return float(np.hypot(std, extra)) if std is not None and np.isfinite(extra) else std


def with_runs_spread(sigmas: dict, spread: dict) -> dict:
    """sigmas (camera name -> CameraUncertainty) with each camera's focal, projection, rotation
    and principal point standard deviations widened by the consensus runs' spread of its answer
    (spread: name -> (focal px, projection px, rotation deg, principal point px),
    consensus_runs.runs_intrinsics_spread), in quadrature.

    For a calibration whose runs disagree: each run's covariance describes the valley it settled
    in, while the runs, calibrated from different samples of the same correspondences, settled in
    different ones. How far their answers scatter is then the larger part of the uncertainty,
    and the one a single run's covariance cannot see (docs/design-notes.md, Sigmas of runs that
    disagree)."""
    out = dict(sigmas)
    for name, (focal_px, projection_px, rotation_deg, point_px) in spread.items():
        u = out.get(name)
        if u is None or u.focal_std_px is None:
            continue
        out[name] = replace(u, focal_std_px=in_quadrature(u.focal_std_px, focal_px),
                            projection_std_px=in_quadrature(u.projection_std_px, projection_px),
                            rotation_std_deg=in_quadrature(u.rotation_std_deg, rotation_deg),
                            principal_point_std_px=in_quadrature(u.principal_point_std_px,
                                                                 point_px))
    return out


def estimated_principal_points(rig: Optional[RigCalibration]) -> dict:
    """Camera name -> (cx, cy, width, height) px of the cameras of `rig` whose principal point
    its images determined (quality.estimated_intrinsics), in COLMAP pixels of images of that
    size; {} without a rig."""
    from ..metrics import principal_point_px

    out = {}
    for name, cam in (rig.cameras.items() if rig is not None else ()):
        estimated = cam.quality.estimated_intrinsics if cam.quality is not None else None
        if estimated and "cx" in estimated:
            cx, cy = principal_point_px(cam.intrinsics)
            out[name] = (float(cx), float(cy), cam.intrinsics.width, cam.intrinsics.height)
    return out


def camera_sigmas(rig: RigCalibration, reconstruction, camera_names: Sequence[str],
                  config: PipelineConfig, sigmas: Optional[dict] = None
                  ) -> tuple[dict, Optional[float]]:
    """(camera name -> CameraUncertainty, the held principal points' sigma as a fraction of the
    long side where it entered them, else None): `sigmas` (the image refinement's) where they
    cover every camera, else core.method.uncertainty's for the others, units of one model that
    share an estimated principal point widened by their own points' spread (with_units_spread);
    ({}, None) where those cannot be computed (a diagnostic: never a reason to lose the
    result)."""
    sigmas = dict(sigmas or {})
    if set(sigmas) >= set(rig.cameras):
        return sigmas, None
    pp_refined = [camera_names[c] for c in config.sfm.principal_point_cameras(len(camera_names))]
    given = sorted(config.cameras.known_intrinsics or {})
    # The RMS is over 2D error vectors: one pixel coordinate's residual is RMS / sqrt(2), the
    # noise larger by the coordinates the points take.
    quality = rig.quality
    noise_px = float(quality.reprojection_rms_px) / np.sqrt(2.0) * points_dof_factor(
        quality.num_observations or 0, quality.num_points or 0)
    try:
        found = calibration_uncertainty(reconstruction, rig.reference_camera, noise_px,
                                        pp_refined, given)
    except (RuntimeError, ValueError) as exc:
        log.warning("no standard deviations for this calibration: %s", exc)
        return {}, None
    units = {n for names, _ in config.cameras.identical_units for n in names}
    frames = {n: (cam.intrinsics.width, cam.intrinsics.height, cam.intrinsics.model)
              for n, cam in rig.cameras.items() if n in units and n in pp_refined}
    return {**with_units_spread(found, frames), **sigmas}, HELD_PP_STD_FRACTION


def with_units_spread(sigmas: dict, frames: dict,
                      fraction: float = HELD_PP_STD_FRACTION) -> dict:
    """sigmas (camera name -> CameraUncertainty) with the principal point and projection standard
    deviations of units of one model, whose one principal point the calibration estimated
    (frames: those cameras -> their image's width, height and COLMAP model name), widened in
    quadrature by how far a unit's own point may be from it: the spread real cameras' points
    have about the centre (principal_point_spread_px with `fraction`), since each unit's sensor
    sits where its own assembly put it (and its video window where its firmware did); the
    principal point by the larger axis's, the projection by both axes together.

    The shared estimate's covariance is that of the units' common point: a unit 1 % of the side
    from it is turned by about that over its focal length, which no covariance of the shared
    block shows (docs/design-notes.md, Units of one model: each its own principal point)."""
    out = dict(sigmas)
    for name, frame in frames.items():
        u = out.get(name)
        if u is None or u.principal_point_std_px is None:
            continue
        unit_px = principal_point_spread_px(*frame, fraction)
        out[name] = replace(u, principal_point_std_px=in_quadrature(u.principal_point_std_px,
                                                                    max(unit_px)),
                            projection_std_px=in_quadrature(u.projection_std_px,
                                                            float(np.hypot(*unit_px))))
    return out
