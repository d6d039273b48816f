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
names the matches, not the layout, as the cause (FORWARD_SPREAD_DEG). Between the 1 % the
calibration aims at (AIMED_FOCAL_STD_FRACTION) and that bound, such a rig is told its focal lengths
are short of the aim (loose_focal_warning): after the second matcher where sift's matches left it
so (core.robust.second_matcher), for the rig kept.

On a rig whose optical axes spread under FORWARD_SPREAD_DEG the covariance does not see it: the
cost over the focal lengths there is a long, curved, nearly flat valley, the adjustment stops
anywhere along it, and the local curvature it inverts says 0.2-3 % where the focal lengths are
15-35 % off (docs/design-notes.md, Cameras that look the same way: the focal-scale probe). So on
such rigs the image refinement probes the valley (probed_focal_scale_std): it restarts the
adjustment from the found rig with every focal length PROBE_STEP shorter and longer, and a
restart that ends as good a fit at a focal scale well away from the found one shows the images
leave that scale open; the cameras' focal sigmas are raised to what the probe shows."""
from __future__ import annotations

import logging
from typing import Optional, Sequence

import numpy as np

from ..config import lens_of_model
from ..metrics import mean_focal_px
from ..types import CameraIntrinsics, RigCalibration
from .prior_adjustment import Priors, adjust_with_priors
from .reconstruction import SfMState

log = logging.getLogger(__name__)

# The calibration aims at focal lengths right to 1 % (3D lengths and angles as right): a rig whose
# cameras' focal sigma is above that at the median is short of the aim, and its cameras err
# together.
AIMED_FOCAL_STD_FRACTION = 0.01
# A focal whose 1-sigma is 5 % of it may well be 10 % off: 3D lengths and angles off by as much,
# ten times the 1 % the calibration aims at.
WEAK_FOCAL_STD_FRACTION = 0.05
WEAK_FOCAL_PREFIX = "focal lengths weakly determined by these images"
# Below this spread of the optical axes the rig's layout is the likely cause (a bar, a stereo
# head); above it, the matches are.
FORWARD_SPREAD_DEG = 20.0
# The probe's restarts: every focal length this fraction shorter and longer, three times the
# warning's 5 %, so that on a rig determined to that a restart's cost rises by 9 (3 sigma).
PROBE_STEP = 0.15
# Adjustment iterations of each restart, and of the found rig again so that all three have had as
# many (the adjustment crawls along the valley: from 15 % off a determined rig comes back most of
# the way in this many).
PROBE_ITERATIONS = 30


def axes_spread_deg(cam_from_world_rotations) -> float:
    """The largest angle (deg) between two cameras' optical axes, given their (3, 3) rotations
    from a common frame; 0 for one camera."""
    axes = np.array([np.asarray(R)[2, :] for R in cam_from_world_rotations])
    if not len(axes):
        return 0.0
    cosines = np.clip(axes @ axes.T, -1.0, 1.0)
    return float(np.degrees(np.arccos(cosines.min())))


def lenses_adjusted(models: Sequence[str], cam_from_world_rotations) -> bool:
    """Whether the image refinement adjusts lenses of these models on a rig of these rotations:
    perspective ones always, fisheye ones where the optical axes spread FORWARD_SPREAD_DEG or
    more (a forward-facing real pair's came out worse: docs/design-notes.md, Image refinement:
    fisheye lenses)."""
    return all(lens_of_model(m) == "pinhole" for m in models) or \
        axes_spread_deg(cam_from_world_rotations) >= FORWARD_SPREAD_DEG


def optical_axes_spread_deg(rig: RigCalibration) -> float:
    """axes_spread_deg of a calibrated rig's cameras."""
    return axes_spread_deg([cam.cam_from_rig[:3, :3] for cam in rig.cameras.values()])


