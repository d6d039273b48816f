"""The consensus policy around one calibration run (core.robust.consensus says why): the run
repeated with consecutive sampling seeds until further runs could only repeat the answer
(ConsensusRuns), the run to keep chosen among them (choose), and how far the kept rig stands from
the others (summarize), which the quality record and the warning are made of.

The run itself is the caller's callable, calibrate_once(seed, only_starts, progress): this
module knows the runs only by their rigs, tracks and states."""
from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field
from itertools import combinations
from typing import Callable, Optional, Sequence

import numpy as np

from ..config import PipelineConfig
from ..errors import CalibrationError
from ..metrics import (mean_focal_px, principal_point_px, projection_map_error,
                       rotation_angle_deg)
from ..method.multistart import AGREEMENT_DEG, agreement_deg, cost_truncation_px
from ..progress import Progress
from ..types import RigCalibration, Tracks
from .consensus import (EARLY_STOP_RUNS, Choice, choose_run, least_determined_pairs, medoid,
                        rig_disagreement_deg)

log = logging.getLogger(__name__)

# calibrate_once(seed, only_starts, progress) -> a run's result (rig, tracks, state,
# settled_starts); CalibrationError where the run fails.
CalibrateOnce = Callable[[int, Optional[list], Progress], object]
# The refined disagreement matrix of runs (core.stages.refinement.RefinedRuns.disagreement_deg),
# None where one of them cannot be refined.
RefinedDisagreement = Callable[[Sequence[object]], Optional[np.ndarray]]


def runs_agreement_deg(rig: RigCalibration, camera_names: Sequence[str],
                       config: PipelineConfig) -> float:
    """multistart.agreement_deg for the cameras as `rig` (a consensus run's) calibrated them."""
    return agreement_deg([rig.cameras[n].intrinsics if n in rig.cameras else None
                          for n in camera_names], config.sfm)


