"""A second matcher where sift's matches leave a perspective rig undetermined: the pipeline
matches again with an affine-invariant matcher (asift) and keeps the better-determined calibration
(with_second_matcher, the policy core.pipeline runs around a matcher's calibration).

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

import logging
from dataclasses import dataclass, field
from typing import Callable, Optional, Sequence

import numpy as np

from ..config import PipelineConfig
from ..errors import CalibrationError, InputError
from ..method.focal_determination import median_focal_std_fraction, short_of_aim
from ..types import RigCalibration
from .consensus import WARN_DISAGREEMENT_DEG, standing_disagreement_deg
from .consensus_runs import runs_intrinsics_spread

log = logging.getLogger(__name__)


def perspective_on_sift(config: PipelineConfig, camera_names: Sequence[str]) -> bool:
    """Whether `config` matches cameras all of perspective lenses with sift: the rigs whose wide
    steps or narrow views thin sift's matches out."""
    models = config.for_cameras(camera_names).sfm.models(len(camera_names))
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
    the rig), then the one that places its cameras more tightly: the smaller median rotation
    sigma (median_rotation_std_deg) where both have one, else the smaller focal sigma
    (focal_determination.median_focal_std_fraction); `b` on a tie. A camera's rotation sigma
    takes in its focal length's, principal point's and lens model's shares of where the camera
    points, which is what the rig's pairs are judged by; the focal sigma is one of those shares
    (docs/design-notes.md, A second matcher: the legs compared on their rotation sigmas)."""
    if a is None or b is None:
        return b is None and a is not None
    rotation_deg = (median_rotation_std_deg(a), median_rotation_std_deg(b))
    by_rotation = None not in rotation_deg

    def rank(rig: RigCalibration, rotation: Optional[float]) -> tuple[int, float, float]:
        disagreement = standing_disagreement_deg(rig.quality) or 0.0
        spread = rotation if by_rotation else median_focal_std_fraction(rig)
        return (len(rig.cameras), -(disagreement if disagreement > WARN_DISAGREEMENT_DEG else 0.0),
                -spread)
    return rank(a, rotation_deg[0]) > rank(b, rotation_deg[1])


def median_rotation_std_deg(rig: RigCalibration) -> Optional[float]:
    """The median over the rig's cameras but the reference of their rotation sigmas (deg,
    relative to the reference camera: CameraQuality.rotation_std_deg); None where one of them
    has none (the rig was not refined on the images) or there is no other camera."""
    stds = [cam.quality.rotation_std_deg if cam.quality is not None else None
            for name, cam in rig.cameras.items() if name != rig.reference_camera]
    if not stds or any(s is None or not np.isfinite(s) for s in stds):
        return None
    return float(np.median(stds))


@dataclass(frozen=True)
class Rematch:
    """What the second matcher did: the first matcher and why its calibration was undetermined,
    the second and how its calibration came out, whether the second's was kept, and where the
    kept one is undetermined too, how far the two answers stand apart in units of their sigmas
    (apart: matchers_apart)."""

    first: str
    first_result: str
    second: str
    second_result: str
    kept_second: bool
    apart: dict = field(default_factory=dict)

    def record(self) -> dict:
        """The quality record's `rematch`."""
        return {"first": self.first, "first_result": self.first_result, "second": self.second,
                "second_result": self.second_result,
                "kept": self.second if self.kept_second else self.first}


def first_runs_undetermined(runs) -> bool:
    """The consensus runs' rule on the first matcher's matches (runs: its ConsensusRuns): end
    after a first run that left a camera unregistered, or once the first runs, judged refined on
    the dense image correspondences, stand apart beyond WARN_DISAGREEMENT_DEG. Both are the
    second matcher's case; more runs on these matches would only delay it: a later sample rarely
    registers a camera the first run left out (docs/design-notes.md, A second matcher: sooner),
    and runs that the images do not bring together stay apart however many more are made
    (consensus.EARLY_STOP_RUNS). They are completed where the other matcher does no better."""
    results = runs.results
    if len(results) == 1 and bool(results[0].rig.failed_cameras):
        return True
    return runs.judged_apart_deg is not None and runs.judged_apart_deg > WARN_DISAGREEMENT_DEG


