"""A small office mission, its robots' delta batches and a running map server on loopback Zenoh:
the pieces the map-server tests (and the roles' tests that need a server) share."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import yaml

from map_server.options import ServerOptions
from map_server.server import MapServer
from swarm.config import Mission, mission_from_dict
from swarm.map.coverage_map import CoverageMap
from swarm.map.delta import Delta
from swarm.map.fusion import batch_information
from swarm.map.grid import Grid
from swarm.map.sensor_model import SensorModel
from swarm.protocol import bus
from swarm.protocol.epochs import EpochGrant, EpochRefused, delta_mac, put_delta, wait_for_epoch
from swarm.protocol.map_client import MapClient
from swarm.protocol.wire import DeltaMessage

MISSION_YAML = """
mission: srvtest
workspace: {lo: [0.0, 0.0, 0.0], hi: [3.0, 2.0, 1.0], voxel: 0.1}
robots:
  - {id: r1, start: {x: 0.5, y: 0.5}}
  - {id: r2, start: {x: 2.5, y: 1.5}}
  - {id: r3, start: {x: 1.5, y: 1.0}}
"""


#: the first epoch a fresh store issues to each robot (map_server.epochs)
EPOCH = 1


def small_mission() -> Mission:
    return mission_from_dict(yaml.safe_load(MISSION_YAML))


def robot_batches(
    grid: Grid, sensor: SensorModel, robots: int = 3, per_robot: int = 6, rays: int = 120, seed: int = 0
) -> dict[str, list[Delta]]:
    """Each robot's deltas: batches of random rays from random positions inside the grid."""
    rng = np.random.default_rng(seed)
    out: dict[str, list[Delta]] = {}
    for r in range(robots):
        deltas = []
        for _ in range(per_robot):
            origin = rng.uniform(grid.lo + 0.3, grid.hi - 0.3)
            points = rng.uniform(grid.lo, grid.hi - 1e-6, size=(rays, 3))
            deltas.append(batch_information(grid, sensor, origin, points).delta)
        out[f"r{r + 1}"] = deltas
    return out


def encode_all(
    grid: Grid, batches: dict[str, list[Delta]], epoch: int = EPOCH
) -> list[tuple[str, int, bytes]]:
    """``(robot, seq, payload)`` of every delta, seqs 1, 2, ... per robot."""
    return [
        (rid, seq, DeltaMessage(rid, epoch, seq, float(seq), grid, d.idx, d.dlam, d.deta).encode())
        for rid, deltas in batches.items()
        for seq, d in enumerate(deltas, start=1)
    ]


def signed(server: MapServer, sent, epoch: int = EPOCH) -> list[tuple[str, bytes, bytes]]:
    """``(robot, payload, MAC)`` of ``(robot, seq, payload)`` items, for :meth:`MapServer.merge`:
    the server issues its robots epochs up to ``epoch`` first where it has not yet."""
    keys = {}
    for rid, _, _payload in sent:
        if rid not in keys:
            keys[rid] = server.admission.registry.key_of(rid, epoch)
            while keys[rid] is None:
                grant = server.admission.issue(rid)
                assert grant.epoch <= epoch, f"{rid} is past epoch {epoch}"
                keys[rid] = grant.key if grant.epoch == epoch else None
    return [(rid, payload, delta_mac(keys[rid], payload)) for rid, _, payload in sent]


def central_fusion(grid: Grid, sensor: SensorModel, batches: dict[str, list[Delta]]) -> CoverageMap:
    """One map that fuses every robot's batches once, robot by robot."""
    cmap = CoverageMap(grid, sensor)
    for deltas in batches.values():
        for d in deltas:
            cmap.apply(d)
    return cmap


def assert_maps_equal(lam: np.ndarray, eta: np.ndarray, cmap: CoverageMap) -> None:
    """Equal to float32 rounding (the order of the sums differs)."""
    np.testing.assert_allclose(lam, cmap.lam, rtol=2e-6, atol=0)
    np.testing.assert_allclose(eta, cmap.eta, rtol=2e-6, atol=1e-6)


