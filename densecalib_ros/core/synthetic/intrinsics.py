"""Intrinsics of a generated rig's cameras: lens profiles ("real", "ideal") and how the rig's
lenses relate to each other (RigSpec.lens_mix: one rig lens type, a mix of lenses, or units of one
camera model)."""
from __future__ import annotations

import numpy as np

from ..types import CameraIntrinsics
from .lens import is_perspective, monotonic_limit, radial_g

FOV_RANGE_DEG = {"RADIAL": (55.0, 75.0), "OPENCV_FISHEYE": (150.0, 190.0)}
FOV_LIMITS_DEG = {"RADIAL": (20.0, 120.0), "OPENCV_FISHEYE": (90.0, 230.0)}
FISHEYE_CIRCLE_RAD = np.deg2rad(120.0)  # lens circle: pixels beyond this angle stay black
# Lens profiles. "real": intrinsics as real lenses have them (target-based calibrations of
# Strecha's DSLR, a DTU lab camera, phones, the fisheye pair): principal points up to
# PP_OFFSET_FRACTION of each side off-centre per axis, pinhole focal lengths from 0.5x to 2.2x the
# image width (fields of view ~90 down to ~25 deg), fy != fx by up to PIXEL_ASPECT_FRACTION
# (pinhole cameras are then OPENCV with p1 = p2 = 0). "ideal": the principal point within 4 px
# of the centre, fx = fy, 55-75 deg (kinder than real cameras; kept for plumbing tests).
LENS_PROFILES = ("real", "ideal")
PP_OFFSET_FRACTION = 0.02
PIXEL_ASPECT_FRACTION = 0.005
REAL_FOCAL_WIDTH_RATIOS = (0.5, 2.2)
REAL_FOCAL_JITTER = 0.05  # cameras of one rig: the rig's focal ratio x exp(+-this)
REFERENCE_HALF_FOV_DEG = 32.5  # a 65 deg lens: the scale of the cameras' aim scatter
# How the lenses of a rig relate (RigSpec.lens_mix). "rig": one focal ratio for the rig, each
# camera within REAL_FOCAL_JITTER of it (the bench's rigs until issue 81). "mixed": each camera
# its own lens, its field of view uniform in fov_range_deg (default MIXED_FOV_DEG) and its
# distortion in MIXED_K_RANGES. "identical": N units of one camera model, UNIT_* apart.
LENS_MIXES = ("rig", "mixed", "identical")
# The held-out webcam rig spans 56-83 deg; Caliscope's four webcams 71-90 deg.
MIXED_FOV_DEG = (56.0, 83.0)
# Webcams differ in distortion far more than one lens type does: Caliscope's four measure k1
# -0.33 (a strong barrel) to +0.18. Draws a lens cannot have (folding back inside the image)
# are drawn again, so the strongest barrels go with the narrower fields of view.
MIXED_K_RANGES = ((-0.3, 0.15), (-0.05, 0.05))
# Webcams and camera traps filming 16:9 read that frame out of a 4:3 sensor, and the crop is not
# centred to the row: Caliscope's four webcams (ChArUco reference, 1280x720) put cy 1.8-4.8 % of
# the height off-centre (cx 0.6-1.7 % of the width). A "mixed" rig's perspective cameras with a
# frame wider than 4:3 draw cy within this fraction of the height (docs/benchmarks.md, The real
# rooms taken apart).
CROPPED_FRAME_PP_FRACTION = 0.05
# Units of one model: Pose2Sim's four Qualisys Miqus cameras measure f 1673.7-1681.6 px
# (+-0.24 %), k1 -0.0462..-0.0478 (+-0.0008) and k2 0.1347..0.1400 (+-0.0027); their principal
# points differ as independent units' do (cx 513-540 of 1088 px), which PP_OFFSET_FRACTION draws.
UNIT_FOCAL_SPREAD = 0.003
UNIT_K_SPREAD = (0.001, 0.003)


def a_limit(cam: CameraIntrinsics, theta_limit: float) -> float:
    """Ray angle limit -> limit of the model's radial variable (r = tan(theta) for RADIAL)."""
    return float(np.tan(theta_limit)) if is_perspective(cam) else float(theta_limit)


