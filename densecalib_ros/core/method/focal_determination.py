"""Whether the images determined the focal lengths: the warning for a rig whose cameras look
nearly the same way (cameras side by side on a bar, a stereo head, a forward-facing array).

A rig's images fix its focal lengths through the angles between its cameras: a rotation moves
image points by amounts that depend on the focal, a translation alone does not (for cameras that
only translate, scaling every focal and every depth by one factor k, with the radial terms
k1 -> k^2 k1, k2 -> k^4 k2, reprojects every point exactly as before). With a few degrees
between the cameras the focal rests on those few degrees, which trade against where the
principal point lies, and the regular preset holds that at the image centre. The covariance
shows it: with the held point's offset (core.method.uncertainty) a camera's f_std is a large
fraction of its focal on such rigs, mostly below 5 % where cameras stand 20 deg or more apart around
the scene, and all of a rig's cameras err together (measured figures: docs/cli.md, "Cameras that
look the same way"; `densecalib bench --forward`). One camera's intrinsics given (a lab calibration)
pins the others' focals through the images; a known focal given as a start (--focal-px) does
not, since the adjustment refines it like any other.

So the calibration warns, in its quality's warnings, where the median over its cameras of
f_std / focal exceeds WEAK_FOCAL_STD_FRACTION: the rig as a whole, since its cameras err together
(a single camera's sigma leaves that common part out, pycolmap giving per-camera blocks).
Fisheye cameras are left out: their focal trades against the distortion terms over a partly
seen field with the projection still well determined (read their proj_std). The same figure
flags cameras well apart whose matches leave the focal open (3-camera rigs with few or bunched
matches; on the held-out bench it fired on such rigs whose result was off): the message then
names the matches, not the layout, as the cause (FORWARD_SPREAD_DEG)."""
from __future__ import annotations

from typing import Optional

import numpy as np

from ..config import lens_of_model
from ..metrics import mean_focal_px
from ..types import RigCalibration

# A focal whose 1-sigma is 5 % of it may well be 10 % off: 3D lengths and angles off by as much,
# ten times the 1 % the calibration aims at.
WEAK_FOCAL_STD_FRACTION = 0.05
WEAK_FOCAL_PREFIX = "focal lengths weakly determined by these images"
# Below this spread of the optical axes the rig's layout is the likely cause (a bar, a stereo
# head); above it, the matches are.
FORWARD_SPREAD_DEG = 20.0


def optical_axes_spread_deg(rig: RigCalibration) -> float:
    """The largest angle (deg) between two cameras' optical axes; 0 for one camera."""
    axes = np.array([cam.cam_from_rig[:3, :3].T @ np.array([0.0, 0.0, 1.0])
                     for cam in rig.cameras.values()])
    cosines = np.clip(axes @ axes.T, -1.0, 1.0)
    return float(np.degrees(np.arccos(cosines.min()))) if len(axes) else 0.0


def weak_focal_fractions(rig: RigCalibration) -> dict[str, float]:
    """Per pinhole-model camera whose intrinsics were calibrated (not given) and have a sigma:
    focal_std_px / focal_px."""
    given = set(rig.quality.given_intrinsics or ())
    out = {}
    for name, cam in rig.cameras.items():
        q = cam.quality
        if name in given or q is None or not q.focal_std_px \
                or lens_of_model(cam.intrinsics.model) == "fisheye":
            continue
        out[name] = float(q.focal_std_px) / mean_focal_px(cam.intrinsics)
    return out


def median_focal_std_fraction(rig: RigCalibration) -> float:
    """The median of weak_focal_fractions over the rig's cameras (its cameras err together, so
    the rig is as determined as its median camera); 0 where none has a sigma."""
    fractions = list(weak_focal_fractions(rig).values())
    return float(np.median(fractions)) if fractions else 0.0


def weak_focal_warning(rig: RigCalibration) -> Optional[str]:
    """The message for a user whose images leave the rig's focal lengths open
    (median_focal_std_fraction above WEAK_FOCAL_STD_FRACTION), else None."""
    if median_focal_std_fraction(rig) <= WEAK_FOCAL_STD_FRACTION:
        return None
    fractions = weak_focal_fractions(rig)
    listed = ", ".join(f"{n} {100 * v:.1f} %" for n, v in
                       sorted(fractions.items(), key=lambda item: -item[1]))
    spread_deg = optical_axes_spread_deg(rig)
    if spread_deg < FORWARD_SPREAD_DEG:
        why = (f"The optical axes are at most {spread_deg:.0f} deg apart: images fix focal "
               "lengths through the angles between cameras, and cameras that look nearly the "
               "same way leave them open.")
        other_fix = "or place cameras around the scene, 20 deg or more apart"
    else:
        why = (f"The optical axes are up to {spread_deg:.0f} deg apart, so the matches leave them "
               "open: few of them, or bunched in a part of the images (small overlap, a flat or "
               "repetitive scene).")
        other_fix = ("or add frame sets (time-aligned images of a changing scene) or a camera "
                     "between the others")
    return (f"{WEAK_FOCAL_PREFIX}: f_std is {listed} of the focal length (1 sigma; a rig's "
            f"cameras err together). {why} Give one camera's intrinsics from a lab calibration "
            "(--intrinsics NAME=PATH; node: intrinsics_files; library: "
            "PipelineConfig.cameras.known_intrinsics) "
            f"and the others follow from it, {other_fix}. A known focal given as a start "
            "(--focal-px) does not help: it is refined like any other.")
