"""Data types shared by the pipeline stages.

Conventions (used everywhere in the core):
- image coordinates are pixels in COLMAP's convention (top-left pixel centre at (0.5, 0.5));
- camera models and parameter vectors are COLMAP's (e.g. RADIAL = f, cx, cy, k1, k2;
  OPENCV_FISHEYE = fx, fy, cx, cy, k1, k2, k3, k4);
- poses are 4x4 row-major rigid transforms named `<to>_from_<from>`: `cam_from_world`
  maps world points into the camera frame (x right, y down, z forward).
"""
from __future__ import annotations

import functools
from dataclasses import dataclass, field, fields, replace
from typing import Optional, Sequence

import numpy as np

from .errors import InputError


def check_camera_names(names: Sequence) -> list[str]:
    """The names as a list; InputError unless each is a distinct, non-empty string usable as a
    file name: `<name>.yaml` and exports are written beside calibration.json, so a path
    separator or '..' would write outside the output folder."""
    names = list(names)
    for name in names:
        if not isinstance(name, str):
            raise InputError(f"Camera names must be strings, got {name!r} "
                             f"({type(name).__name__}): e.g. [f'cam{{i}}' for i in ...].")
        if (not name.strip() or name != name.strip() or name in (".", "..")
                or name.startswith(".") or any(c in name for c in "/\\")
                or any(ord(c) < 32 for c in name)):
            raise InputError(f"Camera name {name!r} cannot name a file (<camera>.yaml is written "
                             "for each): use letters, digits, '_' or '-', without '/' or a "
                             "leading '.' or space.")
        if not name.isprintable() or any("\ud800" <= c <= "\udfff" for c in name):
            raise InputError(f"Camera name {name!r} is not printable UTF-8 text (a folder or file "
                             "named in another encoding?): rename it with letters, digits, '_' "
                             "or '-'.")
    repeated = sorted({n for n in names if names.count(n) > 1})
    if repeated:
        raise InputError(f"Camera names repeat ({', '.join(repeated)}): give each camera its own "
                         "name.")
    return names


def colmap_parameter_names(camera) -> list[str]:
    """A pycolmap.Camera's parameter names, in params order (from its params_info)."""
    return [name.strip() for name in camera.params_info.split(",")]


@functools.lru_cache(maxsize=None)
def colmap_model_id(model: str):
    """pycolmap's CameraModelId of a COLMAP model name; InputError for a name COLMAP lacks."""
    import pycolmap

    if str(model) not in pycolmap.CameraModelId.__members__ or model == "INVALID":
        raise InputError(f"Unknown camera model {model!r}: use one of COLMAP's, e.g. "
                         "RADIAL, OPENCV, OPENCV_FISHEYE, RADIAL_FISHEYE, PINHOLE.")
    return pycolmap.CameraModelId.__members__[str(model)]


@dataclass
class CameraIntrinsics:
    """One camera's intrinsics in COLMAP terms."""

    model: str  # COLMAP model name, e.g. "RADIAL", "OPENCV_FISHEYE"
    width: int
    height: int
    params: np.ndarray  # float64, COLMAP parameter order

    def to_pycolmap(self, camera_id: int = 1):
        # Built attribute by attribute: the SfM builds tens of thousands of these, and pycolmap's
        # keyword constructor takes five times as long for the same camera.
        import pycolmap

        camera = pycolmap.Camera()
        camera.camera_id = camera_id
        camera.model = colmap_model_id(self.model)
        camera.width, camera.height = int(self.width), int(self.height)
        camera.params = np.asarray(self.params, dtype=np.float64)
        return camera

    @property
    def parameter_names(self) -> list[str]:
        """COLMAP's names of the model's parameters, e.g. ["f", "cx", "cy", "k1", "k2"]."""
        return colmap_parameter_names(self.to_pycolmap())

    @classmethod
    def from_pycolmap(cls, camera) -> "CameraIntrinsics":
        return cls(model=camera.model.name, width=int(camera.width), height=int(camera.height),
                   params=np.array(camera.params, dtype=np.float64))


