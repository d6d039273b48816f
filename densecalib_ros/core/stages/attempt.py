"""One matcher's matches calibrated (Calibrator): the consensus runs (core.robust.consensus_runs)
or, for a recalibration or a single run, one run; the focal hops where the runs found different
minima; the kept run refined on the images; its quality record (stages.record.assemble). The
result (Attempt) is what the second matcher's policy compares."""
from __future__ import annotations

import copy
from dataclasses import dataclass, replace
from typing import Callable, Optional

from ..calibration_result import CalibrationResult, result_with_state
from ..config import PipelineConfig
from ..method.known_intrinsics import given_intrinsics_fit
from ..progress import Progress
from ..robust.consensus import rig_disagreement_deg
from ..robust.consensus_runs import (ConsensusRecord, ConsensusRuns, choose, runs_agreement_deg,
                                     summarize)
from ..robust.focal_hops import hop_focals
from ..types import RigCalibration
from .inputs import RigImages
from .matching import Matched
from .record import assemble
from .refinement import RefinedRuns, RefinementRecord, dense_ahead
from .runs import calibrate_once


@dataclass
class Attempt:
    """A matcher's calibration, finished but for the warnings: the kept (refined) result with its
    quality record, the configuration that made it, and what the stages did."""

    result: CalibrationResult
    config: PipelineConfig
    matched: Matched
    consensus: Optional[ConsensusRecord]
    refinement: Optional[RefinementRecord]
    cut_short: bool = False  # its consensus runs were ended by the caller's rule
    # Ended after its first run, not refined on the images (Calibrator.calibrate's
    # refine_cut_short): calibrate again to have it refined.
    unrefined: bool = False
    # The kept run's rig as the SfM left it, before the refinement on the images (which gives
    # identical units each its own intrinsics): what the one-model policy judges the model by.
    sfm_rig: Optional[RigCalibration] = None

    @property
    def rig(self) -> RigCalibration:
        return self.result.rig