def probed_focal_scale_std(state: SfMState, blocks: list[int], priors: Priors,
                           noise_px: float) -> float:
    """The standard deviation (fraction) of a common scale of the `blocks`' focal lengths that a
    probe of the adjustment's cost shows (module docstring): from `state` (adjusted with `priors`
    at `noise_px`; left as it is) every focal length is scaled by 1 / (1 + PROBE_STEP) and
    1 + PROBE_STEP, and each restart and the found rig are adjusted PROBE_ITERATIONS more. A
    restart that ends at focal lengths |ln r| from the found ones (r: the median ratio) for a
    cost rise dC (in units of the noise: one is one sigma) puts the sigma at |ln r| / sqrt(dC),
    with dC taken at least 1: a rig as good a fit that far away is within one sigma of it. The
    larger of the two; 0 where no restart could be adjusted or no focal length is adjusted."""
    if not blocks:
        return 0.0
    found = state.copy()
    try:
        found_cost = adjust_with_priors(found, blocks, priors, PROBE_ITERATIONS,
                                        noise_px).cost_after
    except (ValueError, np.linalg.LinAlgError):
        return 0.0
    std = 0.0
    for k in (1.0 / (1.0 + PROBE_STEP), 1.0 + PROBE_STEP):
        trial = _focal_scaled(found, blocks, k)
        try:
            cost = adjust_with_priors(trial, blocks, priors, PROBE_ITERATIONS,
                                      noise_px).cost_after
        except (ValueError, np.linalg.LinAlgError):
            continue
        ratio = np.median([trial.intrinsics[b].params[0] / found.intrinsics[b].params[0]
                           for b in blocks])
        std = max(std, abs(float(np.log(ratio))) / np.sqrt(max(cost - found_cost, 1.0)))
        log.debug("focal-scale probe from %.3f: ended at %.3f of the found focal lengths, cost "
                  "%+.1f", k, ratio, cost - found_cost)
    return std


def _focal_scaled(state: SfMState, blocks: list[int], k: float) -> SfMState:
    """A copy of `state` with the blocks' focal lengths times k and the points stretched by k
    along the reference camera's axis, which for cameras that only translate reprojects every
    point as before with k1 -> k^2 k1, k2 -> k^4 k2 (module docstring)."""
    out = state.copy()
    for b in blocks:
        cam = out.intrinsics[b]
        p = np.array(cam.params, float)
        f, k1 = ([0, 1], 4) if cam.model == "OPENCV" else ([0], 3)
        p[f] *= k
        p[k1] *= k ** 2
        p[k1 + 1] *= k ** 4
        out.intrinsics[b] = CameraIntrinsics(cam.model, cam.width, cam.height, p)
    T = out.cam_from_world[out.registered()[0]]
    in_reference = out.points_xyz @ T[:3, :3].T + T[:3, 3]
    in_reference[:, 2] *= k
    out.points_xyz = (in_reference - T[:3, 3]) @ T[:3, :3]
    return out


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


def short_of_aim(rig: RigCalibration) -> bool:
    """Whether the rig's focal lengths are looser than the calibration aims at
    (median_focal_std_fraction above AIMED_FOCAL_STD_FRACTION) on a rig whose optical axes spread
    FORWARD_SPREAD_DEG or more, where more or other matches can determine them (on a bar the
    layout leaves them open and the probe's sigma says so)."""
    return (median_focal_std_fraction(rig) > AIMED_FOCAL_STD_FRACTION
            and optical_axes_spread_deg(rig) >= FORWARD_SPREAD_DEG)


def loose_focal_warning(rig: RigCalibration, matched: str) -> Optional[str]:
    """The message for a user whose rig is short_of_aim but within WEAK_FOCAL_STD_FRACTION (above
    it weak_focal_warning says more), else None; `matched` says which matches the calibration
    rests on ("sift's matches", ...)."""
    if not short_of_aim(rig) or median_focal_std_fraction(rig) > WEAK_FOCAL_STD_FRACTION:
        return None
    return (f"focal lengths looser than the calibration aims at: on {matched} f_std is "
            f"{_listed(rig)} of the focal length (1 sigma; a rig's cameras err together) where "
            f"it aims at {100 * AIMED_FOCAL_STD_FRACTION:.0f} %, so 3D lengths and angles may be "
            f"off by twice that. {_focal_fix(rig, optical_axes_spread_deg(rig))}")


