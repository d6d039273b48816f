"""Frame sets checked before any work: the shapes, types and sizes of the images, one camera
given twice. A bad image in the last frame set would otherwise surface minutes later, deep in the
pipeline, without the camera's name."""
from __future__ import annotations

import numpy as np

from ..errors import InputError, TooFewCamerasGivenError
from ..types import check_camera_names


def check_frame_sets(frame_sets, camera_names) -> list[tuple[int, int]]:
    """(width, height) per camera; InputError (TooFewCamerasGivenError below two cameras) on
    unusable input, found before any work (a bad image in the last frame set would otherwise surface
    minutes later)."""
    camera_names = check_camera_names(camera_names)
    C = len(camera_names)
    if C < 2:
        raise TooFewCamerasGivenError(f"A rig needs at least two cameras, got {C} "
                                    f"({', '.join(camera_names) or 'none'}).")
    if frame_sets is None or len(frame_sets) == 0:
        raise InputError("No frame sets to calibrate from: give at least one image per camera.")
    sizes = None
    for t, frames in enumerate(frame_sets):
        if (isinstance(frames, np.ndarray) and frames.ndim <= 3) or not hasattr(frames, "__len__"):
            raise InputError(f"Frame set {t} is not a list of images, one per camera: "
                             "frame_sets[t][c] is camera c's image of moment t (one moment: "
                             "[[image_cam0, image_cam1, ...]]).")
        if len(frames) != C:
            raise InputError(f"Frame set {t} has {len(frames)} images for {C} cameras.")
        for name, image in zip(camera_names, frames):
            _check_image(image, t, name)
        _check_distinct(frames, t, camera_names)
    return camera_sizes(frame_sets, camera_names)


def camera_sizes(frame_sets, camera_names) -> list[tuple[int, int]]:
    """(width, height) per camera of frame_sets[t][c]; InputError naming the camera whose images
    change size between frame sets (a bag's topic switched resolution part-way)."""
    sizes = None
    for t, frames in enumerate(frame_sets):
        shape = [(int(im.shape[1]), int(im.shape[0])) for im in frames]
        if sizes is not None and shape != sizes:
            c = next(c for c in range(len(shape)) if shape[c] != sizes[c])
            raise InputError(f"Camera {camera_names[c]}'s images change size between frame "
                             f"sets: {sizes[c][0]}x{sizes[c][1]} in set 0, {shape[c][0]}x"
                             f"{shape[c][1]} in set {t}. A camera is calibrated at one "
                             "resolution: leave out the frame sets of the other size.")
        sizes = shape
    return sizes


def _check_distinct(frames, t: int, camera_names) -> None:
    """InputError when two cameras' images of one frame set are the same textured pixels: two
    sensors never record identical noise, so one camera was given twice (a folder copied, one
    topic under two names), and its pairs would otherwise fail far later as 'no consistent
    relative pose'. Uniform images (a covered lens, a black frame) are left to later checks."""
    seen: dict = {}
    for name, image in zip(camera_names, frames):
        probe = image[::8, ::8]
        if probe.min() == probe.max():
            continue
        key = (image.shape, probe.tobytes())
        twin = seen.get(key)
        if twin is not None and np.array_equal(twin[1], image):
            raise InputError(f"Cameras {twin[0]} and {name} gave identical images in frame set "
                             f"{t}: one camera was given twice (the same folder, video or topic "
                             "under two names?); give each camera's own images.")
        seen[key] = (name, image)


def _check_image(image, t: int, camera: str) -> None:
    where = f"The image of camera {camera} in frame set {t}"
    if not isinstance(image, np.ndarray):
        raise InputError(f"{where} is a {type(image).__name__}, not a numpy array: give (H, W, 3) "
                         "uint8 RGB or (H, W) uint8 gray (an unreadable file gives None).")
    if image.dtype != np.uint8:
        raise InputError(f"{where} has dtype {image.dtype}: give uint8 (16-bit images: "
                         "core.io.image_encoding.to_pipeline_image(image, 'rgb') converts them).")
    if not (image.ndim == 2 or image.ndim == 3 and image.shape[2] == 3):
        hint = (" (one channel: image[..., 0])" if image.ndim == 3 and image.shape[2] == 1 else
                " (RGBA: image[..., :3])" if image.ndim == 3 and image.shape[2] == 4 else "")
        raise InputError(f"{where} has shape {image.shape}: give (H, W, 3) RGB or (H, W) "
                         f"gray{hint}.")
    if min(image.shape[:2]) < 16:
        raise InputError(f"{where} is {image.shape[1]}x{image.shape[0]} px: at least 16 px on "
                         "each side.")
