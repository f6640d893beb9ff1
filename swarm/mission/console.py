"""Standard output that outlives its reader, for commands that run for minutes.

``swarm sim | tee log``: a Ctrl-C ends ``tee`` together with ``swarm sim``, and every later
line ``swarm sim`` prints, while it stops its roles and writes its run folder, would raise
``BrokenPipeError`` (and once more when Python exits). Within :func:`surviving_stdout` a
write to a standard output whose reader has gone goes nowhere instead; the command carries
on, and what it must still tell the user it says on stderr too.
"""

from __future__ import annotations

import io
import os
import sys
from collections.abc import Iterator
from contextlib import contextmanager


class SurvivingStdout(io.TextIOBase):
    """A text stream over ``stream`` that, once its pipe breaks, drops what is written to it."""

    def __init__(self, stream) -> None:
        self._stream = stream
        self.lost = False

    def write(self, text: str) -> int:
        if not self.lost:
            try:
                self._stream.write(text)
            except (BrokenPipeError, ValueError):
                self._lose()
        return len(text)

    def flush(self) -> None:
        if not self.lost:
            try:
                self._stream.flush()
            except (BrokenPipeError, ValueError):
                self._lose()

    def _lose(self) -> None:
        """From now on write nowhere; point the file descriptor at /dev/null, so that the
        interpreter's own flush at exit finds no broken pipe either."""
        self.lost = True
        try:
            fd = self._stream.fileno()
            null = os.open(os.devnull, os.O_WRONLY)
            os.dup2(null, fd)
            os.close(null)
        except (OSError, ValueError, io.UnsupportedOperation):
            pass

    def isatty(self) -> bool:
        return not self.lost and self._stream.isatty()

    def fileno(self) -> int:
        return self._stream.fileno()

    @property
    def encoding(self) -> str:
        return self._stream.encoding


@contextmanager
def surviving_stdout() -> Iterator[SurvivingStdout]:
    """``sys.stdout`` as a :class:`SurvivingStdout` for the block."""
    previous = sys.stdout
    wrapped = SurvivingStdout(previous)
    sys.stdout = wrapped
    try:
        yield wrapped
    finally:
        sys.stdout = previous