def with_second_matcher(calibrate: Callable[..., object],
                        config: PipelineConfig, camera_names: Sequence[str], fresh: bool,
                        say: Callable[[str], None]) -> tuple[object, Optional[Rematch]]:
    """(the calibration to keep, what the second matcher did or None where it did not run).

    calibrate(matcher, until, refine_cut_short=True) calibrates on that matcher's matches, its
    consensus runs ended by `until` (ConsensusRuns.run), a first run they end after left
    unrefined on the images unless refine_cut_short; called again for a matcher it continues the
    runs it ended. Its result has `.rig`, `.cut_short` (whether `until` ended the runs) and
    `.unrefined`. Where rematch_applies, the first matcher's calibration is matched again with
    config.second_matcher where it is undetermined, and the better determined is kept. Raises the
    first calibration's error where neither gives one.

    A first run that left a camera out is refined on the images only where the comparison needs
    it: a second calibration that registers more cameras is kept over it and one that registers
    fewer has the first's runs completed, whatever its refinement; only one that registers as
    many is compared on the refined sigmas (better_determined)."""
    if not rematch_applies(config, camera_names, fresh=fresh):
        return calibrate(config.matcher, None), None
    first, error = None, None
    try:
        first = calibrate(config.matcher, first_runs_undetermined, False)
    except InputError:
        raise  # the user's input, not sift's matches: another matcher would be refused too
    except CalibrationError as exc:
        error = exc
    why = undetermined(first.rig if first else None)
    if why is None and first.cut_short:  # determined after all: the runs as they would have been
        first = calibrate(config.matcher, None)
        why = undetermined(first.rig)
    if why is None:
        return first, None
    second_matcher = config.second_matcher
    say(f"{config.matcher}: {why}; matching again with {second_matcher}, which keeps matches "
        "across wide viewpoint changes (several times slower)")
    second = None
    try:
        second = calibrate(second_matcher, None)
    except CalibrationError as exc:
        log.info("the calibration on %s's matches failed too: %s", second_matcher, exc)
    if first is not None and first.unrefined and second is not None and \
            len(second.rig.cameras) == len(first.rig.cameras):
        first = calibrate(config.matcher, first_runs_undetermined)  # refined: its sigmas compared
    if first is not None and first.cut_short and \
            not better_determined(second.rig if second else None, first.rig):
        say(f"{second_matcher}: no better determined; completing {config.matcher}'s consensus "
            "runs")
        try:
            first = calibrate(config.matcher, None)
        except CalibrationError as exc:  # not expected (the runs go on from the first): keep it
            log.info("completing %s's consensus runs failed: %s", config.matcher, exc)
        why = undetermined(first.rig)
        if why is None:  # a later run registered the camera: no second matcher was needed
            return first, None
    if first is None and second is None:
        raise error
    second_came = undetermined(second.rig if second else None) or "determined"
    keep_second = better_determined(second.rig if second else None,
                                    first.rig if first else None)
    say(f"{second_matcher}: {second_came}; kept the calibration on "
        f"{second_matcher if keep_second else config.matcher}'s matches")
    kept, other = (second, first) if keep_second else (first, second)
    # Where the kept calibration is determined its sigmas stand as the rules that judged it
    # checked them; the other's distance from it is why that one was not.
    apart = matchers_apart(kept, other, camera_names) if undetermined(kept.rig) else {}
    return kept, Rematch(config.matcher, why, second_matcher, second_came, keep_second, apart)


def matchers_apart(kept, other, camera_names: Sequence[str]) -> dict:
    """Camera name -> (focal, projection, rotation, principal point): how far apart the two
    matchers' answers for the camera stand, in units of their joint sigma (the distance over the
    root sum of squares of the two calibrations' own sigmas; NaN where either has none), where
    both calibrations (with_second_matcher's: `.rig`, `.unrefined`) placed the same cameras and
    were refined on the images; else {}. The matchers' keypoints predict and select different dense
    correspondences of the same images, so the two refined answers are two draws of what the
    images say: beyond 1, their distance is error the sigmas do not see."""
    if kept is None or other is None or kept.unrefined or other.unrefined or \
            set(kept.rig.cameras) != set(other.rig.cameras) or \
            not (kept.rig.quality.image_refinement_tracks and
                 other.rig.quality.image_refinement_tracks):
        return {}
    def stds(rig: RigCalibration, name: str) -> tuple:
        q = rig.cameras[name].quality
        return (None,) * 4 if q is None else \
            (q.focal_std_px, q.projection_std_px, q.rotation_std_deg, q.principal_point_std_px)

    out = {}
    # for two answers the spread (their sample standard deviation) is the distance / sqrt 2
    for name, spread in runs_intrinsics_spread([kept.rig, other.rig], camera_names).items():
        out[name] = tuple(float(np.sqrt(2.0) * d / np.hypot(sa, sb))
                          if sa and sb and np.isfinite(d) else float("nan")
                          for d, sa, sb in zip(spread, stds(kept.rig, name),
                                               stds(other.rig, name)))
    return out


def with_matchers_apart(rig: RigCalibration, rematch: Optional[Rematch],
                         say: Callable[[str], None] = lambda message: None) -> None:
    """rig's focal, projection, rotation and principal point sigmas widened, in place, where the
    two matchers' refined calibrations stand further apart than their sigmas allow
    (Rematch.apart): each by that factor, as both calibrations' sigmas would have to be (said);
    the quality record then names the matcher whose calibration was not kept
    (sigmas_matchers_spread). Where the other is the looser, its own sigmas explain most of the
    distance and the kept ones widen little (docs/design-notes.md, Sigmas of two matchers)."""
    if rematch is None or not rematch.apart:
        return
    raised = False
    for name, factors in rematch.apart.items():
        quality = rig.cameras[name].quality if name in rig.cameras else None
        if quality is None or quality.focal_std_px is None:
            continue
        stds = (quality.focal_std_px, quality.projection_std_px, quality.rotation_std_deg,
                quality.principal_point_std_px)
        wider = [std * factor if std is not None and factor > 1.0 else std
                 for std, factor in zip(stds, factors)]  # NaN > 1 is False
        raised |= wider != list(stds)
        (quality.focal_std_px, quality.projection_std_px, quality.rotation_std_deg,
         quality.principal_point_std_px) = wider
    if raised:
        other = rematch.first if rematch.kept_second else rematch.second
        rig.quality.sigmas_matchers_spread = other
        say(f"sigmas widened: the calibration on {other}'s matches stands further from the kept "
            "one than both calibrations' sigmas allow")
