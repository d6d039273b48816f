"""Three or four perspective cameras far apart: where sift's calibration leaves the rig
undetermined, the pipeline matches again with an affine-invariant matcher (asift) and keeps the
better-determined calibration (core.pipeline.run_calibration).

A wide viewpoint change (45-65 deg between neighbours) leaves sift a few dozen correct matches per
pair, and with three or four cameras there are too few pairs to make up for it: a camera fails to
register, no calibration comes out, or the consensus runs disagree about the rig. asift finds ten
times the correct matches at those angles but takes five to ten times as long (docs/benchmarks.md,
Three and four cameras far apart), so it runs only where sift's calibration says it did not
suffice. Fisheye lenses keep sift: their wide view keeps shared surfaces large, and sift's matches
calibrate those rigs (same section).
"""
from __future__ import annotations

from typing import Optional, Sequence

from ..config import PipelineConfig, resolve_camera_lenses
from ..types import RigCalibration
from .consensus import WARN_DISAGREEMENT_DEG

# Rigs of more cameras have pairs enough that a wide step between two of them is bridged by the
# others (docs/benchmarks.md: six or more cameras calibrate with sift).
MAX_CAMERAS = 4


def few_perspective_on_sift(config: PipelineConfig, camera_names: Sequence[str]) -> bool:
    """Whether `config` matches at most MAX_CAMERAS cameras, all of perspective lenses, with
    sift: the rigs whose wide steps thin sift's matches out."""
    C = len(camera_names)
    models = resolve_camera_lenses(config, camera_names).sfm.models(C)
    return (config.matcher == "sift" and C <= MAX_CAMERAS
            and not any("FISHEYE" in m for m in models))


def rematch_applies(config: PipelineConfig, camera_names: Sequence[str],
                    fresh: bool = True) -> bool:
    """Whether a calibration with `config` gets a second matcher where sift's leaves the rig
    undetermined: a fresh calibration (a recalibration keeps the matches of its kind) of
    few_perspective_on_sift, with config.few_camera_matcher set to another matcher."""
    return (fresh and few_perspective_on_sift(config, camera_names)
            and config.few_camera_matcher not in (None, "", config.matcher))


def undetermined(rig: Optional[RigCalibration]) -> Optional[str]:
    """Why a calibration leaves the rig undetermined (no calibration, a camera not registered, or
    consensus runs that put the cameras beyond AUC@3's threshold from each other:
    consensus.WARN_DISAGREEMENT_DEG), or None where it does not."""
    if rig is None:
        return "no calibration came out"
    if rig.failed_cameras:
        return f"{', '.join(rig.failed_cameras)} not registered"
    disagreement = rig.quality.consensus_disagreement_deg
    if disagreement is not None and disagreement > WARN_DISAGREEMENT_DEG:
        return f"the calibration runs disagree by {disagreement:.1f} deg"
    return None


def better_determined(a: Optional[RigCalibration], b: Optional[RigCalibration]) -> bool:
    """Whether `a` is the calibration to keep over `b`: one where the other is None, else more
    cameras registered, then the smaller disagreement between its consensus runs (the direct
    measure of how well the images determine the rig); `b` on a tie."""
    if a is None or b is None:
        return b is None and a is not None

    def rank(rig: RigCalibration) -> tuple[int, float]:
        return len(rig.cameras), -(rig.quality.consensus_disagreement_deg or 0.0)
    return rank(a) > rank(b)