@dataclass
class SiteMatches:
    """Matches of one ordered camera pair (i -> j) as a map between site tables.

    `target[s]` is the index of the site of camera j that site s of camera i maps to, or -1.
    `certainty[s]` in [0, 1] (0 where target is -1). Both have length = number of sites of i.
    `target_xy_px` (optional, matchers with sub-pixel output): row s is the refined COLMAP pixel
    position in camera j of the scene point that site s of i shows, NaN where target is -1 or the
    position was not refined. `target` stays the site index (cycles compose on indices); consumers
    that want sub-pixel observations use target_xy_px where finite, else sites[j][target[s]].
    """

    target: np.ndarray  # int32 (S_i,)
    certainty: np.ndarray  # float32 (S_i,)
    target_xy_px: Optional[np.ndarray] = None  # float64 (S_i, 2), NaN = not refined


@dataclass
class SiteMatchSet:
    """The matcher output for one time step: a site table per camera and matches per ordered pair.

    sites[c]: float64 (S_c, 2) pixel coordinates of camera c's sites in its original image.
    pairs[(i, j)]: SiteMatches for every ordered pair i != j that the matcher produced.
    For detector-based matchers (j, i) is the inverse map of (i, j) (mutual matches); for dense
    matchers both directions are predicted independently, so 2-cycles are a real test.
    """

    sites: list[np.ndarray]
    pairs: dict[tuple[int, int], SiteMatches]
    image_sizes: list[tuple[int, int]]  # (width, height) per camera


@dataclass
class Tracks:
    """Sampled correspondence tracks across the rig's cameras.

    xy_px[t, c] is track t's observation in camera c (NaN where camera c does not observe it).
    A track comes from one cycle at one time step, so it has at most one observation per camera.
    """

    xy_px: np.ndarray  # float64 (T, C, 2), NaN = not observed
    cycle_order: np.ndarray  # int32 (T,), 2..4: the order of the cycle the track was sampled from
    score: np.ndarray  # float64 (T,), triangulation-angle score (0 when scoring is off)
    time_index: np.ndarray  # int32 (T,), the frame set the track was sampled from

    @property
    def num_tracks(self) -> int:
        return int(self.xy_px.shape[0])

    @property
    def num_cameras(self) -> int:
        return int(self.xy_px.shape[1])

    def observed(self) -> np.ndarray:
        """bool (T, C): whether camera c observes track t."""
        return ~np.isnan(self.xy_px[..., 0])

    def subset(self, mask: np.ndarray) -> "Tracks":
        return Tracks(self.xy_px[mask], self.cycle_order[mask], self.score[mask],
                      self.time_index[mask])

    def sample(self, max_tracks: int, seed: int = 0) -> "Tracks":
        """At most max_tracks of the tracks, a seeded random choice kept in track order; self
        (the same object) when there are not more."""
        if self.num_tracks <= max_tracks:
            return self
        pick = np.random.default_rng(seed).choice(self.num_tracks, max_tracks, replace=False)
        return self.subset(np.sort(pick))

    @staticmethod
    def concatenate(parts: list["Tracks"], num_cameras: int) -> "Tracks":
        if not parts:
            return Tracks(np.zeros((0, num_cameras, 2)), np.zeros(0, np.int32), np.zeros(0),
                          np.zeros(0, np.int32))
        return Tracks(np.concatenate([p.xy_px for p in parts]),
                      np.concatenate([p.cycle_order for p in parts]),
                      np.concatenate([p.score for p in parts]),
                      np.concatenate([p.time_index for p in parts]))


