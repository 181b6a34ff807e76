"""Python `logging` records of a core package (e.g. hv_driver's warnings) shown in a node's ROS log."""
from __future__ import annotations

import logging


class RosLogHandler(logging.Handler):
    """Forwards records to an rclpy logger at the matching severity."""

    def __init__(self, ros_logger):
        super().__init__()
        self._logger = ros_logger

    def emit(self, record: logging.LogRecord) -> None:
        text = self.format(record)
        # rclpy ties one severity to each calling line, hence one line per severity.
        if record.levelno >= logging.ERROR:
            self._logger.error(text)
        elif record.levelno >= logging.WARNING:
            self._logger.warning(text)
        else:
            self._logger.info(text)


def forward_logging(package: str, ros_logger) -> RosLogHandler:
    """Show ``package``'s log records in ``ros_logger``; returns the handler (remove it with ``stop_forwarding``)."""
    handler = RosLogHandler(ros_logger)
    logging.getLogger(package).addHandler(handler)
    return handler


def stop_forwarding(package: str, handler: RosLogHandler) -> None:
    logging.getLogger(package).removeHandler(handler)
