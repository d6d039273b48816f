"""The matcher interface every backend implements."""
from __future__ import annotations

import abc
from typing import Callable, ClassVar, Optional, Sequence

import numpy as np

from ...errors import InputError
from ...types import SiteMatchSet
from .utils import check_images


class Matcher(abc.ABC):
    """Images in; per image a table of sites; per ordered camera pair a site map with certainty.

    Usage: `m = create_matcher(name, **options); m.load(); match_set = m.match(images)`.
    `load()` is the explicit heavy step (model weights); `match()` calls it if it was skipped.
    Options are keyword arguments of the backend's constructor; every backend takes
    `max_image_side_px` (images are matched at most at this size; coordinates are mapped back to
    the original image exactly).
    """

    name: ClassVar[str]
    # Whether _match takes the regions (its keypoints only there) as its second argument.
    detects_in_regions: ClassVar[bool] = False

    def __init__(self, max_image_side_px: int | None = 1024):
        self.max_image_side_px = max_image_side_px
        self._loaded = False

    def load(self) -> None:
        """Load model weights; idempotent. Raises ModelWeightsError naming a missing file."""
        if not self._loaded:
            self._load()
            self._loaded = True

    def _load(self) -> None:
        """Backend-specific heavy initialisation (default: nothing)."""

    def match(self, images: Sequence[np.ndarray],
              regions: Optional[Sequence[Optional[np.ndarray]]] = None,
              on_step: Optional[Callable[[int, int], None]] = None) -> SiteMatchSet:
        """Match every ordered pair of a frame set.

        images: one per camera, (H, W, 3) uint8 RGB or (H, W) uint8 gray; sizes may differ.
        regions: per image None or bool (H, W), True where its matches may lie (e.g.
        core.method.new_content); a backend that can detect in regions only does
        (detects_in_regions), the others' matches outside them are dropped.
        Returns a SiteMatchSet with `sites[c]` float64 (S_c, 2) COLMAP pixel coordinates in the
        original image c and `pairs[(i, j)]` for every ordered pair i != j.
        on_step(done, total): told as each image's features and each unordered pair are done
        (total: images + pairs; backends that match all at once tell it at the end); what it
        raises (a cancelled calibration) ends the matching.
        """
        images = check_images(images)
        self.load()
        steps = Steps(len(images) + len(images) * (len(images) - 1) // 2, on_step)
        match_set = self._matched(images, regions, steps)
        steps.finish()
        return match_set

    def _matched(self, images: list[np.ndarray], regions, steps: "Steps") -> SiteMatchSet:
        if regions is None or all(r is None for r in regions):
            return self._match(images, steps)
        if len(regions) != len(images) or any(
                r is not None and r.shape != im.shape[:2] for r, im in zip(regions, images)):
            raise InputError(f"{len(regions)} regions for {len(images)} images: give one per "
                             "image, None or a bool mask of the image's height and width.")
        if self.detects_in_regions:
            return self._match(images, steps, list(regions))
        from ..masks import apply_masks

        match_set = self._match(images, steps)
        apply_masks(match_set, [None if r is None else ~r for r in regions])
        return match_set

    @abc.abstractmethod
    def _match(self, images: list[np.ndarray], steps: "Steps") -> SiteMatchSet:
        """Backend matching on validated images; steps.done() after each image's features and
        each unordered pair."""


class Steps:
    """A frame set's matching steps (each image's features, each unordered pair) counted for
    on_step(done, total), in the thread that counts them."""

    def __init__(self, total: int, on_step: Optional[Callable[[int, int], None]]) -> None:
        self.total, self.count, self._on_step = total, 0, on_step

    def done(self) -> None:
        self.count += 1
        if self._on_step is not None:
            self._on_step(min(self.count, self.total), self.total)

    def finish(self) -> None:
        """Every step done (a backend that matched all at once without counting)."""
        if self.count < self.total:
            self.count = self.total - 1
            self.done()