class Calibrator:
    """Calibrations on one matcher's matches (`matched`) of the rig's images, with `config`.
    previous: a previous calibration (a recalibration: one run, started from it); same_matches:
    another Calibrator of these matches (the same rig as one model), whose dense correspondences'
    first pass, found ahead, this one takes over. Close it when done: the image refinement's
    work run ahead is stopped."""

    def __init__(self, images: RigImages, matched: Matched, config: PipelineConfig,
                 progress: Progress, previous: Optional[RigCalibration] = None,
                 same_matches: Optional["Calibrator"] = None):
        self.images, self.matched, self.config = images, matched, config
        self.progress, self.previous = progress, previous
        ahead = dense_ahead(images, matched, config, same_matches.refined.ahead
                            if same_matches is not None and same_matches.refined else None)
        self.refined = RefinedRuns(images, matched, config, previous, ahead) \
            if config.refine_on_images else None
        self.runs = None
        if previous is None and config.consensus_runs > 1:
            self.runs = ConsensusRuns(
                self._once, config, images.camera_names, progress,
                self.refined.disagreement_deg if self.refined is not None else None,
                (lambda first: ahead.expect(first.state)) if ahead is not None else None)

    def calibrate(self, until: Optional[Callable[[ConsensusRuns], bool]] = None,
                  refine_cut_short: bool = True) -> Attempt:
        """The calibration (module docstring); `until`: the consensus runs' caller's rule
        (ConsensusRuns.run), and a later call goes on with the runs it ended. Where `until` ended
        them after the first run and not refine_cut_short, the run is not refined on the images
        (Attempt.unrefined): the caller (the second matcher's policy) may need it only to count
        its cameras."""
        names = self.images.camera_names
        if self.refined is not None:
            self.refined.pause(False)  # set aside unrefined before (below), now taken up again
        self.progress.begin("calibrate", "calibrating", 1)
        consensus, hops = None, []
        if self.runs is not None:
            self.runs.run(until)
            choice = choose(self.runs, names, self.config, self.matched.keypoint_tracks,
                            self.progress)
            result = self.runs.results[choice.best]
            # agreement_deg of the first run's cameras, as the runs' early stop judged them
            agree_deg = runs_agreement_deg(self.runs.results[0].rig, names, self.config)
            if choice.disagreement_deg.max() >= agree_deg and self.runs.refined_deg is None:
                result, hops = self._focal_hops(result)
            consensus = summarize(result.rig, self.runs, choice, names, self.progress,
                                  hopped=bool(hops))
        else:
            result = self._once(self.config.sampling.seed, None, self.progress)
        refinement, sfm_rig = None, result.rig
        unrefined = self.refined is not None and not refine_cut_short and \
            self.runs is not None and self.runs.cut_short and len(self.runs.results) == 1
        if unrefined:
            self.refined.pause()  # its dense correspondences wait while the caller goes on
        elif self.refined is not None:
            self.progress.begin("refine", "refining on the images", 1,
                                self.refined.seconds_waited(result))
            result, refinement = self.refined.refine(result, self.progress)
            if consensus is not None and consensus.runner_up is not None and \
                    refinement is not None and consensus.refined_disagreement_deg is None:
                self._refine_runner_up(result, consensus)
        too_few = self.refined.thin_cameras(result) if self.refined is not None and \
            refinement is None and not unrefined else None
        result = replace(result, rig=copy.deepcopy(result.rig))  # the record is this one's own
        assemble(result, self.config, names, self.matched.keypoint_tracks, consensus, hops,
                 refinement, too_few)
        return Attempt(result, self.config, self.matched, consensus, refinement,
                       cut_short=self.runs is not None and self.runs.cut_short,
                       unrefined=unrefined, sfm_rig=sfm_rig)

    def close(self) -> None:
        if self.refined is not None:
            self.refined.close()

    def _once(self, seed: int, only_starts: Optional[list], progress: Progress
              ) -> CalibrationResult:
        config = self.config if seed == self.config.sampling.seed else \
            self.config.with_options(sampling__seed=seed)
        return calibrate_once(self.matched, self.images.image_sizes, self.images.camera_names,
                              config, progress, self.previous, only_starts)

    def _focal_hops(self, result: CalibrationResult) -> tuple[CalibrationResult, list[str]]:
        """The runs found different minima, which the images do not make one: search around the
        kept one (core.robust.focal_hops)."""
        tracks = self.matched.keypoint_tracks
        if tracks is None or not tracks.num_tracks or result.state is None:
            return result, []
        names = list(self.images.camera_names)
        state, hops = hop_focals(result.state, tracks, names, self.config.sfm,
                                 self.config.sampling.seed, self.progress.say)
        if not hops:
            return result, []
        result = result_with_state(result, state, names)
        if result.sfm.given_intrinsics_fit:  # judged again on the hopped rig
            result = replace(result, sfm=replace(result.sfm, given_intrinsics_fit=(
                given_intrinsics_fit(state, names, self.config.sfm.num_threads) or None)))
        return result, hops

    def _refine_runner_up(self, result: CalibrationResult, consensus: ConsensusRecord) -> None:
        """Refine the runner-up run on the dense image correspondences as the kept rig (`result`,
        refined) was, and record how far apart the two come out. Runs that disagree on the
        keypoint matches' flat valley can meet in the dense correspondences' sharper minimum:
        then the images determine the rig after all, and neither a warning nor a second matcher
        is called for."""
        rig = self.refined.rig(self.runs.results[consensus.runner_up])
        if rig is None:
            return
        deg = rig_disagreement_deg(result.rig, rig, self.images.camera_names)
        consensus.refined_disagreement_deg = deg
        self.progress.say(f"consensus: refined on the dense image correspondences as well, the "
                          f"run with seed {consensus.runner_up_seed} comes out {deg:.2f} deg "
                          "from the kept rig")