class ConsensusRuns:
    """Up to config.consensus_runs runs with seeds seed, seed + 1, ... (run: the results so far,
    their seeds, how many failed, the first run's settled starts, and where the runs stopped
    for agreeing refined on the images, their refined disagreement matrix).

    They stop early where further runs could only repeat the answer: once EARLY_STOP_RUNS runs
    have succeeded and agree (multistart.agreement_deg). Where the first run's focal multi-start
    settled (every start that fit about as well ended in one rig: multistart.settled_starts),
    later runs try only its best starts, as the focal lengths are not in doubt, only the
    sampling's draw; a settled first run that registered every camera is the answer alone.
    Runs that disagree on the keypoint matches are, where `refined` is given, refined on the
    dense image correspondences and stop as well where they agree refined within AGREEMENT_DEG:
    the keypoint matches' valley is flat where the images' minimum is sharp, and there more
    runs would be refined to the same rig (docs/design-notes.md, Consensus: runs apart, refined).
    on_first_run(result): told of the first run's result (the image refinement's work ahead
    expects it: runs that agree keep the first)."""

    def __init__(self, calibrate_once: CalibrateOnce, config: PipelineConfig,
                 camera_names: Sequence[str], progress: Progress,
                 refined: Optional[RefinedDisagreement] = None,
                 on_first_run: Optional[Callable[[object], None]] = None):
        self._calibrate_once, self._config = calibrate_once, config
        self._names, self._progress = list(camera_names), progress
        self._refined, self._on_first_run = refined, on_first_run
        self.results: list = []
        self.seeds: list[int] = []
        self.failed = 0
        self.settled: Optional[list[str]] = None
        self.refined_deg: Optional[np.ndarray] = None
        # Where the first EARLY_STOP_RUNS runs were judged: the largest disagreement between
        # them on the keypoint matches (deg), and where they stood apart there, refined on the
        # dense image correspondences (deg; None where not refined).
        self.apart_on_matches_deg: Optional[float] = None
        self.judged_apart_deg: Optional[float] = None
        self.cut_short = False  # ended by the caller's rule (run's `until`)
        self._first_error: Optional[CalibrationError] = None
        self._next, self._judged, self._run_s = 0, False, None

    def run(self, until: Optional[Callable[["ConsensusRuns"], bool]] = None) -> "ConsensusRuns":
        """The runs made, from where an earlier call ended; until(self): a caller's rule that
        ends them before the next run, once the runs so far are judged (a second matcher's: the
        first run left a camera out, or the first runs stand apart refined, and more runs on
        these matches would only delay the other matcher). Raises the first run's error where
        every run failed."""
        self.cut_short = False
        n = self._config.consensus_runs
        for k in range(self._next, n):
            if self._enough(k, until):
                break
            self._progress.advance(k, total=n if self._judged else min(n, EARLY_STOP_RUNS),
                                   label=f"calibration run {k + 1} of up to {n}")
            self._one_run(k)
            self._next = k + 1
        if not self.results:
            raise self._first_error
        return self

    def _enough(self, k: int, until: Optional[Callable[["ConsensusRuns"], bool]]) -> bool:
        """Whether run k need not be made (the class docstring's rules, then `until`)."""
        if k == 1 and self._settled_whole():
            log.info("consensus: the first run's focal multi-start settled and it registered "
                     "every camera; no more runs")
            return True
        if len(self.results) == EARLY_STOP_RUNS and not self._judged:
            self._judged = True
            stop, self.refined_deg = self._no_more_runs()
            if stop:
                return True
        if until is not None and until(self):
            self.cut_short = True
            return True
        return False

    def _one_run(self, k: int) -> None:
        seed = self._config.sampling.seed + k
        # What this run will take; nothing where runs take under a second.
        took = f"; about {self._run_s:.0f} s each" if self._run_s and self._run_s >= 1.0 else ""
        only = f"; focal starts {' and '.join(self.settled)} only" if self.settled else ""
        self._progress.say(f"consensus run {k + 1} of up to {self._config.consensus_runs} "
                           f"(sampling seed {seed}{only}{took})")
        started = time.perf_counter()
        try:
            self.results.append(self._calibrate_once(
                seed, self.settled, self._progress if k == 0 else self._progress.muted()))
            self.seeds.append(seed)
            self._run_s = time.perf_counter() - started
        except CalibrationError as exc:
            log.info("consensus run %d (seed %d) failed: %s", k + 1, seed, exc)
            self.failed += 1
            self._first_error = self._first_error or exc
        first = self.results[0] if k == 0 and self.results else None
        if first is not None and first.state is not None and self._on_first_run is not None:
            self._on_first_run(first)
        if first is not None and first.settled_starts:
            self.settled = first.settled_starts
            self._run_s = None  # the later runs try fewer starts: the first run's time says nothing

    def _settled_whole(self) -> bool:
        """Whether the one run so far settled (multistart.settled_starts) and registered every
        camera: then another sample could only repeat it. Every start that fit about as well
        ended in its rig, so the focal lengths are not in doubt, and with every camera placed no
        pair is left to the sampling's draw; a camera left out is (another sample may register
        it: a run that does disagrees with this one by consensus.UNREGISTERED_PAIR_DEG on its
        pairs), so such a run is checked by more (docs/design-notes.md, Consensus: one settled
        run)."""
        return bool(self.settled) and len(self.results) == 1 and \
            len(self.results[0].rig.cameras) == len(self._names)

    def _no_more_runs(self) -> tuple[bool, Optional[np.ndarray]]:
        """Whether the runs so far answer alike, so that more runs could only repeat them: they
        agree within multistart.agreement_deg, or, where `refined` is given, refined on the dense
        image correspondences within AGREEMENT_DEG; with, in that case, their disagreement matrix
        refined (else None)."""
        agree_deg = runs_agreement_deg(self.results[0].rig, self._names, self._config)
        apart_deg = medoid([r.rig for r in self.results], self._names)[1].max()
        self.apart_on_matches_deg = float(apart_deg)
        if apart_deg < agree_deg:
            log.info("consensus: the %d runs agree within %.1f deg; no more runs",
                     len(self.results), agree_deg)
            return True, None
        refined_deg = self._refined(self.results) if self._refined is not None else None
        if refined_deg is not None:
            self.judged_apart_deg = float(refined_deg.max())
        if refined_deg is not None and refined_deg.max() < AGREEMENT_DEG:
            log.info("consensus: the %d runs, %.1f deg apart on the keypoint matches, agree "
                     "within %.2f deg refined on the dense image correspondences; no more runs",
                     len(self.results), apart_deg, refined_deg.max())
            return True, refined_deg
        return False, None


