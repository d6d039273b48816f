"""The core's Python `logging` records (loggers "densecalib" and "densecalib_ros") forwarded to
an rclpy logger, so an operator finds them in /rosout and ros2 launch's log files with the node's
own lines (they went to stderr only, or nowhere below WARNING)."""
from __future__ import annotations

import logging

CORE_LOGGERS = ("densecalib", "densecalib_ros")


class _ToRclpy(logging.Handler):
    def __init__(self, ros_logger):
        super().__init__(logging.INFO)
        self._ros_logger = ros_logger

    def emit(self, record: logging.LogRecord) -> None:
        try:
            text = record.getMessage()
            if record.levelno >= logging.ERROR:
                self._ros_logger.error(text)
            elif record.levelno >= logging.WARNING:
                self._ros_logger.warning(text)
            else:
                self._ros_logger.info(text)
        except Exception:  # a logging failure must not end a calibration
            self.handleError(record)


def forward_core_logs(ros_logger) -> logging.Handler:
    """Forward INFO and above of the core's loggers to `ros_logger` until `stop_forwarding`."""
    handler = _ToRclpy(ros_logger)
    for name in CORE_LOGGERS:
        logger = logging.getLogger(name)
        logger.addHandler(handler)
        if logger.getEffectiveLevel() > logging.INFO:
            logger.setLevel(logging.INFO)
    return handler


def stop_forwarding(handler: logging.Handler) -> None:
    for name in CORE_LOGGERS:
        logging.getLogger(name).removeHandler(handler)
