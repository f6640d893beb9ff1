"""A corridor mission for the coordinator's tests: its map, robot poses, a stand-in map server and
the coord/assign query."""

from __future__ import annotations

import itertools
import math
import time

import numpy as np

from map_server.snapshot_stream import MapStreams, StreamCache, held_snapshot
from swarm.config import mission_from_dict
from swarm.map.coverage_map import CoverageMap
from swarm.protocol import bus
from swarm.protocol.coord_client import assign_key, coordinator_stats
from swarm.protocol.map_chunks import CHUNK_BYTES
from swarm.protocol.wire import DeltaMessage, Pose, Snapshot, Status

MISSION = {
    "mission": "coordtest",
    "workspace": {"lo": [0.0, 0.0, 0.0], "hi": [8.0, 4.0, 1.0], "voxel": 0.1},
    "robots": [
        {"id": "r1", "start": {"x": 1.0, "y": 2.0}},
        {"id": "r2", "start": {"x": 1.4, "y": 2.0}},
        {"id": "r3", "start": {"x": 6.5, "y": 2.0}},
    ],
    "rig": {"camera_height": 0.4},
    "exploration": {"radius": 1.0},
}


POSES = {"r1": (1.0, 2.0), "r2": (1.4, 2.0), "r3": (6.5, 2.0)}


def mission(**coordination):
    data = dict(MISSION)
    if coordination:
        data["coordination"] = coordination
    return mission_from_dict(data)


def corridor_map(m, x_lo=0.3, x_hi=7.7) -> CoverageMap:
    """Known free columns (every layer) over a corridor y 1.5..2.5 m; the rest unknown."""
    cmap = CoverageMap(m.workspace.grid(), m.sensor.model())
    nx, ny, nz = cmap.grid.shape
    cx = (np.arange(nx) + 0.5) * 0.1
    cy = (np.arange(ny) + 0.5) * 0.1
    cols = ((cx >= x_lo) & (cx <= x_hi))[:, None] & ((cy >= 1.5) & (cy <= 2.5))[None, :]
    lam = cmap.lam.reshape(nx, ny, nz)
    eta = cmap.eta.reshape(nx, ny, nz)
    lam[cols] = 1.0 / 0.02**2
    eta[cols] = 0.0
    return cmap


def pose(robot: str) -> Pose:
    x, y = POSES[robot]
    return Pose((x, y, 0.4), (0.0, 0.0, 0.0))


# ---------------------------------------------------------------------------------------
# Over Zenoh
# ---------------------------------------------------------------------------------------
class MapServerStandIn:
    """A router with a real map/snapshot queryable, and a publisher on the merged stream."""

    def __init__(self, name: str, snapshot: Snapshot | None) -> None:
        self.endpoint = bus.tcp_endpoint(bus.free_port())
        self.session = bus.open_session(listen=[self.endpoint])
        self.merged = bus.reliable_publisher(self.session, bus.key(name, "merged"))
        self.status = {}
        self.name = name
        self._snap = None
        if snapshot is not None:  # streamed in chunks, as the map server answers it
            streams = MapStreams(StreamCache(), CHUNK_BYTES)
            self._snap = self.session.declare_queryable(
                bus.key(name, "map", "snapshot"),
                lambda q: streams.answer(q, lambda _q: held_snapshot(snapshot, 0, 0, CHUNK_BYTES)),
            )

    def publish_status(self, robot: str, target, state: str = "drive") -> None:
        if robot not in self.status:
            self.status[robot] = self.session.declare_publisher(bus.key(self.name, "robot", robot, "status"))
        self.status[robot].put(Status(robot, 0.0, pose(robot), target, state, 0).encode())

    def close(self) -> None:
        self.session.close()


def wait_until(condition, timeout: float = 10.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if condition():
            return True
        time.sleep(0.02)
    return condition()


def wait_until_answering(session, name: str, timeout: float = 20.0) -> None:
    """Wait until the coordinator of mission ``name`` answers ``session`` (its queryables'
    declarations have reached this session's router): a query asked before that finds no
    queryable and gets no reply."""
    deadline = time.monotonic() + timeout
    while coordinator_stats(session, name, timeout=1.0) is None:
        assert time.monotonic() < deadline, f"the coordinator of {name} did not answer in {timeout} s"
        time.sleep(0.05)


def query(session, name: str, payload: bytes, timeout: float = 5.0, robot: str = "r1"):
    """The one reply to ``payload`` asked on ``robot``'s key ``coord/assign/<robot>``."""
    replies = list(session.get(assign_key(name, robot), payload=payload, timeout=timeout))
    assert len(replies) == 1
    return replies[0]


FOOTPRINT = 2.0  # min(2 xi, max range)


def known_everywhere(m) -> CoverageMap:
    """Every voxel known and free: nothing left to explore."""
    cmap = corridor_map(m, 0.0, 8.0)
    cmap.lam[:] = cmap.lam.max()
    cmap.eta[:] = 0.0
    return cmap


def deltas_of(m, cmap: CoverageMap, robot: str, epoch: int, chunks: int) -> list[DeltaMessage]:
    """``cmap``'s information over the prior as ``chunks`` deltas of ``robot`` (seqs 1 ...)."""
    prior = CoverageMap(cmap.grid, cmap.sensor)
    idx = np.flatnonzero(cmap.lam != prior.lam)
    dlam = cmap.lam[idx].astype(np.float64) - prior.lam[idx]
    deta = cmap.eta[idx].astype(np.float64) - prior.eta[idx]
    parts = np.array_split(np.arange(len(idx)), chunks)
    return [
        DeltaMessage(robot, epoch, seq, 0.0, cmap.grid, idx[p], dlam[p], deta[p])
        for seq, p in enumerate(parts, start=1)
    ]


def far_apart(targets: list[tuple[float, ...]], radius: float) -> bool:
    """Whether every two targets stand at least ``radius`` apart (x-y, m)."""
    return all(math.dist(a[:2], b[:2]) >= radius for a, b in itertools.combinations(targets, 2))
