"""The EuRoC pairs shipped with the tests (``tests/data/euroc_mini``) replayed through the command
line: ``swarm replay asl|bag`` in its own process, which starts the map server and the agent as
processes on loopback Zenoh (free ports)."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

from tests.support.paths import TEST_DATA

EUROC_MINI = TEST_DATA / "euroc_mini"
REPLAY_FRAMES = 3  # the fewest pairs whose map still shows the floor (tests/replay/test_asl.py)


def swarm_replay(args: list[str], out: Path, timeout: float = 300.0) -> float:
    """Run ``swarm replay ARGS --out OUT``; raise with its output unless it exits 0; the wall time (s)."""
    start = time.monotonic()
    done = subprocess.run(
        [sys.executable, "-m", "swarm.cli", "replay", *args, "--out", str(out)],
        capture_output=True, text=True, timeout=timeout,
    )  # fmt: skip
    if done.returncode != 0:
        raise AssertionError(
            f"swarm replay {' '.join(args)} exited {done.returncode}:\n{done.stdout}\n{done.stderr}"
        )
    return time.monotonic() - start