def wait_until(condition: Callable[[], bool], timeout: float, what: str) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        if time.monotonic() > deadline:
            raise AssertionError(f"timed out after {timeout} s waiting for {what}")
        time.sleep(0.02)


@contextmanager
def running_server(
    mission: Mission, store: Path, options: ServerOptions | None = None
) -> Iterator[tuple[MapServer, str]]:
    """A map server in this process, listening on a free loopback port."""
    endpoint = bus.tcp_endpoint(bus.free_port())
    server = MapServer(mission, store, options=options)
    session = bus.open_session(listen=[endpoint])
    server.start(session)
    try:
        yield server, endpoint
    finally:
        server.stop()
        session.close()


@contextmanager
def client_session(endpoint: str):
    session = bus.open_session(connect=[endpoint])
    try:
        yield session
    finally:
        session.close()


class SignedPublisher:
    """A robot's ``delta/<rid>`` publisher that attaches each payload's MAC under its grant."""

    def __init__(self, session, mission: str, grant: EpochGrant) -> None:
        self.grant = grant
        self.pub = bus.reliable_publisher(session, bus.key(mission, "delta", grant.robot))

    def put(self, payload: bytes) -> None:
        put_delta(self.pub, self.grant, payload)

    @property
    def matching_status(self):  # for bus.wait_for_subscribers
        return self.pub.matching_status


class UnsignedPublisher:
    """``delta/<rid>`` of a robot the server issues no epoch to: payloads go without a MAC."""

    grant = None

    def __init__(self, session, mission: str, robot: str) -> None:
        self.pub = bus.reliable_publisher(session, bus.key(mission, "delta", robot))

    def put(self, payload: bytes) -> None:
        self.pub.put(payload)


def publishers(session, mission: str, robots, grants: dict | None = None) -> dict:
    """A :class:`SignedPublisher` per robot, under ``grants`` or epochs the server issues now
    (an :class:`UnsignedPublisher` for a robot it refuses an epoch)."""
    if grants is None:
        grants = {}
        for rid in robots:
            try:
                grants[rid] = wait_for_epoch(session, mission, rid, 30)
            except EpochRefused:
                pass
    pubs = {
        rid: SignedPublisher(session, mission, grants[rid])
        if rid in grants
        else UnsignedPublisher(session, mission, rid)
        for rid in robots
    }
    assert bus.wait_for_subscribers([p.pub for p in pubs.values()], timeout=10.0)
    return pubs


def resend_until_acked(client: MapClient, pubs: dict, by_robot: dict, timeout: float = 30.0) -> None:
    """What an agent does: send each robot's unacked payloads again, in seq order, until acked."""
    deadline = time.monotonic() + timeout
    while True:
        acks = client.acks()
        left = {r: acks.get(r, {}).get(pubs[r].grant.epoch, 0) for r in by_robot}
        if all(left[r] >= len(by_robot[r]) for r in by_robot):
            return
        assert time.monotonic() < deadline, f"not all acked: {left}"
        for rid, payloads in by_robot.items():
            for payload in payloads[left[rid] :]:
                pubs[rid].put(payload)
        time.sleep(0.3)


def all_acked(client: MapClient, expected: dict[str, int], epoch: int = EPOCH) -> bool:
    acks = client.acks()
    return all(acks.get(rid, {}).get(epoch, 0) >= n for rid, n in expected.items())


def delta_publisher(session, mission: str, rid: str) -> SignedPublisher:
    """``delta/<rid>`` under an epoch the server issues now (EPOCH on a fresh store)."""
    pub = SignedPublisher(session, mission, wait_for_epoch(session, mission, rid, 30))
    assert bus.wait_for_subscribers([pub.pub], timeout=10.0)
    return pub