def choose(runs: ConsensusRuns, camera_names: Sequence[str], config: PipelineConfig,
           match_tracks: Optional[Tracks], progress: Progress) -> Choice:
    """The run to keep (consensus.choose_run), said with the runs fitting clearly worse."""
    results, seeds = runs.results, runs.seeds
    choice = choose_run([r.rig for r in results], [r.tracks for r in results], camera_names,
                        cost_truncation_px(config.sfm, len(camera_names)), config.sampling.seed,
                        refined_on=match_tracks,
                        agree_deg=runs_agreement_deg(results[0].rig, camera_names, config),
                        first_searched_more=runs.settled is not None)
    costs = choice.costs_px
    if choice.worse_fit:
        progress.say("consensus: the runs with seeds " + ", ".join(
            f"{seeds[k]} ({costs[k]:.2f} px)" for k in choice.worse_fit) + " fit the common "
            f"tracks clearly worse than seed {seeds[int(np.nanargmin(costs))]} "
            f"({np.nanmin(costs):.2f} px) and are not kept")
    if len(results) > 1:
        why = (f"fits the keypoint-match tracks best ({costs[choice.best]:.3f} px on a common "
               "sample)" if choice.by_fit else "agrees best with the others")
        progress.say(f"consensus: kept the run with seed {seeds[choice.best]}, which {why}")
    return choice


@dataclass
class ConsensusRecord:
    """The consensus as the quality record and the warning need it: the runs made and failed,
    the kept run's seed, the first run's settled starts, the runs fitting clearly worse, whether
    the kept run was chosen by its fit, the median disagreement of the kept rig with the other
    runs (deg) and, refined on the images, with them (where the runs were judged so), the least
    determined camera pairs (a, b, deg), and where the runs disagree beyond the warning's bar,
    the other run at the median disagreement (runner_up: its index and seed) and the spread of
    each camera's intrinsics and rotation over the runs (intrinsics_spread:
    runs_intrinsics_spread); the
    median disagreement with the other runs that fit about as well (fitting_disagreement_deg:
    choose_run's worse_fit left out; None where no other run is left), which a refusal reads
    (core.stages.record.refusal)."""

    num_runs: int
    failed_runs: int
    seed: int
    settled_starts: Optional[list]
    worse_fit_runs: int
    kept_by_fit: bool
    disagreement_deg: float
    refined_disagreement_deg: Optional[float] = None
    least_determined_pairs: list = field(default_factory=list)
    runner_up: Optional[int] = None
    runner_up_seed: Optional[int] = None
    intrinsics_spread: dict = field(default_factory=dict)
    fitting_disagreement_deg: Optional[float] = None