@dataclass
class CameraQuality:
    reprojection_rms_px: float
    num_observations: int
    coverage: float  # fraction of image grid cells (10x10) holding at least one observation
    # Observations of points that >= 3 cameras see (the rest rest on 2-view geometry alone).
    # A diagnostic, not a verdict: on generated rigs cameras with < 30 were often, not always,
    # the less accurate ones. None in files written before it was recorded.
    num_multiview_observations: Optional[int] = None
    # The same count in the SfM's fit that placed the camera, where the image refinement then
    # re-measured the rig on other (dense) correspondences; None where it did not.
    sfm_multiview_observations: Optional[int] = None
    # Standard deviations from the final adjustment's information matrix (core.method.uncertainty; a
    # lower bound). None where not estimated; a principal point held there has how far a real
    # camera's may lie from it (principal_point_held; files written before 2026-12-06: None).
    focal_std_px: Optional[float] = None
    principal_point_std_px: Optional[float] = None
    projection_std_px: Optional[float] = None  # the intrinsics as a whole, mean over the image
    # Of the camera's rotation relative to the reference camera, deg (core.method.rotation_spread);
    # None for the reference camera and where not estimated (no refinement on the images).
    rotation_std_deg: Optional[float] = None
    # The intrinsics the images pinned down (core.method.image_refinement: "f", "cx", "cy", "k1",
    # "k2", "aspect"); those with a prior that are not listed rest on it (the principal point near
    # the image centre). None where not judged (no refinement on the images, given intrinsics).
    estimated_intrinsics: Optional[list] = None
    # True where the final bundle adjustment held the principal point (where it started: the
    # image centre or a previous calibration's); None where it did not say (the image refinement's
    # estimated_intrinsics say it there, files written before 2026-12-06).
    principal_point_held: Optional[bool] = None


@dataclass
class RigCamera:
    name: str
    intrinsics: CameraIntrinsics
    cam_from_rig: np.ndarray  # 4x4; the rig frame is the reference camera's frame
    quality: Optional[CameraQuality] = None


