"""The node's check of its calibration against frame sets (~/check and the watch): the epipolar
check per frame set since the last change (core.monitor.consistency) and each camera against its
reference view (core.monitor.reference_views), one verdict."""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

from ..core.types import RigCalibration
from .settings import Settings, pipeline_config


@dataclass
class CheckOutcome:
    """A check's result: fits None = it could not tell (too few matches, no frame sets)."""
    fits: Optional[bool]
    message: str
    misfit_sets: int = 0  # the frame sets the failing figures come from
    calibration_dir: Optional[Path] = None  # the calibration it judged
    at: float = field(default_factory=time.time)



def check_frame_sets(rig: RigCalibration, calibration_dir: Optional[Path], s: Settings,
                     sets: list, images: list, matcher) -> CheckOutcome:
    """Does `rig` (stored in calibration_dir, with its reference views) still fit the frame sets
    `sets` (their decoded `images`), matched with the loaded `matcher`."""
    from ..core.io.reference_view_files import read_reference_views
    from ..core.monitor.consistency import best_transfer_per_camera, check_latest
    from ..core.monitor.reference_views import check_verdict, compare_with_reference_views
    from ..core import match_frame_sets

    match_sets = match_frame_sets(images, pipeline_config(s), matcher=matcher,
                                  camera_names=s.camera_names, each_on_its_own=True)
    report = check_latest(rig, s.camera_names, match_sets, s.check_tolerance_px)
    k = report.frame_sets_before_change
    since = (f" (the change came before the frame set stamped {sets[k].stamp_ns * 1e-9:.3f} "
             "s)" if k else "")
    views = None
    references = (read_reference_views(calibration_dir, s.camera_names)
                  if calibration_dir is not None else {})
    if references:
        views = compare_with_reference_views(rig, s.camera_names, images, references,
                                             s.check_tolerance_px)
    fits, verdict = check_verdict(report, views, report.verdict() + since,
                                  [n for n in s.camera_names if n in rig.cameras])
    per_camera = ", ".join(f"{t.target} {t.median_error_px:.2f}"
                           for t in best_transfer_per_camera(report.transfers))
    return CheckOutcome(fits, f"{verdict}; {len(sets)} frame sets"
                        + (f"; transfer error px: {per_camera}" if per_camera else ""),
                        misfit_sets=max(0 if report.fits else len(sets) - k,
                                        views.changed_sets if views else 0))
