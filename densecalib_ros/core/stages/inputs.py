"""The first stage: the frame sets checked and the configuration resolved for the cameras, before
any work (a bad image in the last frame set, or intrinsics given for another resolution, would
otherwise surface minutes later)."""
from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np

from ..config import PipelineConfig
from ..method.frame_checks import check_frame_sets
from ..method.known_intrinsics import check_known_intrinsics
from ..method.masks import ignored_regions, info_strips
from ..method.prior_adjustment import SUPPORTED_MODELS
from ..progress import Progress


@dataclass(frozen=True)
class RigImages:
    """What a calibration runs on: frame_sets[t][c] camera c's image of moment t, the cameras'
    names and image sizes ((width, height) px), the configuration resolved for them and checked
    (PipelineConfig.for_cameras), the info strips found (camera -> strips) and per camera the
    bool (H, W) region no match may use, or None ([] where no camera has one)."""

    frame_sets: Sequence[Sequence[np.ndarray]]
    camera_names: tuple
    config: PipelineConfig
    image_sizes: tuple
    strips: dict
    ignored: list

    def since(self, first: int) -> "RigImages":
        """The same cameras' frame sets from frame set `first` on (a recalibration's, after a
        change of the rig)."""
        return RigImages(self.frame_sets[first:], self.camera_names, self.config,
                         self.image_sizes, self.strips, self.ignored)


def prepare(frame_sets: Sequence[Sequence[np.ndarray]], camera_names: Sequence[str],
            config: PipelineConfig, progress: Optional[Progress] = None) -> RigImages:
    """The frame sets checked (check_frame_sets: InputError naming the camera and frame set),
    the intrinsics given checked against the images' sizes, the configuration resolved for the
    cameras and checked, and the regions the matches must keep out of; the identical units
    said (to `progress`)."""
    image_sizes = check_frame_sets(frame_sets, camera_names)
    names = tuple(camera_names)
    if config.cameras.known_intrinsics:
        config = config.with_options(cameras__known_intrinsics=check_known_intrinsics(
            config.cameras.known_intrinsics, names, image_sizes))
    config = config.for_cameras(names)
    for members, why in config.cameras.identical_units if progress is not None else ():
        refined = config.refine_on_images and all(
            config.sfm.model_of(names.index(n)) in SUPPORTED_MODELS for n in members)
        progress.say(f"{', '.join(members)}: identical units ({why}): one set of intrinsics in "
                     "the SfM" + (", each unit's own in the refinement on the images" if refined
                                  else ""))
    strips = info_strips(frame_sets, names, config)
    return RigImages(frame_sets, names, config, tuple(image_sizes), strips,
                     ignored_regions(frame_sets, names, config, strips))
