"""One progress channel for the calibration's stages: each event is said once, by `say_progress`,
which logs it (INFO, under the stage's logger) and passes it to the caller's callback. Front ends
show one of the two: the commands the log, the node its ~/status topic (the log reaches /rosout
through ros.core_logs)."""
from __future__ import annotations

import logging
from typing import Callable, Optional

Progress = Optional[Callable[[str], None]]


def say_progress(progress: Progress, msg: str, logger: Optional[logging.Logger] = None) -> None:
    (logger or logging.getLogger(__name__)).info(msg)
    if progress is not None:
        progress(msg)
