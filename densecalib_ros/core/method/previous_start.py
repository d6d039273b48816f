"""A previous calibration as the start of a recalibration (sfm.global_init "previous"): its
poses and its intrinsics re-expressed in the working models."""
from __future__ import annotations

from typing import Sequence

import numpy as np

from ..errors import InputError
from ..types import CameraIntrinsics, RigCalibration


def poses_from_previous(previous: RigCalibration, camera_names: Sequence[str],
                        image_sizes: Sequence[tuple[int, int]],
                        models: Sequence[Sequence[str]] = ()
                        ) -> tuple[list[CameraIntrinsics], list[np.ndarray]]:
    """Intrinsics and cam_from_world (= cam_from_rig: world = the previous rig frame) of every
    camera from a previous calibration. models: per camera, the models the pipeline works in (its
    initial model first, then its refinement model: working_models); a previous camera of
    another model (e.g. PINHOLE from another tool) is re-expressed in the first of them
    (`convert_intrinsics`), since the staged BA refines exactly the parameters of that model.
    Raises InputError when a camera is missing from it or its image size changed."""
    intrinsics, poses = [], []
    for c, (name, (w, h)) in enumerate(zip(camera_names, image_sizes)):
        cam = previous.cameras.get(name)
        if cam is None:
            raise InputError(
                f"Camera {name!r} is not in the previous calibration (cameras: "
                f"{', '.join(previous.cameras) or 'none'}): recalibrate with "
                "sfm.global_init='rotation_averaging' instead.")
        if (int(cam.intrinsics.width), int(cam.intrinsics.height)) != (int(w), int(h)):
            raise InputError(
                f"Camera {name!r} was calibrated at {cam.intrinsics.width}x{cam.intrinsics.height} "
                f"but its images are now {w}x{h}: recalibrate with "
                "sfm.global_init='rotation_averaging'.")
        start = CameraIntrinsics(cam.intrinsics.model, w, h,
                                 np.array(cam.intrinsics.params, dtype=np.float64))
        if models and start.model not in models[c]:
            start = convert_intrinsics(start, models[c][0])
        intrinsics.append(start)
        poses.append(np.asarray(cam.cam_from_rig, dtype=np.float64).copy())
    return intrinsics, poses


# Positions of the radial terms k1, k2 (if any) in each COLMAP model's parameter vector.
_RADIAL_TERMS = {"SIMPLE_PINHOLE": (), "PINHOLE": (), "SIMPLE_RADIAL": (3,), "RADIAL": (3, 4),
                 "OPENCV": (4, 5), "FULL_OPENCV": (4, 5), "SIMPLE_RADIAL_FISHEYE": (3,),
                 "RADIAL_FISHEYE": (3, 4), "OPENCV_FISHEYE": (4, 5)}


def convert_intrinsics(camera: CameraIntrinsics, model: str) -> CameraIntrinsics:
    """`camera` re-expressed in a (f, cx, cy, k1, k2) model (RADIAL or RADIAL_FISHEYE): mean focal,
    principal point, and the first two radial terms when the source model has the same kind of
    lens (pinhole family -> RADIAL, fisheye family -> RADIAL_FISHEYE), else zero. Approximate
    where the source has more terms; it is a starting point for bundle adjustment."""
    if model not in ("RADIAL", "RADIAL_FISHEYE") or camera.model not in _RADIAL_TERMS:
        raise InputError(f"Cannot start a {model} calibration from a {camera.model} camera: "
                         "recalibrate with sfm.global_init='rotation_averaging'.")
    src = camera.to_pycolmap()
    k = [0.0, 0.0]
    if ("FISHEYE" in camera.model) == ("FISHEYE" in model):
        for n, idx in enumerate(_RADIAL_TERMS[camera.model]):
            k[n] = float(camera.params[idx])
    params = [src.mean_focal_length(), src.principal_point_x, src.principal_point_y, *k]
    return CameraIntrinsics(model, camera.width, camera.height, np.array(params, dtype=np.float64))