@dataclass(slots=True)
class RigQuality:
    """What a calibration was made from, how well it fits and what was found on the way; saved as
    calibration.json's "quality" (to_dict/from_dict: a field left None is left out; keys this
    version does not know, from a newer or hand-edited file, are kept in `extra`). Slots: a
    misspelt field is an error, not a value that is silently never saved."""

    # the fit (calibration_result.rig_from_state)
    reprojection_rms_px: Optional[float] = None
    num_points: Optional[int] = None
    num_observations: Optional[int] = None
    num_registered: Optional[int] = None
    num_cameras: Optional[int] = None
    # the run (pipeline)
    pipeline: Optional[str] = None
    preset: Optional[str] = None
    sfm_runtime_s: Optional[float] = None
    view_order: Optional[list] = None  # camera names in the order they were registered
    match_tracks: Optional[int] = None  # keypoint-match tracks the rig was refined on
    moved_cameras: Optional[list] = None  # cameras that refinement on those tracks moved
    global_init: Optional[str] = None  # the global pipeline's start (core.method.global_sfm)
    gauge_camera: Optional[str] = None
    num_outlier_observations: Optional[int] = None
    stage_residuals: Optional[dict] = None  # the global pipeline's residuals per BA stage
    consensus_runs: Optional[int] = None  # core.robust.consensus
    consensus_failed_runs: Optional[int] = None
    consensus_seed: Optional[int] = None
    # The first run's focal multi-start settled: the later runs tried only these starts.
    consensus_settled_starts: Optional[list] = None
    consensus_worse_fit_runs: Optional[int] = None
    consensus_kept_by_fit: Optional[bool] = None
    consensus_disagreement_deg: Optional[float] = None
    # Where the runs disagreed: the runner-up and the kept rig both refined on the dense image
    # correspondences, how far apart they came out (pipeline._refine_runner_up), or where the
    # runs stopped for meeting refined, the median over the others (pipeline._no_more_runs).
    consensus_refined_disagreement_deg: Optional[float] = None
    consensus_least_determined_pairs_deg: Optional[dict] = None  # "a/b" -> deg
    # Each camera not registered -> [the camera it shares the most keypoint matches with, how
    # many] (pipeline.calibrate_from_matches; calibration_result.unregistered_warning).
    unregistered_best_partner: Optional[dict] = None
    # Sift left a rig of perspective cameras undetermined, so it was matched again
    # (core.robust.second_matcher): {first, first_result (why it was undetermined), second,
    # second_result, kept (the matcher whose calibration was kept)}.
    rematch: Optional[dict] = None
    focal_hops: Optional[list] = None  # core.robust.focal_hops, one line per hop
    image_refinement_tracks: Optional[int] = None  # core.method.image_refinement
    image_refinement_noise_px: Optional[float] = None
    # camera -> dense observations, where too few of them kept the refinement from the rig
    image_refinement_too_few_dense: Optional[dict] = None
    # the camera groups its dense points leave unconnected, where there are two or more
    image_refinement_groups_apart: Optional[list] = None
    principal_point_prior_std_fraction: Optional[float] = None
    held_pp_std_fraction: Optional[float] = None  # core.method.uncertainty
    # The runs that disagree whose spread entered the sigmas (uncertainty.with_runs_spread)
    sigmas_runs_spread: Optional[int] = None
    # The matcher whose refined calibration, not kept, stands apart from the kept one by more than
    # the sigmas: its distance raised f_std, pp_std, proj_std and the rotation sigmas (second_matcher.
    # with_matchers_apart)
    sigmas_matchers_spread: Optional[str] = None
    matcher: Optional[str] = None
    num_frame_sets: Optional[int] = None
    runtime_s: Optional[float] = None
    # the user's data it was given (camera -> ...)
    given_intrinsics: Optional[dict] = None  # camera -> model (known_intrinsics.describe_known)
    given_intrinsics_fit: Optional[dict] = None  # camera -> how they fit the scene
    camera_lens: Optional[dict] = None
    masked_cameras: Optional[list] = None
    exif_focal_px: Optional[dict] = None
    # groups of cameras estimated as units of one model in the SfM: [{"cameras", "why"}]
    identical_units: Optional[list] = None
    info_strips: Optional[dict] = None  # camera -> the info strips ignored
    # a recalibration (core.recalibration)
    init: Optional[str] = None  # what the kept run started from
    change_vs_previous: Optional[dict] = None  # camera -> its change (vars of CameraChange)
    change_summary: Optional[str] = None
    frame_sets_before_change: Optional[int] = None  # older frame sets left out: the rig changed
    # the provenance (core.io.export.note_provenance)
    input: Optional[dict] = None
    densecalib_version: Optional[str] = None
    calibrated_utc: Optional[str] = None
    # the products recorded with it
    floor: Optional[dict] = None  # core.products.floor.Floor.to_dict
    scale_from_baseline: Optional[dict] = None  # core.products.scale
    scale_from_points: Optional[dict] = None
    undistorted_from: Optional[str] = None  # densecalib undistort
    stereo_rectified_pair: Optional[list] = None
    source: Optional[str] = None  # where it came from when no calibration made it (ground truth)
    # said to the user once and kept for whoever looks later (calibration_result.warn_user)
    warnings: list = field(default_factory=list)
    extra: dict = field(default_factory=dict)

    def update(self, **values) -> None:
        """Set the named fields (AttributeError on a name that is none: slots)."""
        for name, value in values.items():
            setattr(self, name, value)

    def fit_rms_px(self) -> float:
        """The reprojection RMS [px], NaN where none was recorded (a hand-written file)."""
        return float("nan") if self.reprojection_rms_px is None else self.reprojection_rms_px

    def copy(self) -> "RigQuality":
        """A copy whose warnings can change without changing these."""
        return replace(self, warnings=list(self.warnings), extra=dict(self.extra))

    def to_dict(self) -> dict:
        out = {name: getattr(self, name) for name in _RIG_QUALITY_FIELDS
               if getattr(self, name) is not None}
        if not self.warnings:
            out.pop("warnings", None)
        out.update((k, v) for k, v in self.extra.items() if k not in _RIG_QUALITY_FIELDS)
        return out

    @classmethod
    def from_dict(cls, data: dict) -> "RigQuality":
        known = {k: v for k, v in data.items() if k in _RIG_QUALITY_FIELDS}
        known["warnings"] = list(known.get("warnings") or [])
        return cls(**known, extra={k: v for k, v in data.items()
                                   if k not in _RIG_QUALITY_FIELDS})


_RIG_QUALITY_FIELDS = tuple(f.name for f in fields(RigQuality) if f.name != "extra")


@dataclass
class RigCalibration:
    """A calibrated rig. Translation units are those of the reconstruction (arbitrary scale) unless
    `metric_scale` is True (a known baseline was applied)."""

    reference_camera: str
    cameras: dict[str, RigCamera]
    failed_cameras: list[str] = field(default_factory=list)
    quality: RigQuality = field(default_factory=RigQuality)
    metric_scale: bool = False
