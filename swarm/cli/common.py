"""What every command shares: the error line users see."""

from __future__ import annotations

import sys


def fail(message: str) -> int:
    """Print ``swarm: error: MESSAGE`` on stderr; the exit status 2 of a user error."""
    print(f"swarm: error: {message}", file=sys.stderr)
    return 2