def runs_intrinsics_spread(rigs: Sequence[RigCalibration], camera_names: Sequence[str]
                           ) -> dict[str, tuple[float, float, float, float]]:
    """Camera name -> (focal px, projection px, rotation deg, principal point px): how far one
    run's answer for the camera scatters, from the runs that registered it (at least two). Each
    run calibrates from its own seeded sample of the tracks, so the runs are a bootstrap of the
    calibration over its correspondences: the focal's is the runs' sample standard deviation,
    the principal point's the larger of its two axes' (as its sigma is checked: the larger
    axis's error), the projection's the same from the pairs' mean projection-map differences
    (for two independent draws the mean square difference is twice the variance), the
    rotation's likewise from the pairs' angles between its rotations relative to the first of
    camera_names that every run registered (nan where there is none; 0 for that camera)."""
    common = [n for n in camera_names if all(n in rig.cameras for rig in rigs)]

    def relative(rig: RigCalibration, name: str) -> np.ndarray:
        return rig.cameras[name].cam_from_rig[:3, :3] @ \
            rig.cameras[common[0]].cam_from_rig[:3, :3].T
    out = {}
    for name in camera_names:
        placed = [rig for rig in rigs if name in rig.cameras]
        if len(placed) < 2:
            continue
        cams = [rig.cameras[name].intrinsics for rig in placed]
        focal_px = float(np.std([mean_focal_px(c) for c in cams], ddof=1))
        point_px = float(np.max(np.std([principal_point_px(c) for c in cams], axis=0, ddof=1)))
        apart_px = [projection_map_error(a, b)["mean_px"] for a, b in combinations(cams, 2)]
        apart_px = [d for d in apart_px if np.isfinite(d)]
        projection_px = float(np.sqrt(np.mean(np.square(apart_px)) / 2.0)) if apart_px \
            else float("nan")
        turned_deg = [rotation_angle_deg(relative(a, name) @ relative(b, name).T)
                      for a, b in combinations(placed, 2)] if common else []
        rotation_deg = float(np.sqrt(np.mean(np.square(turned_deg)) / 2.0)) if turned_deg \
            else float("nan")
        out[name] = (focal_px, projection_px, rotation_deg, point_px)
    return out


def summarize(kept: RigCalibration, runs: ConsensusRuns, choice: Choice,
              camera_names: Sequence[str], progress: Progress, hopped: bool = False
              ) -> ConsensusRecord:
    """How far the kept rig (the chosen run's, after focal hops where `hopped`) stands from the
    other runs, said and recorded (ConsensusRecord)."""
    from .consensus import WARN_DISAGREEMENT_DEG

    best, results = choice.best, runs.results
    others = np.delete(choice.disagreement_deg[best], best)
    if hopped:
        others = np.array([rig_disagreement_deg(kept, r.rig, camera_names)
                           for k, r in enumerate(results) if k != best])
    record = ConsensusRecord(len(results), runs.failed, runs.seeds[best], runs.settled,
                             len(choice.worse_fit), choice.by_fit,
                             float(np.median(others)) if len(others) else 0.0)
    fitting = [d for k, d in zip([k for k in range(len(results)) if k != best], others)
               if k not in choice.worse_fit]
    record.fitting_disagreement_deg = float(np.median(fitting)) if fitting else None
    said = ""
    if runs.refined_deg is not None and len(results) > 1:
        record.refined_disagreement_deg = float(np.median(np.delete(runs.refined_deg[best],
                                                                    best)))
        said = (f" ({record.refined_disagreement_deg:.2f} deg refined on the dense image "
                "correspondences)")
    if len(results) > 1:
        progress.say(f"consensus: median disagreement of the result with the other "
                     f"{len(results) - 1} runs {record.disagreement_deg:.2f} deg{said}")
    record.least_determined_pairs = least_determined_pairs(
        kept, [r.rig for k, r in enumerate(results) if k != best], camera_names)
    if record.disagreement_deg > WARN_DISAGREEMENT_DEG:
        # The other run at the median disagreement (the upper one of an even count): the one the
        # reported disagreement is measured to.
        other_runs = [k for k in range(len(results)) if k != best]
        record.runner_up = other_runs[int(np.argsort(others)[len(others) // 2])]
        record.runner_up_seed = runs.seeds[record.runner_up]
    if max(record.disagreement_deg, record.refined_disagreement_deg or 0.0) > \
            WARN_DISAGREEMENT_DEG:  # what a calibration left warned adds to its sigmas
        record.intrinsics_spread = runs_intrinsics_spread([r.rig for r in results], camera_names)
    return record
