"""Focal lengths and capture times from the EXIF metadata of image files (the offline command's
image folders).

Phones, DSLRs and many trail cameras record the lens focal length in EXIF. It is turned into
pixels of the image as it is now, in one of two ways (COLMAP's image reader does the same):
- FocalLengthIn35mmFilm: the focal length a 36 x 24 mm frame needs for the same field of view.
  The equivalence is on the frame diagonal (CIPA DC-008), so f_px = f_35mm * diagonal_px /
  43.27 mm. It holds at any resolution the image was scaled to.
- FocalLength [mm] with FocalPlaneXResolution / FocalPlaneResolutionUnit (sensor pixels per
  unit at the size PixelXDimension x PixelYDimension, else at the image's own size):
  f_px = f_mm * pixels_per_mm, scaled by the image's long side over that size's long side.
A file with neither, or whose value is outside 0.1-10x its long side, has no EXIF focal.

EXIF describes the camera that took the picture, not what was done to the file afterwards (a
cropped image keeps its tags; digital zoom may not be recorded). So an EXIF focal is only where the
SfM starts, like a user's --focal-px: the focal multi-start still tries the scaled and generic
starts and keeps the one that fits all the matches best, and bundle adjustment refines the focal.

Capture time: DateTimeOriginal (else IFD0 DateTime) with SubSecTimeOriginal, in seconds on the
camera's own clock (the time zone is ignored: it is the same clock's offset for every image).
"""
from __future__ import annotations

import calendar
import logging
import math
import os
import time
from dataclasses import dataclass
from typing import Optional, Sequence

log = logging.getLogger(__name__)

FULL_FRAME_DIAGONAL_MM = math.hypot(36.0, 24.0)  # 43.27 mm, the 35 mm format's diagonal
# mm per FocalPlaneResolutionUnit: 2 inch, 3 cm (EXIF 2.3); 4 mm and 5 um are written by some
# cameras although the standard stops at 3. 1 ("no unit") carries no scale.
RESOLUTION_UNIT_MM = {2: 25.4, 3: 10.0, 4: 1.0, 5: 1e-3}
PLAUSIBLE_FOCAL_RATIO = (0.1, 10.0)  # focal / long side: outside this the tag is not trusted
# Images of one camera whose EXIF focals differ by more than this were taken at different zoom
# settings; no single start fits them and the calibration assumes fixed intrinsics.
CONSISTENT_FOCAL_REL = 0.01

# EXIF tag numbers (Exif sub-IFD)
_EXIF_IFD = 0x8769
_FOCAL_LENGTH = 0x920A
_FOCAL_LENGTH_35MM = 0xA405
_FOCAL_PLANE_X_RESOLUTION = 0xA20E
_FOCAL_PLANE_RESOLUTION_UNIT = 0xA210
_PIXEL_X_DIMENSION = 0xA002
_PIXEL_Y_DIMENSION = 0xA003
_DATETIME = 0x0132  # IFD0
_MAKE = 0x010F  # IFD0
_MODEL = 0x0110  # IFD0
_BODY_SERIAL = 0xA431
_LENS_MODEL = 0xA434
_DATETIME_ORIGINAL = 0x9003
_SUBSEC_TIME_ORIGINAL = 0x9291


def _positive(value) -> Optional[float]:
    try:
        v = float(value)
    except (TypeError, ValueError, ZeroDivisionError):
        return None
    return v if math.isfinite(v) and v > 0 else None


def focal_px_from_tags(tags: dict, image_size: tuple[int, int]) -> Optional[float]:
    """Focal length [px] of an image of image_size (width, height) px from its Exif sub-IFD
    tags {tag number: value}, or None when they do not give one (module docstring)."""
    w, h = image_size
    long_side = float(max(w, h))
    focal = None
    f35 = _positive(tags.get(_FOCAL_LENGTH_35MM))
    if f35 is not None:
        focal = f35 * math.hypot(w, h) / FULL_FRAME_DIAGONAL_MM
    else:
        f_mm = _positive(tags.get(_FOCAL_LENGTH))
        px_per_unit = _positive(tags.get(_FOCAL_PLANE_X_RESOLUTION))
        unit_mm = RESOLUTION_UNIT_MM.get(tags.get(_FOCAL_PLANE_RESOLUTION_UNIT, 2))
        if f_mm is not None and px_per_unit is not None and unit_mm is not None:
            dims = [_positive(tags.get(tag)) for tag in (_PIXEL_X_DIMENSION, _PIXEL_Y_DIMENSION)]
            recorded_long_side = max(dims) if all(dims) else long_side
            focal = f_mm * px_per_unit / unit_mm * long_side / recorded_long_side
    if focal is None:
        return None
    lo, hi = PLAUSIBLE_FOCAL_RATIO
    if not lo * long_side <= focal <= hi * long_side:
        log.warning("EXIF focal %.0f px is implausible for a %dx%d image: ignored", focal, w, h)
        return None
    return focal


def _read_tags(path: str | os.PathLike) -> tuple[dict, dict]:
    """(IFD0 tags, Exif sub-IFD tags) of an image file; empty when it has none or is unreadable."""
    from PIL import Image

    try:
        with Image.open(path) as im:
            exif = im.getexif()
            return dict(exif), dict(exif.get_ifd(_EXIF_IFD))
    except Exception as exc:  # noqa: BLE001 - metadata is optional; the pixels are read elsewhere
        log.debug("no EXIF from %s: %s", path, exc)
        return {}, {}