def _real_pinhole_ratio(rng: np.random.Generator, spec) -> float:
    """A "real" rig's focal length / image width (RigSpec docstring)."""
    if spec.fov_range_deg is not None:
        ratios = 0.5 / np.tan(np.deg2rad(np.asarray(spec.fov_range_deg, float)) / 2)
    else:
        ratios = np.asarray(REAL_FOCAL_WIDTH_RATIOS, float)
    return float(np.exp(rng.uniform(np.log(ratios.min()), np.log(ratios.max()))))


def _principal_point(rng: np.random.Generator, spec, model: str = "") -> tuple[float, float]:
    """A "real" lens's principal point (px) as it sits in a frame of spec's size: within
    PP_OFFSET_FRACTION of each side of the centre, cy within CROPPED_FRAME_PP_FRACTION of the
    height for a "mixed" rig's perspective camera whose frame is cropped wider than 4:3."""
    w, h = spec.width, spec.height
    if spec.lenses == "real":
        cropped = model == "RADIAL" and spec.lens_mix == "mixed" and 3 * w > 4 * h
        return (w / 2 + rng.uniform(-1, 1) * PP_OFFSET_FRACTION * w,
                h / 2 + rng.uniform(-1, 1)
                * (CROPPED_FRAME_PP_FRACTION if cropped else PP_OFFSET_FRACTION) * h)
    return w / 2 + rng.uniform(-4, 4) * w / 1024, h / 2 + rng.uniform(-4, 4) * w / 1024


def _ray_limit(cam: CameraIntrinsics, half_fov: float) -> float | None:
    """The largest ray angle (rad) cam images, or None where cam is no real lens: a pinhole
    whose model folds back before the image corner, a fisheye that folds back inside its field
    of view or does not fill the image horizontally."""
    w, h = cam.width, cam.height
    p = np.asarray(cam.params, float)
    if is_perspective(cam):
        f, fy, cx, cy = (p[0], p[0], p[1], p[2]) if cam.model == "RADIAL" else p[:4]
        theta_lim = float(np.arctan(monotonic_limit(cam, 4.0)))
        need = np.hypot(max(cx, w - cx) / f, max(cy, h - cy) / fy)  # r_d of the farthest corner
    else:
        f, cx = p[0], p[2]
        theta_lim = monotonic_limit(cam, float(FISHEYE_CIRCLE_RAD))
        if theta_lim < min(half_fov + np.deg2rad(10.0), FISHEYE_CIRCLE_RAD):
            return None  # folds back inside the field of view: not a real lens
        need = (max(cx, w - cx) + 8) / f  # the image must be filled horizontally
    if float(radial_g(cam, np.array([a_limit(cam, theta_lim)]))[0][0]) > need:
        return theta_lim
    return None


def sample_intrinsics(rng: np.random.Generator, spec, model: str, half_fov: float,
                      k_ranges: tuple | None = None) -> tuple[CameraIntrinsics, float]:
    """Random intrinsics of `model` with this half horizontal field of view (rad) and the
    largest ray angle (rad) the camera images. k_ranges: the pinhole's (k1, k2) ranges where
    not the default ones."""
    w, h = spec.width, spec.height
    cx, cy = _principal_point(rng, spec, model)
    while True:
        if model == "RADIAL":
            k_lo, k_hi = np.array(k_ranges or ((-0.15, 0.1), (-0.03, 0.03))).T
            k = np.array([rng.uniform(k_lo[0], k_hi[0]), rng.uniform(k_lo[1], k_hi[1])])
            probe = CameraIntrinsics("RADIAL", w, h, np.r_[1.0, cx, cy, k])
            f = (w / 2) / float(radial_g(probe, np.array([np.tan(half_fov)]))[0][0])
            if spec.lenses == "real":
                fy = f * (1 + rng.uniform(-PIXEL_ASPECT_FRACTION, PIXEL_ASPECT_FRACTION))
                cam = CameraIntrinsics("OPENCV", w, h, np.r_[f, fy, cx, cy, k, 0.0, 0.0])
            else:
                cam = CameraIntrinsics("RADIAL", w, h, np.r_[f, cx, cy, k])
        else:
            # Equidistant-like lens: small higher-order terms as in real OpenCV fisheye fits.
            k = np.array([rng.uniform(-0.04, 0.05), rng.uniform(-0.02, 0.02),
                          rng.uniform(-0.004, 0.004), rng.uniform(-0.001, 0.001)])
            probe = CameraIntrinsics("OPENCV_FISHEYE", w, h, np.r_[1.0, 1.0, cx, cy, k])
            f = (w / 2) / float(radial_g(probe, np.array([half_fov]))[0][0])
            fy = f * (1 + rng.uniform(-0.002, 0.002))
            cam = CameraIntrinsics("OPENCV_FISHEYE", w, h, np.r_[f, fy, cx, cy, k])
        theta_lim = _ray_limit(cam, half_fov)
        if theta_lim is not None:
            return cam, theta_lim


