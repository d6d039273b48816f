"""The image refinement stage: the kept run refined on dense correspondences measured in the images
(core.method.image_refinement), found ahead on idle cores while the rig is still being searched
(DenseAhead). Runs that disagree on the keypoint matches may meet refined: the consensus policy
asks for their refinements too (RefinedRuns.disagreement_deg), and the kept run's is then not
computed again."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional, Sequence

import numpy as np

from ..calibration_result import CalibrationResult, result_with_state, rig_from_state
from ..config import PipelineConfig
from ..method.dense_ahead import DenseAhead
from ..method.dense_matches import TooFewDenseCorrespondences, keypoint_px_scale
from ..method.image_refinement import PP_PRIOR_STD_FRACTION, ImageRefinement, refine_on_images
from ..method.prior_adjustment import SUPPORTED_MODELS
from ..method.uncertainty import estimated_principal_points
from ..progress import Progress
from ..robust.consensus import medoid
from ..types import RigCalibration, Tracks
from .inputs import RigImages
from .matching import Matched


@dataclass(frozen=True)
class RefinementRecord:
    """What the stage did to the kept rig, for the quality record: the dense tracks it adjusted
    on, their noise (px), the principal point prior's sigma (fraction of the long side), per
    camera the intrinsics the images determined, per camera its CameraUncertainty, the
    one-camera test's verdicts (ImageRefinement.one_camera) and the camera groups its points do
    not connect (ImageRefinement.apart)."""

    num_tracks: int
    noise_px: float
    pp_prior_std_fraction: float
    estimated: dict
    sigmas: dict
    one_camera: dict = field(default_factory=dict)
    apart: list = field(default_factory=list)  # ImageRefinement.apart


def dense_ahead(images: RigImages, matched: Matched, config: PipelineConfig,
                first_of: Optional[DenseAhead] = None) -> Optional[DenseAhead]:
    """The image refinement's dense correspondences, which need only the images and the keypoint
    matches until their last checks, started on cores the rig's search leaves idle
    (dense_ahead.DenseAhead). None where the refinement will not run, or will not start from
    the keypoint matches, or cannot apply (a lens model it does not project). first_of: the
    DenseAhead of another calibration of the same matches, whose first pass is taken over."""
    tracks = matched.keypoint_tracks
    if not config.refine_on_images or tracks is None or not tracks.num_tracks or any(
            m not in SUPPORTED_MODELS for m in config.sfm.models(len(images.camera_names))):
        return None
    return DenseAhead(images.frame_sets, len(images.camera_names), tracks,
                      images.ignored or None, keypoint_px_scale(images.image_sizes,
                                                                config.max_image_side_px),
                      first_of)


class RefinedRuns:
    """Calibrations (their SfM states) refined on the dense image correspondences, each state
    once (a result rebuilt from another state, e.g. after focal hops, is refined anew).
    previous: a previous calibration, whose principal points its images determined centre the
    priors; ahead: the dense correspondences as far as they were found ahead, or None."""

    def __init__(self, images: RigImages, matched: Matched, config: PipelineConfig,
                 previous: Optional[RigCalibration], ahead: Optional[DenseAhead]):
        self.images, self.matched, self.config, self.ahead = images, matched, config, ahead
        self.pp_centres = estimated_principal_points(previous)
        self.px_scale = keypoint_px_scale(images.image_sizes, config.max_image_side_px)
        # (state, its refinement or None, its messages, its thin cameras or None)
        self._done: list[tuple] = []

    def refinement(self, result: CalibrationResult, progress: Optional[Progress] = None
                   ) -> Optional[ImageRefinement]:
        """The ImageRefinement of result.state (None where the stage does not apply); its
        messages are said to `progress` (where given) each time it is asked for."""
        state = result.state
        found = next((done for done in self._done if done[0] is state), None)
        if found is None:
            if self.ahead is not None and progress is not None:
                self.ahead.wait(state, progress.waited)
            messages: list[str] = []
            # identical units, estimated as one by the SfM: each unit's own from here, as one
            # camera where the images do not tell them apart (the refinement's one-camera test)
            units = [c for group in self.config.sfm.shared_intrinsics_groups for c in group]
            thin = None
            try:
                refinement = refine_on_images(
                    state.with_own_blocks(units) if units else state, self.images.frame_sets,
                    _seeds(result, self.matched.keypoint_tracks), self.images.camera_names,
                    self.images.ignored or None, self.config.sampling.seed, messages.append,
                    self.pp_centres, self.ahead, self.px_scale)
            except TooFewDenseCorrespondences as exc:
                refinement, thin = None, exc.counts
                messages.append(f"dense correspondences: too few in {exc}; the rig is kept as "
                                "found")
            found = (state, refinement, messages, thin)
            self._done.append(found)
        for message in found[2] if progress is not None else ():
            progress.say(message)
        return found[1]

    def thin_cameras(self, result: CalibrationResult) -> Optional[dict]:
        """Where refining result met too few dense correspondences (dense_matches.
        TooFewDenseCorrespondences): camera name -> its dense observations; else None."""
        return next((done[3] for done in self._done if done[0] is result.state), None)

    def seconds_waited(self, result: CalibrationResult) -> Optional[float]:
        """About how long refining result will wait for its dense correspondences still found
        ahead (DenseAhead.seconds_left); None where nothing runs ahead."""
        if self.ahead is None or result.state is None:
            return None
        return self.ahead.seconds_left(result.state)

    def rig(self, result: CalibrationResult) -> Optional[RigCalibration]:
        """result's rig refined, None where the stage does not apply or there is no state."""
        refinement = self.refinement(result) if result.state is not None else None
        if refinement is None:
            return None
        names = list(self.images.camera_names)
        failed = [names.index(n) for n in result.rig.failed_cameras]
        return rig_from_state(refinement.state, names, failed, result.rig.quality)

    def disagreement_deg(self, results: Sequence[CalibrationResult]) -> Optional[np.ndarray]:
        """The (R, R) disagreement matrix (consensus.medoid's) of the results refined; None where
        one of them could not be (the others then not tried: a kept one is refined when kept)."""
        rigs = []
        for result in results:
            rigs.append(self.rig(result))
            if rigs[-1] is None:
                return None
        return medoid(rigs, self.images.camera_names)[1]

    def refine(self, result: CalibrationResult, progress: Progress
               ) -> tuple[CalibrationResult, Optional[RefinementRecord]]:
        """(result refined, what the stage did); the result as it was and None where the stage
        does not apply."""
        if result.state is None:
            return result, None
        refinement = self.refinement(result, progress)
        if refinement is None:
            return result, None
        refined = result_with_state(result, refinement.state, list(self.images.camera_names))
        for name, cam in refined.rig.cameras.items():
            placed_by = result.rig.cameras.get(name)
            if cam.quality is not None and placed_by is not None and placed_by.quality:
                cam.quality.sfm_multiview_observations = \
                    placed_by.quality.num_multiview_observations
        return refined, RefinementRecord(refinement.num_tracks,
                                         round(refinement.adjustment.noise_px, 4),
                                         PP_PRIOR_STD_FRACTION, dict(refinement.estimated),
                                         dict(refinement.uncertainty),
                                         dict(refinement.one_camera), list(refinement.apart))

    def close(self) -> None:
        """Stop the work still run ahead (a calibration that ends without it)."""
        if self.ahead is not None:
            self.ahead.cancel()

    def pause(self, paused: bool = True) -> None:
        """Hold the work still run ahead (a calibration set aside while another runs), or let
        it go on (not paused)."""
        if self.ahead is not None:
            self.ahead.pause(paused)


def _seeds(result: CalibrationResult, match_tracks: Optional[Tracks]) -> Tracks:
    """What the image refinement predicts its dense correspondences from: the keypoint-match
    tracks where there are any, else the tracks the rig was found on."""
    return match_tracks if match_tracks is not None and match_tracks.num_tracks \
        else result.tracks
