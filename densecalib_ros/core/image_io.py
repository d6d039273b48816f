"""Reading a rig's images from a folder.

Two layouts:
- flat: DIR holds one image per camera; the file stem is the camera name (one frame set);
- per camera: DIR holds one subfolder per camera (folder name = camera name) with time-aligned
  images. Images are aligned by file stem when every camera has the same stems, otherwise by
  sorted order (then every camera must have the same number of images).
Hidden entries and files that are not images (by extension) are ignored.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Optional

import cv2
import numpy as np

from .errors import InputError, NotEnoughCamerasError

IMAGE_EXTENSIONS = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".ppm", ".pgm", ".webp")


def read_image(path: str | os.PathLike) -> np.ndarray:
    """(H, W, 3) uint8 RGB of an image file; InputError naming the file if it cannot be read."""
    bgr = cv2.imread(str(path), cv2.IMREAD_COLOR)
    if bgr is None or bgr.size == 0:
        raise InputError(f"Cannot read image {path}: it is missing, empty or not an image "
                         f"format OpenCV can decode. Replace or remove the file.")
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def _images_in(directory: Path) -> list[Path]:
    return sorted(p for p in directory.iterdir() if p.is_file() and not p.name.startswith(".")
                  and p.suffix.lower() in IMAGE_EXTENSIONS)


def list_image_folder(directory: str | os.PathLike
                      ) -> tuple[list[list[Path]], list[str]]:
    """The image files of DIR per frame set and camera (layouts: module docstring).

    Returns (paths, camera_names) with paths[t][c] the file of camera c at time t. Raises
    InputError for a missing/ambiguous/misaligned folder, NotEnoughCamerasError for < 2 cameras.
    """
    directory = Path(directory)
    if not directory.is_dir():
        raise InputError(f"Image folder {directory} does not exist or is not a folder.")
    files = _images_in(directory)
    subdirs = sorted(p for p in directory.iterdir() if p.is_dir() and not p.name.startswith("."))
    subdirs = [d for d in subdirs if _images_in(d)]
    if files and subdirs:
        raise InputError(
            f"{directory} mixes image files ({files[0].name}, ...) and camera subfolders "
            f"({subdirs[0].name}, ...): use one image per camera OR one subfolder per camera.")
    if files:
        names = [p.stem for p in files]
        duplicate = sorted({n for n in names if names.count(n) > 1})
        if duplicate:
            raise InputError(f"Several images in {directory} share the camera name(s) "
                             f"{', '.join(duplicate)} (file stem): keep one image per camera.")
        paths, names = [files], names
    elif subdirs:
        names = [d.name for d in subdirs]
        per_cam = [_images_in(d) for d in subdirs]
        stems = [[p.stem for p in ps] for ps in per_cam]
        if all(s == stems[0] for s in stems):
            paths = [list(row) for row in zip(*per_cam)]
        else:
            counts = {n: len(ps) for n, ps in zip(names, per_cam)}
            if len(set(counts.values())) != 1:
                raise InputError(
                    f"Camera subfolders of {directory} hold different numbers of images "
                    f"({counts}) and different file names, so they cannot be aligned in time: give "
                    "each time step the same file name in every camera folder.")
            paths = [list(row) for row in zip(*per_cam)]
    else:
        raise InputError(f"No images ({', '.join(IMAGE_EXTENSIONS)}) in {directory} or in its "
                         "subfolders: put one image per camera (file name = camera name) or one "
                         "subfolder per camera there.")
    if len(names) < 2:
        raise NotEnoughCamerasError(
            f"Found only one camera ({names[0]}) in {directory}: a rig calibration needs images "
            "of at least two cameras (one file per camera, or one subfolder per camera).")
    return paths, names


def read_image_folder(directory: str | os.PathLike, max_frame_sets: Optional[int] = None
                      ) -> tuple[list[list[np.ndarray]], list[str]]:
    """Frame sets of an image folder: (frame_sets, camera_names), frame_sets[t][c] (H, W, 3)
    uint8 RGB. At most max_frame_sets evenly spaced time steps are read. Every image of a camera
    must have the same size (the cameras are calibrated at one resolution)."""
    paths, names = list_image_folder(directory)
    if max_frame_sets is not None and len(paths) > max_frame_sets:
        keep = np.unique(np.round(np.linspace(0, len(paths) - 1, max_frame_sets)).astype(int))
        paths = [paths[i] for i in keep]
    frame_sets = [[read_image(p) for p in row] for row in paths]
    for c, name in enumerate(names):
        sizes = {frame_sets[t][c].shape[:2] for t in range(len(frame_sets))}
        if len(sizes) > 1:
            raise InputError(f"Images of camera {name} have different sizes "
                             f"{sorted(sizes)}: use one resolution per camera.")
    return frame_sets, names
