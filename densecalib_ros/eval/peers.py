"""Peer baselines: what a user would otherwise run on the rig's images, with pycolmap 4.2.1.

One image per camera (the first time step), one camera per image (camera_mode PER_IMAGE); where
the scene has several frame sets (a rig filmed while the scene changes), every frame of a camera
in one folder and one COLMAP camera per folder (PER_FOLDER: its intrinsics shared by its frames,
as a user who knows the rig would set it up), the camera's pose taken from its first registered
frame. SIFT features, exhaustive matching, then either
- "colmap": incremental SfM (pycolmap.incremental_mapping), or
- "glomap": global SfM. COLMAP 4.x's global mapper does not estimate unknown focal lengths itself
  (the standalone GLOMAP did, in its view-graph calibration step), so, as COLMAP documents for
  uncalibrated images, pycolmap.calibrate_view_graph runs before pycolmap.global_mapping.
Departures from the command-line defaults a user must make for a 3-10 camera rig: min_model_size is
2 (the incremental default of 10 would discard every rig model). Everything else is default.

A peer never raises on a failed reconstruction: it returns a PeerResult with nothing registered and
a message, so a benchmark table shows 0 registered / AUC 0.
"""
from __future__ import annotations

import contextlib
import logging
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional, Sequence

import cv2
import numpy as np

from ..core.colmap_logging import quiet_colmap
from ..core.errors import InputError
from ..core.types import CameraIntrinsics, RigCalibration, RigCamera, RigQuality

log = logging.getLogger(__name__)

PEER_METHODS = ("colmap", "glomap")
# Initial COLMAP camera model per lens type (peers estimate one camera per image).
PEER_CAMERA_MODELS = {"pinhole": "SIMPLE_RADIAL", "fisheye": "OPENCV_FISHEYE"}


@dataclass
class PeerResult:
    """A peer's reconstruction, keyed by camera name.

    cameras[name]: estimated intrinsics; cam_from_world[name]: 4x4 pose in the reconstruction's
    world frame (arbitrary scale); unregistered: camera names not in the largest model.
    """

    method: str
    cameras: dict[str, CameraIntrinsics] = field(default_factory=dict)
    cam_from_world: dict[str, np.ndarray] = field(default_factory=dict)
    unregistered: list[str] = field(default_factory=list)
    runtime_s: float = 0.0
    num_points3d: int = 0
    message: str = ""  # why nothing (or not everything) was registered

    def to_rig_calibration(self, camera_names: Sequence[str]) -> RigCalibration:
        """As a RigCalibration whose rig frame is the first registered camera of `camera_names`."""
        registered = [n for n in camera_names if n in self.cam_from_world]
        reference = registered[0] if registered else (camera_names[0] if camera_names else "")
        cameras = {}
        if registered:
            world_from_ref = np.linalg.inv(self.cam_from_world[reference])
            cameras = {n: RigCamera(n, self.cameras[n], self.cam_from_world[n] @ world_from_ref)
                       for n in registered}
        return RigCalibration(reference, cameras,
                              failed_cameras=[n for n in camera_names if n not in self.cam_from_world],
                              quality=RigQuality(runtime_s=self.runtime_s, extra=dict(
                                  method=self.method, num_points3d=self.num_points3d,
                                  message=self.message)))


def run_peer(method: str, images: Sequence[np.ndarray], camera_names: Sequence[str],
             lens: str | Sequence[str] = "pinhole", num_threads: int = -1, seed: int = 0,
             workdir: Optional[str] = None, single_camera: bool = False,
             later_frames: Sequence[Sequence[np.ndarray]] = ()) -> PeerResult:
    """Reconstruct one image per camera with a peer method.

    images[c]: (H, W, 3) uint8 RGB image of camera camera_names[c]; later_frames[t][c]: the
    camera's images at later times (module docstring). lens: "pinhole" or "fisheye"
    (picks the initial camera model), for all cameras or one per camera (a rig mixing lenses).
    num_threads: -1 = all cores. workdir: keep the COLMAP database and models there (default: a
    temporary folder, removed afterwards). single_camera: one camera for all images (COLMAP's
    single camera mode: one physical camera moved between shots).
    """
    if method not in PEER_METHODS:
        raise InputError(f"Unknown peer method {method!r}: choose one of {', '.join(PEER_METHODS)}.")
    lenses = [lens] * len(camera_names) if isinstance(lens, str) else list(lens)
    if any(v not in PEER_CAMERA_MODELS for v in lenses) or len(lenses) != len(camera_names):
        raise InputError(f"Unknown lens type(s) {lens!r}: choose one of "
                         f"{', '.join(PEER_CAMERA_MODELS)}, for all cameras or one per camera.")
    for t, frame in enumerate((images, *later_frames)):
        if len(frame) != len(camera_names):
            raise InputError(f"Frame set {t} has {len(frame)} images for {len(camera_names)} "
                             "camera names.")
    with contextlib.ExitStack() as stack:
        root = Path(workdir) if workdir else Path(stack.enter_context(
            tempfile.TemporaryDirectory(prefix=f"densecalib_{method}_")))
        start = time.perf_counter()
        try:
            with quiet_colmap():
                result = _reconstruct(method, [images, *later_frames], list(camera_names),
                                      lenses, num_threads, seed, root, single_camera)
        except Exception as exc:  # a peer's failure is a benchmark result, not a crash
            log.warning("%s failed: %s", method, exc)
            result = PeerResult(method, unregistered=list(camera_names),
                                message=f"{type(exc).__name__}: {exc}")
        result.runtime_s = time.perf_counter() - start
        return result


