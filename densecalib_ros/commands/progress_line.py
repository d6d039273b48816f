"""A calibration on a terminal: one updating line per stage (tqdm), each with the time left for the
whole run; only warnings and errors of the log above them. With -v, or where stderr is not a
terminal (piped, redirected, CI), the full log instead (the core logs every event once)."""
from __future__ import annotations

import contextlib
import logging
import os
import sys
import threading
from typing import Iterator, Optional

from ..core.progress import Progress, ProgressState, StopToken

# How often the line redraws its clock while a stage has no step to count (seconds): a person
# sees it move; the calibration is not slowed by it.
REFRESH_S = 1.0
# A terminal that gives no size (a pseudo-terminal no one sized) gets that of a classic one.
DEFAULT_SIZE = (100, 24)


class ProgressLine:
    """Draws a Progress's stages on `stream`: a line per stage, updated in place, left behind
    finished when the next stage begins."""

    def __init__(self, stream=None) -> None:
        self._stream = stream or sys.stderr
        self._bar = None
        self._stage: Optional[str] = None
        self._lock = threading.Lock()
        self._progress: Optional[Progress] = None
        self._stopped = threading.Event()
        self._clock = threading.Thread(target=self._tick, name="densecalib-progress",
                                       daemon=True)

    def attach(self, progress: Progress) -> None:
        self._progress = progress
        self._clock.start()

    def on_stage(self, state: ProgressState) -> None:
        with self._lock:
            if state.stage != self._stage or self._bar is None:
                self._new_bar(state)
            self._draw(state)

    def close(self) -> None:
        self._stopped.set()
        with self._lock:
            if self._bar is not None:
                self._bar.close()
                self._bar = None

    def write(self, text: str) -> None:
        """A log line above the bar, the bar drawn again below it."""
        from tqdm import tqdm

        with self._lock:
            tqdm.write(text, file=self._stream)

    def _new_bar(self, state: ProgressState) -> None:
        from tqdm import tqdm

        if self._bar is not None:
            self._bar.n = self._bar.total  # a stage begun ends the one before
            self._bar.close()
        self._stage = state.stage
        columns, rows = _size(self._stream)
        self._bar = tqdm(total=1000, file=self._stream, leave=True, ncols=columns, nrows=rows,
                         bar_format="{desc} {bar}{postfix}", mininterval=0.2)

    def _draw(self, state: ProgressState) -> None:
        self._bar.set_description_str(f"{state.label:<34.34}", refresh=False)
        steps = f"{state.stage_done}/{state.stage_total}, " if state.stage_total > 1 else ""
        left = "" if state.seconds_left is None else f", about {_duration(state.seconds_left)} left"
        self._bar.set_postfix_str(f"{steps}{_duration(state.elapsed_s)}{left}", refresh=False)
        self._bar.n = int(round(1000 * state.stage_fraction))
        self._bar.refresh()

    def _tick(self) -> None:
        while not self._stopped.wait(REFRESH_S):
            with self._lock:
                if self._bar is not None and self._progress is not None:
                    self._draw(self._progress.state())


def _size(stream) -> tuple[int, int]:
    """The terminal's (columns, rows); DEFAULT_SIZE where it gives none (a pseudo-terminal no one
    sized says 0 x 0, and tqdm draws nothing on a terminal of no rows)."""
    try:
        size = os.get_terminal_size(stream.fileno())
    except (OSError, ValueError, AttributeError):
        return DEFAULT_SIZE
    return (size.columns if size.columns > 0 else DEFAULT_SIZE[0],
            size.lines if size.lines > 0 else DEFAULT_SIZE[1])


def _duration(seconds: float) -> str:
    seconds = max(0, int(round(seconds)))
    return f"{seconds // 60} min {seconds % 60:02d} s" if seconds >= 60 else f"{seconds} s"


class _AboveTheLine(logging.Handler):
    """Log records written above the progress line (tqdm.write), in the log's format."""

    def __init__(self, line: ProgressLine, formatter: Optional[logging.Formatter]) -> None:
        super().__init__(logging.WARNING)
        self._line = line
        self.setFormatter(formatter)

    def emit(self, record: logging.LogRecord) -> None:
        try:
            self._line.write(self.format(record))
        except Exception:  # noqa: BLE001 - logging must never stop the calibration
            self.handleError(record)


@contextlib.contextmanager
def terminal_progress(verbose: bool, stop: Optional[StopToken] = None,
                      stream=None) -> Iterator[Progress]:
    """A Progress with the stop token `stop`: drawn as ProgressLine on a terminal, the console
    log above it at WARNING; with `verbose`, or where `stream` (stderr) is no terminal, the full
    log as configured and no line."""
    stream = stream or sys.stderr
    if verbose or not stream.isatty():
        yield Progress(stop=stop)
        return
    root = logging.getLogger()
    console = [h for h in root.handlers if getattr(h, "stream", None) is stream]
    line = ProgressLine(stream)
    above = _AboveTheLine(line, console[0].formatter if console else None)
    for handler in console:
        root.removeHandler(handler)
    root.addHandler(above)
    progress = Progress(on_stage=line.on_stage, stop=stop)
    line.attach(progress)
    try:
        yield progress
    finally:
        line.close()
        root.removeHandler(above)
        for handler in console:
            root.addHandler(handler)
