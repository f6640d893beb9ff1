"""Deltas for attack tests: a well-formed one from a team robot (good) and the same with one field
forged (tamper)."""

from __future__ import annotations

import msgpack
import numpy as np

from swarm.map.grid import Grid
from swarm.protocol.wire import DeltaMessage
from tests.support.map_server_mission import (
    EPOCH,
)


def good(grid: Grid, robot: str = "r1", seq: int = 1, idx=(3, 40, 41)) -> bytes:
    idx = np.asarray(idx, np.uint32)
    dlam = np.full(len(idx), 50.0, np.float32)
    return DeltaMessage(robot, EPOCH, seq, 1.0, grid, idx, dlam, dlam * 0.25).encode()


def tamper(payload: bytes, **changes) -> bytes:
    msg = msgpack.unpackb(payload, raw=False)
    for k, v in changes.items():
        if v is None:
            del msg[k]
        else:
            msg[k] = v
    return msgpack.packb(msg, use_bin_type=True)