def _reconstruct(method: str, frames: Sequence[Sequence[np.ndarray]], camera_names: list[str],
                 lenses: list[str], num_threads: int, seed: int, root: Path,
                 single_camera: bool = False) -> PeerResult:
    import pycolmap

    image_dir, model_dir, database = root / "images", root / "models", root / "database.db"
    image_dir.mkdir(parents=True, exist_ok=True)
    model_dir.mkdir(parents=True, exist_ok=True)
    per_folder = len(frames) > 1
    file_to_name, lens_of_file = _write_images(frames, camera_names, lenses, image_dir,
                                               per_folder)
    mode = (pycolmap.CameraMode.SINGLE if single_camera else
            pycolmap.CameraMode.PER_FOLDER if per_folder else pycolmap.CameraMode.PER_IMAGE)

    pycolmap.set_random_seed(seed)
    extraction = pycolmap.FeatureExtractionOptions()
    extraction.num_threads = num_threads
    extraction.use_gpu = False
    # One extraction per camera model: the reader gives every image of a call the same model.
    for lens in sorted(set(lenses)):
        reader = pycolmap.ImageReaderOptions()
        reader.camera_model = PEER_CAMERA_MODELS[lens]
        pycolmap.extract_features(database, image_dir,
                                  image_names=sorted(f for f in file_to_name
                                                     if lens_of_file[f] == lens),
                                  camera_mode=mode,
                                  reader_options=reader, extraction_options=extraction,
                                  device=pycolmap.Device.cpu)
    matching = pycolmap.FeatureMatchingOptions()
    matching.num_threads = num_threads
    matching.use_gpu = False
    verification = pycolmap.TwoViewGeometryOptions()
    verification.ransac.random_seed = seed
    pycolmap.match_exhaustive(database, matching_options=matching,
                              verification_options=verification, device=pycolmap.Device.cpu)

    database_handle = pycolmap.Database.open(database)
    num_verified = int(database_handle.num_verified_image_pairs())
    database_handle.close()
    num_pairs = len(file_to_name) * (len(file_to_name) - 1) // 2
    message = ""
    if method == "colmap":
        options = pycolmap.IncrementalPipelineOptions()
        options.num_threads = num_threads
        options.random_seed = seed
        options.min_model_size = 2
        models = pycolmap.incremental_mapping(database, image_dir, model_dir, options)
    else:
        calibration = pycolmap.ViewGraphCalibrationOptions()
        calibration.random_seed = seed
        if not pycolmap.calibrate_view_graph(database, calibration):
            message = "view-graph calibration failed; global mapping used the prior focal lengths"
        options = pycolmap.GlobalPipelineOptions()
        options.num_threads = num_threads
        options.random_seed = seed
        options.min_model_size = 2
        models = pycolmap.global_mapping(database, image_dir, model_dir, options)

    if not models:
        return PeerResult(method, unregistered=list(camera_names),
                          message=(message + "; " if message else "") + "no model reconstructed "
                          f"({num_verified} of {num_pairs} image pairs verified)")
    rec = max(models.values(), key=lambda r: r.num_reg_images())
    result = PeerResult(method, num_points3d=int(rec.num_points3D()), message=message)
    for image in sorted(rec.images.values(), key=lambda im: im.name):
        name = file_to_name[image.name]
        if not image.has_pose or name in result.cam_from_world:  # a later frame of the camera
            continue
        result.cameras[name] = CameraIntrinsics.from_pycolmap(rec.cameras[image.camera_id])
        result.cam_from_world[name] = np.asarray(image.cam_from_world().matrix(), float)
        result.cam_from_world[name] = np.vstack([result.cam_from_world[name], [0, 0, 0, 1]])
    result.unregistered = [n for n in camera_names if n not in result.cam_from_world]
    return result


def _write_images(frames: Sequence[Sequence[np.ndarray]], camera_names: list[str],
                  lenses: list[str], image_dir: Path, per_folder: bool
                  ) -> tuple[dict[str, str], dict[str, str]]:
    """frames[t][c] written under image_dir for COLMAP's image reader: one file per camera, or
    where per_folder (camera mode PER_FOLDER) one folder per camera with a file per frame set.
    Returns file name -> camera name and file name -> lens."""
    # File names by index: camera names need not be valid file names. BMP, not PNG: once pycolmap
    # is imported before cv2, cv2's PNG encoder aborts the process (the two disagree on zlib:
    # "free(): invalid pointer" in deflateEnd, pycolmap 4.2.1 + opencv 5.0.0); BMP needs no zlib.
    file_to_name, lens_of_file = {}, {}
    for t, frame in enumerate(frames):
        for k, (image, name) in enumerate(zip(frame, camera_names)):
            file_name = f"{k:03d}/{t:03d}.bmp" if per_folder else f"{k:03d}.bmp"
            (image_dir / file_name).parent.mkdir(exist_ok=True)
            if not cv2.imwrite(str(image_dir / file_name),
                               cv2.cvtColor(image, cv2.COLOR_RGB2BGR)):
                raise InputError(f"Cannot write image of camera {name!r} to {image_dir}.")
            file_to_name[file_name], lens_of_file[file_name] = name, lenses[k]
    return file_to_name, lens_of_file
