"""The map server's bounds without Zenoh: an honest office mission fits the information bound,
the ledger stays bounded, and hostile payloads interleaved with valid deltas (Hypothesis) never
stop a valid one from being applied exactly once."""

from __future__ import annotations

import math

import msgpack
import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from map_server.admission import Admission
from map_server.epochs import EpochRegistry
from map_server.ledger import Rejected, validate_delta
from map_server.limits import InformationBucket, mission_bounds, ray_information_bound
from map_server.team_map import MergedMap
from robot_agent.explorer import Explorer
from robot_agent.sharing import DeltaOutbox
from sim2d.simulator import Simulator
from swarm.config import load_mission
from swarm.map.sensor_model import SensorModel
from swarm.protocol import bus
from swarm.protocol.epochs import delta_mac
from swarm.protocol.wire import DeltaMessage
from tests.support.malformed_deltas import good
from tests.support.map_server_mission import EPOCH, encode_all, robot_batches, signed, small_mission


def test_ray_bound_covers_the_fusion_of_single_rays():
    """I_ray against batch_information of single rays at many ranges and directions (the oracle)."""
    from swarm.map.fusion import batch_information

    mission = small_mission()
    grid, sensor = mission.workspace.grid(), SensorModel()
    bound = ray_information_bound(sensor, grid.voxel)
    rng = np.random.default_rng(3)
    origin = np.array([0.05, 0.05, 0.05])
    worst = 0.0
    for _ in range(300):
        direction = rng.normal(size=3)
        direction = np.abs(direction) / np.linalg.norm(direction)
        d = rng.uniform(0.05, sensor.max_range)
        point = origin + direction * d
        if not grid.contains_point(point):
            continue
        delta = batch_information(grid, sensor, origin, point[None]).delta
        worst = max(worst, float(np.sum(delta.dlam, dtype=np.float64)))
    assert 0 < worst <= bound


def test_office_deltas_fit_the_bound():
    """Real frames of the office (stereo, 4 robots driven by their explorers): every frame's
    information and every shared delta is within the bound; none is refused."""
    mission = load_mission("configs/office.yaml")
    bounds = mission_bounds(mission)
    buckets = {rid: InformationBucket(bound, 0.0) for rid, bound in bounds.items()}
    team = MergedMap(mission.workspace.grid(), mission.sensor.model())
    session = bus.open_session(listen=[bus.tcp_endpoint(bus.free_port())])
    try:
        sim = Simulator(mission, session)
        robots = mission.robot_ids[:2]
        explorers = {rid: Explorer(mission, rid) for rid in robots}
        outboxes = {
            rid: DeltaOutbox(ex.grid.size, mission.sharing.share_min_bits, ex.table)
            for rid, ex in explorers.items()
        }
        frames, worst = 12, 0.0
        for n in range(frames):
            for rid in robots:
                ex = explorers[rid]
                frame = sim.make_frame(rid)
                delta = ex.fuse(frame)
                worst = max(worst, float(np.sum(delta.dlam, dtype=np.float64)) / bounds[rid].per_frame)
                outboxes[rid].add(delta)
                decision = ex.decide(frame.pose.xyz[0], frame.pose.xyz[1], frame.pose.ypr[0])
                sim.world.command(rid, decision.v, decision.omega)
                taken = outboxes[rid].take(ex.map.lam, ex.map.eta, flush=n == frames - 1)
                if taken is not None:
                    seq, d = taken
                    msg = DeltaMessage(rid, EPOCH, seq, frame.t, ex.grid, d.idx, d.dlam, d.deta)
                    msg = validate_delta(msg.encode(), team.grid, rid)  # honest: never refused
                    # all at one instant of the server's clock: the burst alone holds them
                    information = float(np.sum(msg.dlam, dtype=np.float64))
                    assert buckets[rid].refusal(information, 0.0) is None
                    buckets[rid].charge(information)
                    assert team.admit(msg)
                    team.apply(msg)
            sim.world.step(mission.sim.frame_period_s)
    finally:
        session.close()
    assert 0 < worst < 1.0
    assert len(team.ledger) >= len(robots)
    print(f"largest frame information / I_frame = {worst:.2e}")


def bare_admission(team: MergedMap, mission, **options) -> Admission:
    """The server's admission of deltas on ``team`` without a server: epochs kept in memory."""
    import logging
    import threading

    from swarm.log_limit import LogLimiter

    settings = {
        "robots": frozenset(mission.robot_ids),
        "takes_prior": False,
        "robot_pattern": None,
        "max_pattern_robots": 0,
        "bounds": mission_bounds(mission),
        "quarantine_after": 3,
        "quarantine": team.quarantine,
        "peer_log": LogLimiter(logging.getLogger("test")),
    } | options
    return Admission(team, threading.Lock(), EpochRegistry(None), **settings)