def exif_focal_px(path: str | os.PathLike, image_size: tuple[int, int]) -> Optional[float]:
    """Focal length [px] that the EXIF of the image file at `path` gives for its size
    image_size (width, height) as loaded, or None (no EXIF, no focal tags, unreadable)."""
    return focal_px_from_tags(_read_tags(path)[1], image_size)


def capture_time_from_tags(ifd0: dict, exif: dict) -> Optional[float]:
    """Seconds (on the camera's clock, as if UTC) of DateTimeOriginal / DateTime + sub-seconds,
    or None when the tags are missing or malformed."""
    text = exif.get(_DATETIME_ORIGINAL) or ifd0.get(_DATETIME)
    if not isinstance(text, str):
        return None
    try:
        stamp = calendar.timegm(time.strptime(text.strip("\x00 ")[:19], "%Y:%m:%d %H:%M:%S"))
    except ValueError:
        return None
    digits = "".join(ch for ch in str(exif.get(_SUBSEC_TIME_ORIGINAL, "")) if ch.isdigit())
    return float(stamp) + (int(digits) / 10 ** len(digits) if digits else 0.0)


def exif_capture_time_s(path: str | os.PathLike) -> Optional[float]:
    """Capture time of the image file at `path` (capture_time_from_tags), or None."""
    return capture_time_from_tags(*_read_tags(path))


@dataclass(frozen=True)
class CameraIdentity:
    """What a camera's EXIF says it is: make and model (IFD0), lens model, focal length [mm] and
    the body's serial number (Exif sub-IFD), None where a tag is absent."""

    make: Optional[str]
    model: Optional[str]
    lens: Optional[str]
    focal_mm: Optional[float]
    serial: Optional[str]

    def unit(self) -> Optional[tuple]:
        """What identical units share (make, model, lens, focal): None without make and model."""
        if not self.make or not self.model:
            return None
        return (self.make, self.model, self.lens, self.focal_mm)


def _text(value) -> Optional[str]:
    text = value.decode(errors="replace") if isinstance(value, bytes) else value
    text = str(text).strip("\x00 ") if text is not None else ""
    return text or None


def camera_identity(path: str | os.PathLike) -> Optional[CameraIdentity]:
    """The CameraIdentity of the image file at `path`; None where it has no make and model."""
    ifd0, exif = _read_tags(path)
    focal = _positive(exif.get(_FOCAL_LENGTH))
    identity = CameraIdentity(_text(ifd0.get(_MAKE)), _text(ifd0.get(_MODEL)),
                              _text(exif.get(_LENS_MODEL)),
                              None if focal is None else round(focal, 2),
                              _text(exif.get(_BODY_SERIAL)))
    return identity if identity.unit() is not None else None


def camera_identities(paths: Sequence[Sequence[str | os.PathLike]],
                      camera_names: Sequence[str]) -> dict[str, CameraIdentity]:
    """{camera name: its CameraIdentity} for the cameras whose images all give the same one
    (paths[t][c]: camera c's file at time t); a camera whose images disagree (files of several
    cameras in one folder, a zoom changed) is left out."""
    out = {}
    for c, name in enumerate(camera_names):
        found = {camera_identity(row[c]) for row in paths}
        if len(found) == 1 and None not in found:
            out[name] = found.pop()
    return out


def identical_unit_groups(identities: dict, image_sizes: dict) -> list[tuple[tuple, str]]:
    """[(camera names, why)] for each group of two or more cameras that are units of one camera
    model: the same EXIF make, model, lens and focal length and the same image size
    (identities: camera name -> CameraIdentity; image_sizes: camera name -> (width, height));
    `why` says so, and whether their serial numbers show different bodies or one."""
    groups: dict[tuple, list[str]] = {}
    for name, identity in identities.items():
        if name in image_sizes:
            groups.setdefault((identity.unit(), tuple(image_sizes[name])), []).append(name)
    out = []
    for ((make, model, lens, focal_mm), (w, h)), names in groups.items():
        if len(names) < 2:
            continue
        serials = [identities[n].serial for n in names]
        bodies = ("; one body (the same serial number)" if len(set(serials)) == 1 and serials[0]
                  else f"; serial numbers {', '.join(s or '?' for s in serials)}")
        what = " ".join(x for x in (make, model) if x) + (f", lens {lens}" if lens else "") + \
            (f", {focal_mm:g} mm" if focal_mm else "")
        out.append((tuple(names), f"EXIF {what}, {w}x{h}{bodies}"))
    return out


def camera_exif_focals(paths: Sequence[Sequence[str | os.PathLike]], camera_names: Sequence[str],
                       image_sizes: Sequence[tuple[int, int]]) -> dict[str, float]:
    """{camera name: EXIF focal px} for the cameras whose images all give the same EXIF focal
    (within CONSISTENT_FOCAL_REL; their median). paths[t][c]: camera c's file at time t;
    image_sizes[c]: camera c's (width, height) as loaded. Cameras without one are left out, with
    a warning where their images disagree (zoom changed between them)."""
    out = {}
    for c, name in enumerate(camera_names):
        focals = [exif_focal_px(row[c], image_sizes[c]) for row in paths]
        if not focals or any(f is None for f in focals):
            continue
        lo, hi = min(focals), max(focals)
        if hi > lo * (1.0 + CONSISTENT_FOCAL_REL):
            log.warning("Camera %s: its images' EXIF focal lengths differ (%.0f-%.0f px; zoom "
                        "changed?): not used. The calibration assumes one focal per camera.",
                        name, lo, hi)
            continue
        out[name] = sorted(focals)[len(focals) // 2]
    return out
