"""A second matcher where sift's matches leave a perspective rig undetermined: the pipeline
matches again with an affine-invariant matcher (asift) and keeps the better-determined calibration
(core.pipeline._calibrated).

A wide viewpoint change between neighbours (45-65 deg), or a long lens (25-35 deg field of view)
whose views share little, leaves sift a few dozen correct matches per pair: a camera fails to
register, no calibration comes out, the consensus runs disagree about the rig, or the runs agree
but the images leave the focal lengths looser than the calibration aims at. asift finds ten
times the correct matches at those angles but takes five to ten times as long (docs/benchmarks.md,
A second matcher), so it runs only where sift's calibration says it did not suffice, on rigs of
any size: five to eight cameras leave those pairs as undetermined as three or four do. Fisheye
lenses keep sift: their wide view keeps shared surfaces large, and sift's matches calibrate those
rigs (same section).
"""
from __future__ import annotations

from typing import Optional, Sequence

from ..config import PipelineConfig, resolve_camera_lenses
from ..method.focal_determination import median_focal_std_fraction, short_of_aim
from ..types import RigCalibration
from .consensus import WARN_DISAGREEMENT_DEG, standing_disagreement_deg


def perspective_on_sift(config: PipelineConfig, camera_names: Sequence[str]) -> bool:
    """Whether `config` matches cameras all of perspective lenses with sift: the rigs whose wide
    steps or narrow views thin sift's matches out."""
    models = resolve_camera_lenses(config, camera_names).sfm.models(len(camera_names))
    return config.matcher == "sift" and not any("FISHEYE" in m for m in models)


def rematch_applies(config: PipelineConfig, camera_names: Sequence[str],
                    fresh: bool = True) -> bool:
    """Whether a calibration with `config` gets a second matcher where sift's leaves the rig
    undetermined: a fresh calibration (a recalibration keeps the matches of its kind) of
    perspective_on_sift, with config.second_matcher set to another matcher."""
    return (fresh and perspective_on_sift(config, camera_names)
            and config.second_matcher not in (None, "", config.matcher))


def undetermined(rig: Optional[RigCalibration]) -> Optional[str]:
    """Why a calibration leaves the rig undetermined (no calibration, a camera not registered,
    consensus runs that put the cameras beyond AUC@3's threshold from each other as the
    calibration stands (consensus.standing_disagreement_deg, WARN_DISAGREEMENT_DEG), or focal
    lengths short of the aim (focal_determination.short_of_aim): a tenfold set of matches is
    worth its time there), or None where it does not."""
    if rig is None:
        return "no calibration came out"
    if rig.failed_cameras:
        return f"{', '.join(rig.failed_cameras)} not registered"
    disagreement = standing_disagreement_deg(rig.quality)
    if disagreement is not None and disagreement > WARN_DISAGREEMENT_DEG:
        return f"the calibration runs disagree by {disagreement:.1f} deg"
    # short_of_aim leaves out cameras that look the same way: their focal lengths rest on the
    # few degrees between their axes, which no matcher adds to (docs/design-notes.md, the
    # focal-scale probe).
    if short_of_aim(rig):
        return (f"the focal lengths are determined to {100 * median_focal_std_fraction(rig):.1f} "
                "% only (1 sigma, median over the cameras)")
    return None


def better_determined(a: Optional[RigCalibration], b: Optional[RigCalibration]) -> bool:
    """Whether `a` is the calibration to keep over `b`: one where the other is None, else more
    cameras registered, then the smaller disagreement between its consensus runs where they
    disagree beyond WARN_DISAGREEMENT_DEG (the direct measure of how well the images determine
    the rig), then the smaller focal sigma
    (focal_determination.median_focal_std_fraction); `b` on a tie."""
    if a is None or b is None:
        return b is None and a is not None

    def rank(rig: RigCalibration) -> tuple[int, float, float]:
        disagreement = standing_disagreement_deg(rig.quality) or 0.0
        return (len(rig.cameras), -(disagreement if disagreement > WARN_DISAGREEMENT_DEG else 0.0),
                -median_focal_std_fraction(rig))
    return rank(a) > rank(b)