def _listed(rig: RigCalibration) -> str:
    return ", ".join(f"{n} {100 * v:.1f} %" for n, v in
                     sorted(weak_focal_fractions(rig).items(), key=lambda item: -item[1]))


def weak_focal_warning(rig: RigCalibration) -> Optional[str]:
    """The message for a user whose images leave the rig's focal lengths open
    (median_focal_std_fraction above WEAK_FOCAL_STD_FRACTION), else None."""
    if median_focal_std_fraction(rig) <= WEAK_FOCAL_STD_FRACTION:
        return None
    spread_deg = optical_axes_spread_deg(rig)
    if spread_deg < FORWARD_SPREAD_DEG:
        why = (f"The optical axes are at most {spread_deg:.0f} deg apart: images fix focal "
               "lengths through the angles between cameras, and cameras that look nearly the "
               "same way leave them open.")
    else:
        why = (f"The optical axes are up to {spread_deg:.0f} deg apart, so the matches leave them "
               "open: few of them, or bunched in a part of the images (small overlap, a flat or "
               "repetitive scene).")
    return (f"{WEAK_FOCAL_PREFIX}: f_std is {_listed(rig)} of the focal length (1 sigma; a rig's "
            f"cameras err together). {why} {_focal_fix(rig, spread_deg)}")


def _focal_fix(rig: RigCalibration, spread_deg: float) -> str:
    """What a user can do about focal lengths the images leave open, on a rig whose optical axes
    spread this much (deg)."""
    other_fix = ("or place cameras around the scene, 20 deg or more apart"
                 if spread_deg < FORWARD_SPREAD_DEG else
                 "or add frame sets (time-aligned images of a changing scene) or a camera "
                 "between the others")
    return ("Give one camera's intrinsics from a lab calibration (--intrinsics NAME=PATH; node: "
            "intrinsics_files; library: PipelineConfig.cameras.known_intrinsics) and the others "
            f"follow from it, {other_fix}. A known focal given as a start (--focal-px) does not "
            "help: it is refined like any other." + one_camera_hint(rig))


def one_camera_hint(rig: RigCalibration) -> str:
    """" If these images come from one camera, --share-intrinsics ..." for a rig short of the
    focal aim (median_focal_std_fraction above AIMED_FOCAL_STD_FRACTION) whose cameras could be
    one: every camera calibrated with a sigma (weak_focal_fractions), of one image size and lens
    model, the intrinsics not one set already (not all equal) and the cameras not calibrated as
    units of one model (quality.identical_units). One set estimated from every
    image is determined where one per image is left open; "" otherwise. The images alone do
    not prove they are one camera: separately calibrated, one phone's frames come out with focal
    lengths several of their sigmas apart (docs/design-notes.md, Images of one camera); where
    the runs disagree, core.robust.one_model tries them as one model."""
    cams = list(rig.cameras.values())
    if len(cams) < 2 or len(weak_focal_fractions(rig)) < len(cams) or \
            median_focal_std_fraction(rig) <= AIMED_FOCAL_STD_FRACTION:
        return ""
    if len({(c.intrinsics.model, c.intrinsics.width, c.intrinsics.height) for c in cams}) > 1:
        return ""
    params = [np.asarray(c.intrinsics.params, float) for c in cams]
    if all(np.array_equal(p, params[0]) for p in params[1:]):
        return ""  # one set already
    units = {n for group in rig.quality.identical_units or () for n in group["cameras"]}
    if set(rig.cameras) <= units:
        return ""  # calibrated as units of one model (named, EXIF or assumed), each its own after
    return (" If these images come from one camera (moved between shots, or frames of one "
            "video), --share-intrinsics (node: share_intrinsics; library: "
            "SfMConfig.share_intrinsics) estimates one set of intrinsics from all of them, which "
            "the images determine where one set per image is left open.")
