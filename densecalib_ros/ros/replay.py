"""Replay of a rosbag2 bag's image topics into the running node (no rosbag2_py needed).

Messages are read with `rosbags` (core.io.bag.iter_image_messages) in bag order and handed to the
node's intake (the same synchroniser the subscriptions feed) with their header stamps, paced by
the bag's log times divided by `rate` (0 = as fast as possible), in a background thread.
"""
from __future__ import annotations

import threading
import time
from typing import Callable, Optional

from ..core.errors import CalibrationError
from ..core.io.bag import iter_image_messages


class BagReplayer:
    """Replays `topics` of the bag at `bag_path`: deliver(topic index, stamp ns, message) per
    message, then on_done(number of messages, error message or None)."""

    def __init__(self, bag_path: str, topics: list[str],
                 deliver: Callable[[int, int, object], None], *, rate: float = 0.0,
                 on_done: Optional[Callable[[int, Optional[str]], None]] = None, logger=None):
        self.bag_path, self.topics, self.rate = bag_path, list(topics), float(rate)
        self._deliver, self._on_done, self._logger = deliver, on_done, logger
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self.run, name="densecalib-replay", daemon=True)

    def start(self) -> None:
        self._thread.start()

    def stop(self, timeout_s: float = 5.0) -> None:
        self._stop.set()
        if self._thread.is_alive() and self._thread is not threading.current_thread():
            self._thread.join(timeout_s)

    def run(self) -> int:
        """Replay in the calling thread; returns the number of messages delivered."""
        count, error = 0, None
        if self._logger:
            self._logger.info(f"replaying {self.topics} from {self.bag_path}")
        try:
            first_log_ns, wall_start = None, time.monotonic()
            for stream, stamp, log_ns, _, msg in iter_image_messages(self.bag_path, self.topics):
                if self._stop.is_set():
                    break
                if self.rate > 0:
                    first_log_ns = log_ns if first_log_ns is None else first_log_ns
                    delay = (log_ns - first_log_ns) / 1e9 / self.rate - (time.monotonic()
                                                                         - wall_start)
                    if delay > 0 and self._stop.wait(delay):
                        break
                self._deliver(stream, stamp, msg)
                count += 1
        except CalibrationError as exc:
            error = str(exc)
            if self._logger:
                self._logger.error(f"replay of {self.bag_path} failed: {error}")
        if self._on_done is not None and not self._stop.is_set():
            self._on_done(count, error)
        return count
