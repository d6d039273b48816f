"""Metric scale: SfM recovers the rig only up to scale. It comes from a known baseline (the
distance between two cameras' optical centres) or a known distance between two scene points
(`densecalib scale`), and every length of the calibration is multiplied by one factor."""
from __future__ import annotations

import copy
import dataclasses
import logging

import numpy as np

from ..errors import InputError
from ..types import RigCalibration

log = logging.getLogger(__name__)


# How to make a calibration metric, for every message about its missing scale: by command, node
# parameter and library function (the core's messages reach all three kinds of user).
HOW_TO_SCALE = ("calibrate with --known-baseline (node: known_baseline_m; library: "
                "core.products.scale.apply_known_baseline), or measure a known length with "
                "`densecalib scale` (library: core.products.scale.apply_known_distance)")


def camera_distance(rig: RigCalibration, camera_a: str, camera_b: str) -> float:
    """Distance between the optical centres of two cameras, in the rig's translation units."""
    for name in (camera_a, camera_b):
        if name not in rig.cameras:
            raise InputError(f"Camera {name!r} is not in the calibration (calibrated cameras: "
                             f"{', '.join(rig.cameras)}).")
    centres = [np.linalg.inv(rig.cameras[n].cam_from_rig)[:3, 3] for n in (camera_a, camera_b)]
    return float(np.linalg.norm(centres[0] - centres[1]))


# quality keys saying where a metric scale came from; a new scale replaces them all
SCALE_RECORDS = ("scale_from_baseline", "scale_from_points")
SCALE_WARNINGS = ("scale from points:", "no metric scale:")  # how those warnings begin
MAX_SCALE_RELATIVE_STD = 0.02  # a scale from scene points less sure than this gets a warning


MIN_LENGTH_M, MAX_LENGTH_M = 1e-6, 1e6  # a known length outside is a typo, not a rig


def _check_length_m(what: str, length_m: float) -> None:
    if not MIN_LENGTH_M <= length_m <= MAX_LENGTH_M:
        raise InputError(f"The known {what} must be a length in metres between {MIN_LENGTH_M:g} "
                         f"and {MAX_LENGTH_M:g}, got {length_m}.")


def scaled_rig(rig: RigCalibration, factor: float, record: dict) -> RigCalibration:
    """A copy of `rig` with every length multiplied by `factor` (the cameras' translations and
    the floor frame's origin, fit and camera heights; angles and pixels are unchanged), marked
    metric, its scale's origin `record` ({SCALE_RECORDS key: details}) replacing any earlier."""
    unusable = InputError(f"The scale factor {factor:g} is not usable: give the length in "
                          "metres.")
    if not (np.isfinite(factor) and factor > 0):
        raise unusable
    scaled = copy.deepcopy(rig)
    for cam in scaled.cameras.values():
        cam.cam_from_rig = np.array(cam.cam_from_rig, dtype=np.float64)
        with np.errstate(over="ignore", under="ignore"):
            cam.cam_from_rig[:3, 3] *= factor
        if not np.isfinite(cam.cam_from_rig).all():
            raise unusable
    floor = scaled.quality.floor
    if floor:
        floor_from_rig = np.asarray(floor["floor_from_rig"], dtype=np.float64).reshape(4, 4)
        floor_from_rig[:3, 3] *= factor  # floor(s p) = s floor(p): only the offset scales
        floor["floor_from_rig"] = floor_from_rig.ravel().tolist()
        floor["rms"] = float(floor["rms"]) * factor
        floor["camera_heights"] = {n: float(h) * factor
                                   for n, h in floor["camera_heights"].items()}
    scaled.quality.update(**{key: None for key in SCALE_RECORDS})
    scaled.quality.warnings = [w for w in scaled.quality.warnings  # those about the scale replaced
                               if not w.startswith(SCALE_WARNINGS)]
    scaled.quality.update(**record)
    scaled.metric_scale = True
    return scaled


def apply_known_baseline(rig: RigCalibration, camera_a: str, camera_b: str,
                         baseline_m: float) -> RigCalibration:
    """A copy of `rig` scaled (scaled_rig) so that the optical centres of `camera_a` and
    `camera_b` are `baseline_m` metres apart."""
    _check_length_m("baseline", baseline_m)
    if camera_a == camera_b:
        raise InputError(f"The known baseline needs two different cameras, got {camera_a!r} twice.")
    distance = camera_distance(rig, camera_a, camera_b)
    if not distance > 1e-12:
        raise InputError(f"Cameras {camera_a!r} and {camera_b!r} share one optical centre in the "
                         "calibration: choose two cameras that are apart to fix the scale.")
    factor = baseline_m / distance
    return scaled_rig(rig, factor, {"scale_from_baseline": {
        "cameras": [camera_a, camera_b], "baseline_m": float(baseline_m), "factor": factor}})


