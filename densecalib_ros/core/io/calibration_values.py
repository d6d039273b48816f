"""Values a camera can have, checked where a calibration file is read (core.io.export).

A hand-edited or damaged calibration.json can hold values of the wrong kind (a width `true`,
`"640"` or 640.5, which Python's int() took as 1, 640 and 640) or of no camera (a focal of 1e308,
a principal point 1e9 px off, k1 = 1e6, a width of 10^12 that made `undistort` allocate 7 TiB).
Every later step would carry them into exports or allocate by them; they are refused on reading,
naming the camera and the field. The bounds are loose: they keep out what no lens gives, not
what is merely unusual (the pipeline's own plausibility test, core.method.plausibility, is the
strict one for what it calibrates).
"""
from __future__ import annotations

import math
from typing import Optional, Sequence

# JPEG's largest side (65535); the largest camera sensors are about 14000 px wide, and a side
# beyond this only makes every image-sized buffer absurd (undistort's maps, the matchers').
MAX_IMAGE_SIDE_PX = 65535
# A focal length in pixels against the image's longer side: 0.05 is a third of a fisheye that
# sees 360 deg across its side (f = side / 2 pi), 100 a field of view of 0.6 deg, narrower than
# any lens of a rig of overlapping cameras.
FOCAL_SIDE_RATIO = (0.05, 100.0)
# How far outside the image the principal point may lie, in image sizes: real lenses put it
# within 2 % of the centre; a cropped or rectified camera's may leave the image, not by a whole
# image.
PRINCIPAL_POINT_REACH = 1.0
# The largest |distortion coefficient| (k1.., p1, p2): COLMAP calls |k| > 1 bogus for its own
# lenses; OpenCV's rational model fitted to wide lenses reaches tens (its numerator and
# denominator terms cancel); nothing real needs more than this.
MAX_DISTORTION_COEFFICIENT = 100.0


def _is_number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool)


def entry_problem(name: str, entry) -> Optional[str]:
    """What in one camera's entry of a calibration.json is of the wrong kind (width and height
    whole numbers of pixels in 1..MAX_IMAGE_SIDE_PX, params and cam_from_rig lists of numbers,
    model a name), as read from JSON before any conversion; None when nothing is."""
    if not isinstance(entry, dict):
        return None  # not a calibration's layout at all: the reader says what it expected
    for field in ("width", "height"):
        value = entry.get(field)
        if not isinstance(value, int) or isinstance(value, bool) or not (
                1 <= value <= MAX_IMAGE_SIDE_PX):
            return (f"camera {name}'s {field} is {value!r}: give the image {field} in pixels, "
                    f"a whole number from 1 to {MAX_IMAGE_SIDE_PX}")
    for field in ("params", "cam_from_rig"):
        values = entry.get(field)
        if not isinstance(values, list) or not all(_is_number(v) for v in values):
            return f"camera {name}'s {field} is {_short(values)}: it must be a list of numbers"
    if not isinstance(entry.get("model"), str):
        return f"camera {name}'s model is {entry.get('model')!r}: give a COLMAP model name"
    return None


def params_problem(name: str, width: int, height: int, parameter_names: Sequence[str],
                   params: Sequence[float]) -> Optional[str]:
    """What in a camera's parameters (COLMAP's names and values, COLMAP's pixels) no camera has:
    a focal outside FOCAL_SIDE_RATIO x the longer side, a principal point more than
    PRINCIPAL_POINT_REACH image sizes outside the image, a distortion coefficient beyond
    MAX_DISTORTION_COEFFICIENT; None when none is."""
    side = max(width, height)
    for field, value in zip(parameter_names, params):
        if not math.isfinite(value):
            return f"camera {name}'s {field} is {value}"
        if field in ("f", "fx", "fy"):
            low, high = (r * side for r in FOCAL_SIDE_RATIO)
            if not low <= value <= high:
                return (f"camera {name}'s focal length {field} is {value:g} px: a {width}x"
                        f"{height} camera's lies within {low:g}-{high:g} px")
        elif field in ("cx", "cy"):
            size = width if field == "cx" else height
            low, high = -PRINCIPAL_POINT_REACH * size, (1 + PRINCIPAL_POINT_REACH) * size
            if not low <= value <= high:
                return (f"camera {name}'s principal point {field} is {value:g} px: a "
                        f"{width}x{height} camera's lies within {low:g}-{high:g} px")
    runaway = runaway_distortion(parameter_names, params)
    return f"camera {name}'s {runaway}" if runaway else None


def runaway_distortion(parameter_names: Sequence[str], params: Sequence[float]) -> Optional[str]:
    """What says a distortion coefficient (k1.., p1, p2) is beyond MAX_DISTORTION_COEFFICIENT
    (the first such), else None: the bound a calibration file is read with, which the
    calibration's own plausibility check (core.method.plausibility) holds it to as well."""
    for field, value in zip(parameter_names, params):
        if field[0] in "kp" and field[1:].isdigit() and abs(value) > MAX_DISTORTION_COEFFICIENT:
            return (f"distortion coefficient {field} is {value:g}: a lens's lies within "
                    f"+-{MAX_DISTORTION_COEFFICIENT:g}")
    return None


def _short(value) -> str:
    text = repr(value)
    return text if len(text) <= 60 else text[:57] + "..."
