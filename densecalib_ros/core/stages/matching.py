"""The matching stage: every frame set's ordered camera pairs matched (core.method.matching),
away from the regions no match may use, and the keypoint matches as tracks for what refines and
judges the rig on all of them (core.method.all_matches)."""
from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np

from ..config import PipelineConfig
from ..method.all_matches import keypoint_tracks
from ..method.masks import apply_masks, ignored_regions, info_strips
from ..method.matching import create_matcher
from ..method.new_content import describe as describe_regions
from ..method.new_content import new_content_regions
from ..progress import Progress, StageClock
from ..types import SiteMatchSet, Tracks
from .inputs import RigImages

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Matched:
    """One matcher's matches of a rig's frame sets: a SiteMatchSet per frame set and, where the
    configuration refines on all keypoint matches, those matches as tracks (else None), drawn
    with the sampling seed `seed`; identity_tracks: correspondences by identity the user gave
    (pose keypoints, core.method.identity_tracks), which each run uses beside the matches."""

    matcher: str
    match_sets: list
    keypoint_tracks: Optional[Tracks]
    seed: int = 0
    identity_tracks: Optional[Tracks] = None

    def since(self, first: int) -> "Matched":
        """The matches of frame set `first` on (a recalibration's, after a change of the rig);
        the keypoint tracks made again from them."""
        sets = self.match_sets[first:]
        tracks = None if self.keypoint_tracks is None else keypoint_tracks(
            sets, self.keypoint_tracks.num_cameras, seed=self.seed)
        return Matched(self.matcher, sets, tracks, self.seed, self.identity_tracks)


def match_rig(images: RigImages, config: PipelineConfig, progress: Progress, matcher=None,
              each_on_its_own: bool = False, identity_tracks: Optional[Tracks] = None
              ) -> Matched:
    """The stage: images' frame sets matched with config.matcher (`matcher`: such a one, already
    loaded, to reuse), the keypoint tracks made (config.refine_on_all_matches); identity_tracks
    carried beside them (Matched)."""
    sets = match_frame_sets(images.frame_sets, config, matcher=matcher, progress=progress,
                            camera_names=images.camera_names, ignored=images.ignored,
                            each_on_its_own=each_on_its_own)
    tracks = keypoint_tracks(sets, len(images.camera_names), seed=config.sampling.seed) \
        if config.refine_on_all_matches else None
    return Matched(config.matcher, sets, tracks, config.sampling.seed, identity_tracks)


def match_frame_sets(frame_sets: Sequence[Sequence[np.ndarray]], config: PipelineConfig, *,
                     matcher=None, progress=None, camera_names: Optional[Sequence[str]] = None,
                     strips: Optional[dict] = None, ignored: Optional[list] = None,
                     each_on_its_own: bool = False) -> list:
    """One SiteMatchSet per frame set. matcher: an already loaded core.method.matching.Matcher to
    reuse (else config.matcher is created and loaded here). With config.cameras.masks (then
    camera_names is needed), matches on masked regions are dropped (core.method.masks), and on the
    info strips found (`strips` as info_strips gives them; None: looked for here); `ignored`:
    those regions as ignored_regions gives them, when already resolved. With config.matcher in
    config.new_content_matchers, frame sets after the first are matched only where they show
    something new (core.method.new_content), unless each_on_its_own: every frame set whole, for
    what judges each on its own (a check, a recalibration: a camera may have moved in between).
    progress: a core.progress.Progress (or a message callback): the stage "match", a step per
    frame set, stopped between image pairs."""
    progress = Progress.of(progress)
    if ignored is None:
        if strips is None:
            strips = info_strips(frame_sets, camera_names, config)
        ignored = ignored_regions(frame_sets, camera_names, config, strips)
    if matcher is None:
        matcher = create_matcher(config.matcher, max_image_side_px=config.max_image_side_px)
        matcher.load()
    regions = new_content_regions(frame_sets) \
        if config.matcher in config.new_content_matchers and not each_on_its_own else None
    progress.begin("match", f"matching ({config.matcher})", len(frame_sets))
    match_sets, clock = [], StageClock(len(frame_sets), first_apart=regions is not None)
    for t, frames in enumerate(frame_sets):
        where = next(regions) if regions is not None else None
        match_sets.append(_matched_set(matcher, frames, where, ignored, t, progress))
        if ignored:
            log.debug("frame set %d: %d match(es) on masked regions dropped", t,
                      apply_masks(match_sets[-1], ignored))
        left_s = clock.seconds_left(t + 1)
        progress.advance(t + 1, left_s=left_s)
        progress.say(f"matched frame set {t + 1}/{len(frame_sets)} ({config.matcher})"
                     + clock.said(left_s))
    return match_sets


def _matched_set(matcher, frames: Sequence[np.ndarray], where: Optional[list], ignored: list,
                 t: int, progress: Progress) -> SiteMatchSet:
    """Frame set t matched where `where` (new content, or None: whole) and outside `ignored`."""
    if where is not None and ignored:  # nothing to detect where no match may lie
        where = [r if r is None or skip is None else r & ~skip for r, skip in zip(where, ignored)]
    if where is not None and t > 0:
        log.info("frame set %d: matched on %s of the images (what earlier frame sets did not "
                 "show)", t + 1, describe_regions(where))
    if where is not None and all(r is not None and not r.any() for r in where):
        return SiteMatchSet(  # nothing new in any camera: nothing to match
            sites=[np.zeros((0, 2)) for _ in frames], pairs={},
            image_sizes=[(f.shape[1], f.shape[0]) for f in frames])
    return matcher.match(list(frames), where,
                         on_step=lambda done, total: progress.substep(done / total))
