"""Capturing a logger's lines in a test, and what a rate-limited log may write meanwhile."""

from __future__ import annotations

import logging
import time


class LogLines(logging.Handler):
    """The log lines of one logger (``lines``: their messages), while in a ``with`` block."""

    def __init__(self, name: str) -> None:
        super().__init__(logging.DEBUG)
        self.logger, self.lines = logging.getLogger(name), []

    def emit(self, record: logging.LogRecord) -> None:
        self.lines.append(record.getMessage())

    def __enter__(self):
        self.logger.addHandler(self)
        self.logger.setLevel(logging.DEBUG)
        return self

    def __exit__(self, *exc) -> None:
        self.logger.removeHandler(self)


def allowed_lines(since: float) -> int:
    """Lines of one reason a 10 s limiter may write from ``since`` (time.monotonic()) to now."""
    return 1 + int((time.monotonic() - since) / 10.0)