def unit_of(rng: np.random.Generator, spec, nominal: CameraIntrinsics, half_fov: float
            ) -> tuple[CameraIntrinsics, float]:
    """One unit of the camera model `nominal`: its focal length within UNIT_FOCAL_SPREAD, k1
    and k2 within UNIT_K_SPREAD, its own principal point; and its largest imaged ray angle."""
    p0 = np.asarray(nominal.params, float)
    k_at = {"RADIAL": 3, "OPENCV": 4, "OPENCV_FISHEYE": 4}[nominal.model]
    cx_at = 1 if nominal.model == "RADIAL" else 2
    while True:
        p = p0.copy()
        p[cx_at:cx_at + 2] = _principal_point(rng, spec)
        p[:cx_at] *= np.exp(rng.uniform(-UNIT_FOCAL_SPREAD, UNIT_FOCAL_SPREAD))
        p[k_at:k_at + 2] += [rng.uniform(-s, s) for s in UNIT_K_SPREAD]
        cam = CameraIntrinsics(nominal.model, nominal.width, nominal.height, p)
        theta_lim = _ray_limit(cam, half_fov)
        if theta_lim is not None:
            return cam, theta_lim


def _half_fov(rng: np.random.Generator, spec, c: int, rig_ratio: float | None) -> float:
    """Camera c's half horizontal field of view (rad), as spec's lens mix draws it."""
    model = spec.model_of(c)
    if spec.fov_deg is not None:
        return float(np.deg2rad(spec.fov_deg) / 2)
    if model == "RADIAL" and rig_ratio is not None:
        ratio = rig_ratio * np.exp(rng.uniform(-REAL_FOCAL_JITTER, REAL_FOCAL_JITTER))
        return float(np.arctan(0.5 / ratio))
    if model == "RADIAL" and spec.lens_mix == "mixed":
        return float(np.deg2rad(rng.uniform(*(spec.fov_range_deg or MIXED_FOV_DEG))) / 2)
    return float(np.deg2rad(rng.uniform(*FOV_RANGE_DEG[model])) / 2)


def rig_intrinsics(rng: np.random.Generator, spec
                   ) -> tuple[list[CameraIntrinsics], list[float], float]:
    """Every camera's intrinsics and imaged ray angle limit (rad), and the narrowest pinhole half
    field of view (rad; a 65 deg lens's where there is none). lens_mix "rig" draws as the rigs
    before lens_mix existed did (the same rig for the same seed)."""
    n = int(spec.num_cameras)
    real_pinhole = spec.lenses == "real" and spec.fov_deg is None and \
        spec.lens_mix != "mixed" and any(spec.model_of(c) == "RADIAL" for c in range(n))
    rig_ratio = _real_pinhole_ratio(rng, spec) if real_pinhole else None
    if spec.lens_mix == "identical":  # one camera model: camera 0's lens, each unit a little apart
        half = _half_fov(rng, spec, 0, rig_ratio)
        nominal, _ = sample_intrinsics(rng, spec, spec.model_of(0), half)
        units = [unit_of(rng, spec, nominal, half) for _ in range(n)]
        halves = [half] * n
    else:
        k_ranges = MIXED_K_RANGES if spec.lens_mix == "mixed" else None
        units, halves = [], []
        for c in range(n):
            halves.append(_half_fov(rng, spec, c, rig_ratio))
            units.append(sample_intrinsics(rng, spec, spec.model_of(c), halves[-1], k_ranges))
    pinhole_half = [half for c, half in enumerate(halves) if spec.model_of(c) == "RADIAL"]
    narrowest = min(pinhole_half) if pinhole_half else np.deg2rad(REFERENCE_HALF_FOV_DEG)
    return [u[0] for u in units], [u[1] for u in units], float(narrowest)
