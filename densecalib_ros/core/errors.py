"""Typed errors with messages a field user can act on. The CLI and the ROS service turn them into
an exit code / `success=False` response; nothing below the boundary prints or exits."""
from __future__ import annotations

from typing import Sequence


class CalibrationError(RuntimeError):
    """Base class of every error the calibration core raises on bad input or failed estimation."""


class InputError(CalibrationError):
    """The input cannot be used as given (unreadable image, wrong layout, unknown option)."""


class DamagedBagError(InputError):
    """A bag whose storage or messages stop reading part-way; `messages_read`: how many image
    messages of the requested topics were read before the damage, in bag order."""

    def __init__(self, message: str, messages_read: int):
        super().__init__(message)
        self.messages_read = messages_read


class NotEnoughCamerasError(CalibrationError):
    """Fewer than two cameras could be used or registered."""


class TooFewCamerasGivenError(InputError, NotEnoughCamerasError):
    """Fewer than two cameras in the input: bad input (the commands' exit code 2), before any
    work."""


class NotEnoughOverlapError(CalibrationError):
    """Cameras do not share enough cycle-consistent matches to be calibrated together."""


class DisconnectedViewGraphError(CalibrationError):
    """The cameras split into groups that share no matches; names the groups."""


class UndeterminedRigError(CalibrationError):
    """The calibration's runs fit the matches about as well and place the cameras far apart
    (core.robust.consensus.REFUSE_DISAGREEMENT_DEG): no rig is determined; names the pairs."""


class FocalInitError(CalibrationError):
    """The initial focal lengths could not be estimated from the fundamental matrices. Raised
    where only camera indices are known: `message` may hold "{cameras}", filled with the
    indices until named() gives the names."""

    def __init__(self, message: str, cameras: Sequence[int] = ()):
        self.template, self.cameras = message, list(cameras)
        super().__init__(message.format(cameras=self.cameras) if self.cameras else message)

    def named(self, camera_names: Sequence[str]) -> "FocalInitError":
        if not self.cameras:
            return self
        return FocalInitError(self.template.replace(
            "{cameras}", ", ".join(camera_names[c] for c in self.cameras)))


class ModelWeightsError(CalibrationError):
    """A learned matcher's weights are missing or unreadable at the configured path."""


class CalibrationCancelled(BaseException):
    """The calibration was stopped (a cancelled goal, Ctrl-C, SIGTERM) at one of its checks
    (core.progress.StopToken). Not a CalibrationError, and like KeyboardInterrupt not an
    Exception: the handlers that let a consensus run or a matcher fail and go on must not
    swallow it. Nothing was written."""
