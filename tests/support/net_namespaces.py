"""What the multi-host tests share: ``ip`` commands, the skip when namespaces cannot be made,
a Zenoh config without shared memory or multicast, and waiting on role logs."""

from __future__ import annotations

import os
import shutil
import subprocess
import time
from collections.abc import Callable, Iterable
from pathlib import Path

import pytest

#: every process's Zenoh config: no shared memory (on one machine it would carry payloads
#: around the links under test), no multicast scouting (only the endpoints given)
NO_SHM = "{transport: {shared_memory: {enabled: false}}, scouting: {multicast: {enabled: false}}}\n"


def ip(*args: str) -> None:
    """Run ``ip ARGS`` (iproute2); CalledProcessError when it fails."""
    subprocess.run(["ip", *args], check=True, capture_output=True, timeout=10)


def require_namespaces() -> None:
    """Skip the test, with the reason, where network namespaces cannot be made."""
    if shutil.which("ip") is None or os.geteuid() != 0:
        pytest.skip("network namespaces need root and iproute2's ip")


def wait_for(condition: Callable[[], bool], timeout: float, what: str, logs: Iterable[Path]) -> None:
    """Poll ``condition`` every 0.2 s; AssertionError naming ``what`` with the logs' tails on timeout."""
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            tails = "\n".join(f"--- {p.name}\n{p.read_text()[-2000:]}" for p in logs)
            raise AssertionError(f"timed out waiting for {what}\n{tails}")
        time.sleep(0.2)