def apply_known_distance(rig: RigCalibration, point_a: dict, point_b: dict, distance_m: float,
                         pixel_sigma: float = 1.0) -> RigCalibration:
    """A copy of `rig` scaled (scaled_rig) so that two scene points are `distance_m` metres
    apart: a measured length in the scene (a door's width, a tape laid on the floor) where the
    cameras' own distances are unknown (CCTV, a forensic scene). Each point is given by its
    pixels in two or more cameras, {camera: (x, y)} OpenCV pixels (core.products.triangulation). The
    scale's relative standard deviation, from the points' covariances at `pixel_sigma`, is
    recorded; above MAX_SCALE_RELATIVE_STD it is also a warning."""
    from .triangulation import distance, triangulate

    _check_length_m("distance", distance_m)
    a, b = triangulate(rig, point_a, pixel_sigma), triangulate(rig, point_b, pixel_sigma)
    distance_rig, std_rig = distance(a, b)
    if not distance_rig > 1e-12:
        raise InputError("The two points triangulate to one place: give the pixels of two "
                         "different scene points, as far apart as the scene allows.")
    relative_std = std_rig / distance_rig
    factor = distance_m / distance_rig
    scaled = scaled_rig(rig, factor, {"scale_from_points": {
        "points": [{n: list(map(float, xy)) for n, xy in p.items()} for p in (point_a, point_b)],
        "distance_m": float(distance_m), "factor": factor, "relative_std": relative_std,
        "pixel_sigma": float(pixel_sigma)}})
    problems = [f"point {k}: {w}" for k, p in (("A", a), ("B", b)) for w in p.warnings]
    if relative_std > MAX_SCALE_RELATIVE_STD:
        problems.append(f"the scale is only known to {100 * relative_std:.1f} % (1 sigma at "
                        f"{pixel_sigma:g} px): choose points farther apart, nearer the cameras, "
                        "or seen from directions further apart")
    for problem in problems:
        warning = f"scale from points: {problem}"
        log.warning("%s", warning)
        scaled.quality.warnings.append(warning)
    return scaled


def rig_units_per_model_unit(reconstruction, rig: RigCalibration) -> float:
    """Ratio of the distance between the reference camera and the camera farthest from it in
    the rig file to the same distance in a pycolmap.Reconstruction of it (the two are refined to
    one shape but may be saved at their own scales)."""
    centres = {im.name: np.asarray(im.projection_center()) for im in
               reconstruction.images.values() if im.name in rig.cameras}
    ref = rig.reference_camera
    if ref not in centres or len(centres) < 2:
        return 1.0
    far = max(centres, key=lambda n: float(np.linalg.norm(centres[n] - centres[ref])))
    model = float(np.linalg.norm(centres[far] - centres[ref]))
    return camera_distance(rig, ref, far) / model if model > 0 else 1.0


def move_model_to_rig_frame(reconstruction, rig: RigCalibration) -> None:
    """Put a pycolmap.Reconstruction of `rig` (in place) in the rig's frame and units: world =
    the reference camera's frame, lengths as in the rig file. SfM leaves it in a frame and unit
    of its own; someone reading OUT/colmap beside calibration.json would otherwise combine
    points in one unit with camera positions in another."""
    import pycolmap

    ref = next((im for im in reconstruction.images.values()
                if im.name == rig.reference_camera), None)
    if ref is None:
        return
    factor = rig_units_per_model_unit(reconstruction, rig)
    rig_from_world = ref.cam_from_world()  # the rig frame is the reference camera's
    reconstruction.transform(pycolmap.Sim3d(factor, rig_from_world.rotation,
                                            factor * np.asarray(rig_from_world.translation)))


def scale_reconstruction(reconstruction, factor: float) -> None:
    """Scale a pycolmap.Reconstruction in place about its world origin (camera centres and
    points) by `factor`."""
    import pycolmap

    reconstruction.transform(pycolmap.Sim3d(factor, pycolmap.Rotation3d(), np.zeros(3)))


def scale_reconstruction_to_baseline(reconstruction, camera_a: str, camera_b: str,
                                     baseline_m: float) -> None:
    """Scale a pycolmap.Reconstruction in place (about its world origin: camera centres and
    points) so that the images named camera_a and camera_b are baseline_m metres apart, so the
    COLMAP model written beside a metric calibration is metric too. A factor of its own: models
    saved before they were put in the rig's frame and units (move_model_to_rig_frame) kept SfM's."""
    centres = {im.name: np.asarray(im.projection_center()) for im in reconstruction.images.values()}
    distance = float(np.linalg.norm(centres[camera_a] - centres[camera_b]))
    scale_reconstruction(reconstruction, baseline_m / distance)


def with_known_baseline(result, camera_a: str, camera_b: str, baseline_m: float):
    """A pipeline CalibrationResult made metric: its rig scaled by apply_known_baseline (a copy)
    and its reconstruction scaled to match (in place). When a baseline camera did not register,
    the result stays up to scale with a warning in rig.quality.warnings (the calibration of
    the other cameras is still worth keeping)."""
    missing = [c for c in (camera_a, camera_b) if c not in result.rig.cameras]
    if missing:
        warning = (f"no metric scale: {', '.join(missing)} did not register, so the known "
                   f"baseline {camera_a}-{camera_b} cannot be applied; the rig is up to scale")
        log.warning("%s", warning)
        result.rig.quality.warnings.append(warning)
        return result
    rig = apply_known_baseline(result.rig, camera_a, camera_b, baseline_m)
    if result.reconstruction is not None:
        scale_reconstruction_to_baseline(result.reconstruction, camera_a, camera_b, baseline_m)
    return dataclasses.replace(result, rig=rig)


def warn_if_scale_lost(rig: RigCalibration, previous: RigCalibration | None) -> None:
    """A recalibration of a metric calibration that came out up to scale (its scale was from
    scene points, which moved cameras no longer see where they did, and no baseline was given):
    say so in rig.quality.warnings."""
    if previous is None or not previous.metric_scale or rig.metric_scale:
        return
    warning = ("no metric scale: the previous calibration was metric"
               + (" from two scene points" if previous.quality.scale_from_points else "")
               + ", this one is up to scale; for metres again " + HOW_TO_SCALE)
    log.warning("%s", warning)
    rig.quality.warnings.append(warning)
