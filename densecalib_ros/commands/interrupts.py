"""Ctrl-C (SIGINT) and SIGTERM (timeout, systemd, docker stop) in the offline command: exit codes
130 and 143 and one line, whenever the signal comes.

Outside a calibration a signal stops the command at once (Interrupted, raised in the main
thread). During a calibration (`stopping_calibration`) it does not: an exception raised in the
middle of a compiled kernel or a C++ call (numba's dispatcher, Ceres, OpenCV's threads) surfaces
as a SystemError or aborts the process. The signal sets the calibration's stop token instead,
and the calibration ends at its next check (core.progress), writing nothing. While the written result
is made the output folder (`finishing_write`, around the folders' exchange and the old one's
removal) the signal waits for that to end, so that what the command says is what the output
folder holds; before it, the half-written folder is removed and the old one stays. A second signal during a calibration ends the process at once.
"""
from __future__ import annotations

import contextlib
import logging
import os
import signal
import sys
import threading
from typing import Iterator, Optional

from ..core.progress import StopToken

log = logging.getLogger("densecalib")

EXIT_CODES = {signal.SIGINT: 130, signal.SIGTERM: 143}
SAID = {signal.SIGINT: "interrupted", signal.SIGTERM: "terminated (SIGTERM)"}


class Interrupted(KeyboardInterrupt):
    """A signal that stops the command, raised in the main thread as Ctrl-C is, so that the
    clean-up of what was half written runs on the way out. `signum`: which signal."""

    def __init__(self, signum: int):
        super().__init__(SAID[signum])
        self.signum = signum

    @property
    def exit_code(self) -> int:
        return EXIT_CODES[self.signum]


class _State:
    def __init__(self) -> None:
        self.token: Optional[StopToken] = None  # the running calibration's
        self.writing = False
        self.received: Optional[int] = None  # a signal received while it could not act


_state = _State()


def install() -> list:
    """Take SIGINT and SIGTERM (main thread only); returns what restore() puts back."""
    if threading.current_thread() is not threading.main_thread():
        return []
    return [(s, signal.signal(s, _on_signal)) for s in EXIT_CODES]


@contextlib.contextmanager
def held() -> Iterator[None]:
    """SIGINT and SIGTERM held back (blocked) for the block and delivered after it (main thread)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.pthread_sigmask(signal.SIG_BLOCK, set(EXIT_CODES))
    try:
        yield
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, previous)


def restore(previous: list) -> None:
    for signum, handler in previous:
        signal.signal(signum, handler)


def _on_signal(signum: int, frame) -> None:
    if _state.writing:
        _state.received = _state.received or signum
        return
    if _state.token is not None:
        if _state.received is not None:  # asked twice: now
            sys.stderr.write(f"{SAID[signum]} again: stopped at once; nothing written\n")
            sys.stderr.flush()
            os._exit(EXIT_CODES[signum])
        _state.received = signum
        _state.token.stop(SAID[signum])
        return
    raise Interrupted(signum)


@contextlib.contextmanager
def stopping_calibration(token: StopToken) -> Iterator[StopToken]:
    """The block of a calibration that checks `token`: a signal received meanwhile sets it, and
    its Interrupted is raised when the calibration ends cancelled (or as it ends)."""
    from ..core.errors import CalibrationCancelled

    _state.token, _state.received = token, None
    try:
        yield token
    except CalibrationCancelled:
        raise Interrupted(_state.received or signal.SIGINT) from None
    except Exception:  # a failure that came before the stop's check: the signal is the news
        if _state.received is not None:
            raise Interrupted(_state.received) from None
        raise
    finally:
        _state.token = None
    if _state.received is not None:  # came as the calibration returned: stop before the write
        raise Interrupted(_state.received)


@contextlib.contextmanager
def finishing_write() -> Iterator[None]:
    """The end of a write that signals wait for; the signal received meanwhile raised after it,
    as WrittenThenInterrupted: what was written is current."""
    _state.writing, _state.received = True, None
    try:
        yield
    finally:
        _state.writing = False
    if _state.received is not None:
        raise WrittenThenInterrupted(_state.received)


class WrittenThenInterrupted(Interrupted):
    """A signal that came while the result was written: the write was completed first."""