def _hostile():
    """Payloads of any shape: random bytes, random msgpack values, and valid deltas with one
    field replaced by a random value."""
    scalars = st.one_of(
        st.none(),
        st.booleans(),
        st.integers(-(2**63), 2**64 - 1),
        st.floats(),
        st.text(max_size=8),
        st.binary(max_size=16),
    )

    def containers(inner):
        return st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=6), inner, max_size=4)

    values = st.recursive(scalars, containers, max_leaves=12)
    fields = st.sampled_from(["v", "robot", "epoch", "seq", "t", "grid", "idx", "dlam", "deta"])
    tampered = st.tuples(fields, values).map(lambda fv: (fv[0], fv[1]))
    return st.one_of(
        st.binary(max_size=64).map(lambda b: ("raw", b)),
        values.map(lambda v: ("value", v)),
        tampered.map(lambda fv: ("field", fv)),
    )


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(_hostile(), min_size=1, max_size=8), st.randoms(use_true_random=False))
def test_hostile_payloads_never_touch_the_valid_deltas(hostile, rnd):
    mission = small_mission()
    grid, sensor = mission.workspace.grid(), mission.sensor.model()
    valid = encode_all(grid, robot_batches(grid, sensor, robots=2, per_robot=2, rays=30, seed=1))
    bad = []
    for kind, value in hostile:
        if kind == "raw":
            bad.append(value)
        elif kind == "value":
            bad.append(msgpack.packb(value, use_bin_type=True))
        else:
            msg = msgpack.unpackb(good(grid, robot="r1", seq=99), raw=False)
            msg[value[0]] = value[1]
            bad.append(msgpack.packb(msg, use_bin_type=True))
    team = MergedMap(grid, sensor)
    admission = bare_admission(team, mission)
    keys = {rid: admission.issue(rid).key for rid in ("r1", "r2")}
    # the valid deltas in their order (each robot's seqs in turn), the hostile ones anywhere
    stream = [(rid, p, delta_mac(keys[rid], p)) for rid, _, p in valid]
    for payload in bad:
        mac = rnd.choice([None, b"", delta_mac(keys["r1"], payload)[:8], bytes(16)])
        stream.insert(rnd.randrange(len(stream) + 1), ("r1", payload, mac))
    applied = []
    for rid, payload, mac in stream:
        try:
            msg = admission.admit(rid, payload, mac)
            if msg is not None:
                team.apply(msg)
                admission.applied(msg)
                applied.append(payload)
        except Rejected as exc:
            assert exc.kind != "internal_error", exc
    valid_payloads = {p for _, _, p in valid}
    assert valid_payloads <= set(applied)  # every valid delta applied, exactly once
    assert len(applied) == len(set(applied))
    assert np.all(np.isfinite(team.cmap.lam)) and np.all(np.isfinite(team.cmap.eta))
    assert math.isfinite(team.entropy.total)


def test_inbox_is_bounded_per_robot_and_served_in_turn():
    from map_server.inbox import Inbox

    inbox = Inbox(max_messages=3, max_bytes=10)
    assert [inbox.offer("a", b"1234") for _ in range(4)] == [
        True,
        True,
        False,
        False,
    ]  # 8 bytes, then 12 > 10
    assert inbox.offer("b", b"x") and inbox.offer("b", b"y")
    assert [r for r, *_ in inbox.take(10, timeout=0.1)] == ["a", "b", "a", "b"]
    assert inbox.take(10, timeout=0.01) == []
    stats = inbox.stats()
    assert stats["refused"] == {"a": 2} and stats["high_water"] == 4 and stats["queued"] == 0


def test_a_previous_map_comes_on_delta_prior_only_when_the_mission_has_one(tmp_path):
    """delta/prior (the runner's previous map) is taken without the rig bound, its mean checked
    on the resulting voxel; a mission without prior_map refuses it as an unknown robot."""
    import yaml

    from map_server.server import MapServer
    from swarm.config import mission_from_dict
    from swarm.map.coverage_map import prior_information
    from swarm.protocol.map_messages import PRIOR_SOURCE
    from tests.support.map_server_mission import MISSION_YAML

    plain = small_mission()
    (tmp_path / "previous.npz").write_bytes(b"")  # only its name matters to the server
    with_prior = mission_from_dict(
        {**yaml.safe_load(MISSION_YAML), "prior_map": "previous.npz"}, base_dir=tmp_path
    )
    grid, sensor = plain.workspace.grid(), plain.sensor.model()
    lam0, eta0 = prior_information(sensor)
    idx = np.arange(grid.size, dtype=np.uint32)
    dlam = np.full(grid.size, 1e6 - lam0, np.float32)  # certain, empty: far over any rig's bound
    deta = np.full(grid.size, -eta0, np.float32)  # negative: fine for a previous map's delta
    payload = DeltaMessage(PRIOR_SOURCE, EPOCH, 1, 0.0, grid, idx, dlam, deta).encode()
    assert not MapServer(plain, tmp_path / "a").accepts_robot(PRIOR_SOURCE)
    server = MapServer(with_prior, tmp_path / "b")
    assert server.accepts_robot(PRIOR_SOURCE)
    assert server.merge(signed(server, [(PRIOR_SOURCE, 1, payload)])) == 1
    assert server.team.known == grid.size
    bad = DeltaMessage(PRIOR_SOURCE, EPOCH, 2, 0.0, grid, idx[:1], dlam[:1], -dlam[:1]).encode()
    assert server.merge(signed(server, [(PRIOR_SOURCE, 2, bad)])) == 0  # would leave a negative mean
    assert server.stats()["rejected"]["mean_outside_unit"] == 1
    server.stop()
    again = MapServer(with_prior, tmp_path / "b")  # and it survives a restart (snapshot + log)
    assert again.team.known == grid.size
    again.stop()
