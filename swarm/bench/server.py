"""``swarm bench server``: how fast the map server merges deltas, and how soon they show.

In process: voxel updates per second of the merge path on a 20 m x 10 m x 2 m grid at
0.1 m (400,000 voxels) with deltas of 2,000-20,000 voxels from fused random rays: the
apply alone (map + entropy cache), then with decoding and validation, then with the
write-ahead log fsynced per delta and per batch of 8 (the server's group commit).

Over Zenoh: ``swarm server`` as a separate process (WAL fsync on) and N agent sessions
on loopback, each publishing on its own ``delta/<rid>``. Throughput: every agent publishes
its deltas back to back, and resends what ``map/acks`` does not cover every 0.5 s (the
server's bounded inbox refuses what does not fit); time until ``map/acks`` covers all of
them. Latency: one watcher polls ``map/acks`` every millisecond; the time from a publish to
the first reply that covers it is the publish-to-query latency, measured with every agent
publishing at a steady pace (``period_s``), then saturated (each agent publishes as soon as
its previous delta is acked).
"""

from __future__ import annotations

import json
import os
import subprocess
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from swarm.bench import stop_server
from swarm.child_command import child_environment, swarm_argv
from swarm.map.fusion import batch_information
from swarm.map.grid import Grid
from swarm.map.sensor_model import SensorModel
from swarm.protocol import bus
from swarm.protocol.epochs import SigningPublisher
from swarm.protocol.wire import DeltaMessage

WORKSPACE = ((0.0, 0.0, 0.0), (20.0, 10.0, 2.0))
VOXEL = 0.1
MISSION = "benchserver"


def make_deltas(grid: Grid, sensor: SensorModel, count: int, lo: int, hi: int, seed: int = 0) -> list:
    """``count`` deltas of fused random rays (a robot at 0.4 m looking about), each of about
    ``lo``-``hi`` voxels (log-uniform targets)."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(count):
        target = int(np.exp(rng.uniform(np.log(lo), np.log(hi))))
        origin = np.array([rng.uniform(2, 18), rng.uniform(2, 8), 0.4])
        yaw = rng.uniform(0, 2 * np.pi)
        rays = max(target // 6, 50)
        while True:
            az = yaw + rng.uniform(-1.2, 1.2, rays)
            el = rng.uniform(-0.3, 0.3, rays)
            r = rng.uniform(1.0, 5.0, rays)
            d = np.stack([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)], axis=1)
            delta = batch_information(grid, sensor, origin, origin + d * r[:, None]).delta
            if len(delta) >= target or rays > 200_000:
                break
            rays = int(rays * 1.5)
        if len(delta) > target:
            keep = np.sort(rng.choice(len(delta), target, replace=False))
            delta = type(delta)(delta.idx[keep], delta.dlam[keep], delta.deta[keep])
        out.append(delta)
    return out


def _messages(grid: Grid, deltas: list, robot: str, epoch: int, first_seq: int = 1) -> list[bytes]:
    return [
        DeltaMessage(robot, epoch, first_seq + n, float(n), grid, d.idx, d.dlam, d.deta).encode()
        for n, d in enumerate(deltas)
    ]


# -- in process --------------------------------------------------------------------------


def merge_rates(grid: Grid, sensor: SensorModel, deltas: list, workdir: Path, repeat: int = 3) -> dict:
    """Voxel updates per second of each stage of the merge path (best of ``repeat``)."""
    from map_server.ledger import validate_delta
    from map_server.store import Store, StoreIdentity
    from map_server.team_map import MergedMap

    payloads = _messages(grid, deltas, "b1", 1)
    updates = sum(len(d) for d in deltas)
    msgs = [validate_delta(p, grid) for p in payloads]
    rates = {}

    def timed(name: str, body) -> None:  # best of `repeat`, each on a fresh map
        best = float("inf")
        for _ in range(repeat):
            team = MergedMap(grid, sensor)
            t0 = time.perf_counter()
            body(team)
            best = min(best, time.perf_counter() - t0)
        rates[name] = updates / best

    def apply_only(team) -> None:
        for m in msgs:
            team.admit(m)
            team.apply(m)

    def decode_apply(team) -> None:
        for p in payloads:
            m = validate_delta(p, grid)
            team.admit(m)
            team.apply(m)

    def with_wal(batch: int):
        def body(team) -> None:
            folder = Path(tempfile.mkdtemp(prefix=f"wal{batch}-", dir=workdir))
            store, _ = Store.open(folder, StoreIdentity(MISSION, grid, sensor))
            try:
                for i in range(0, len(payloads), batch):
                    chunk = payloads[i : i + batch]
                    ms = [validate_delta(p, grid) for p in chunk]
                    for m in ms:
                        team.admit(m)
                    store.append(chunk)
                    for m in ms:
                        team.apply(m)
            finally:
                store.close()

        return body

    timed("apply", apply_only)
    timed("decode_apply", decode_apply)
    timed("wal_fsync_each", with_wal(1))
    timed("wal_fsync_batch8", with_wal(8))
    return rates


# -- over Zenoh ----------------------------------------------------------------------------


def _mission_yaml(agents: int) -> str:
    (x0, y0, z0), (x1, y1, z1) = WORKSPACE
    robots = "\n".join(f"  - {{id: a{i + 1}, start: {{x: {1 + i}, y: 1}}}}" for i in range(agents))
    return (
        f"mission: {MISSION}\nworkspace: {{lo: [{x0}, {y0}, {z0}], hi: [{x1}, {y1}, {z1}], voxel: {VOXEL}}}\n"
        f"robots:\n{robots}\n"
    )


def _acks(session) -> dict | None:
    """The server's ``map/acks`` JSON, or None when it does not answer."""
    for reply in session.get(bus.key(MISSION, "map", "acks"), timeout=2.0):
        if reply.ok is not None:
            return json.loads(reply.ok.payload.to_bytes())
    return None


def _acked(session, robot: str, epoch: int) -> int:
    """The last contiguous acked seq of (robot, epoch); -1 when no server answers."""
    acks = _acks(session)
    return -1 if acks is None else int(acks.get(robot, {}).get(str(epoch), 0))


def _all_acked(session, agents: int, epoch: int, count: int) -> bool:
    acks = _acks(session) or {}
    return all(int(acks.get(f"a{a + 1}", {}).get(str(epoch), 0)) >= count for a in range(agents))


def open_agents(sessions: list, endpoint: str, agents: int) -> list:
    """Open ``agents`` sessions to ``endpoint`` (appended to ``sessions``, after the probe at
    index 0) and one reliable ``delta/a<i>`` publisher each, ready once the server subscribes."""
    for _ in range(agents):
        sessions.append(bus.open_session(connect=[endpoint]))
    pubs = [SigningPublisher(s, MISSION, f"a{i + 1}") for i, s in enumerate(sessions[1:])]
    bus.wait_for_subscribers(pubs, timeout=10)
    return pubs


def _renew(pubs: list, epoch: int) -> None:
    """Each agent asks the server for its next epoch: ``epoch`` on the bench's fresh store."""
    for pub in pubs:
        got = pub.renew()
        if got != epoch:
            raise RuntimeError(f"{pub.robot}: the server issued epoch {got}, expected {epoch}")


def _put_all(publisher, payloads: list[bytes]) -> None:
    for payload in payloads:
        publisher.put(payload)


class _AckWatch(threading.Thread):
    """Polls ``map/acks`` every millisecond on one session and notes when each (robot, seq) of
    ``epoch`` is first seen acked; agents may wait for their seq."""

    def __init__(self, session, epoch: int) -> None:
        super().__init__(daemon=True)
        self.session, self.epoch = session, epoch
        self.seen: dict[tuple[str, int], float] = {}
        self.acked: dict[str, int] = {}
        self.cond = threading.Condition()
        self.done = threading.Event()

    def run(self) -> None:
        while not self.done.is_set():
            acks = _acks(self.session) or {}
            now = time.perf_counter()
            with self.cond:
                for rid, by_epoch in acks.items():
                    last = int(by_epoch.get(str(self.epoch), 0))
                    for seq in range(self.acked.get(rid, 0) + 1, last + 1):
                        self.seen[(rid, seq)] = now
                    self.acked[rid] = max(last, self.acked.get(rid, 0))
                self.cond.notify_all()
            time.sleep(0.001)

    def wait(self, rid: str, seq: int) -> None:
        with self.cond:
            self.cond.wait_for(lambda: self.acked.get(rid, 0) >= seq, timeout=60)


def _latencies(grid: Grid, pick: list, pubs: list, probe, epoch: int, period_s: float | None) -> np.ndarray:
    """Seconds from publish to the first map/acks reply that covers it, for every delta of every
    agent: each agent publishes every ``period_s`` (random phase), or, with None, as soon as its
    previous delta is acked."""
    _renew(pubs, epoch)
    watch = _AckWatch(probe, epoch)
    watch.start()
    published: dict[tuple[str, int], float] = {}
    rng = np.random.default_rng(epoch)
    phases = rng.uniform(0, period_s or 0.0, len(pubs))

    def agent(a: int) -> None:
        rid = f"a{a + 1}"
        t0 = time.perf_counter() + phases[a]
        for seq, payload in enumerate(_messages(grid, pick[a], rid, epoch), start=1):
            if period_s is not None:
                time.sleep(max(0.0, t0 + (seq - 1) * period_s - time.perf_counter()))
            published[(rid, seq)] = time.perf_counter()
            pubs[a].put(payload)
            if period_s is None:
                watch.wait(rid, seq)

    threads = [threading.Thread(target=agent, args=(a,)) for a in range(len(pubs))]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    for rid, seq in published:
        watch.wait(rid, seq)
    watch.done.set()
    watch.join()
    return np.array([watch.seen[k] - t for k, t in published.items()])


def _percentiles(seconds: np.ndarray) -> dict:
    ms = seconds * 1e3
    return {"p50": float(np.percentile(ms, 50)), "p99": float(np.percentile(ms, 99)), "max": float(ms.max())}


def zenoh_figures(
    grid: Grid, deltas: list, agents: int, per_agent: int, workdir: Path, period_s: float = 0.25
) -> dict:
    """Throughput and publish-to-acked latency against a ``swarm server`` process."""
    endpoint = bus.tcp_endpoint(bus.free_port())
    config = workdir / "mission.yaml"
    config.write_text(_mission_yaml(agents))
    log_path = workdir / "server.log"
    store = workdir / "store"
    cmd = swarm_argv("server", "--listen", endpoint)
    cmd += ["--store", str(store), "--config", str(config)]
    with open(log_path, "w") as log_file:
        server = subprocess.Popen(cmd, stdout=log_file, stderr=subprocess.STDOUT, env=child_environment())
    sessions = []
    try:
        probe = bus.open_session(connect=[endpoint], wait_s=120)  # a loaded machine starts slowly
        sessions.append(probe)
        deadline = time.monotonic() + 30
        while _acked(probe, "a1", 0) < 0:
            if server.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(
                    f"the server did not start; see {log_path}:\n{log_path.read_text()[-2000:]}"
                )
            time.sleep(0.1)
        pubs = open_agents(sessions, endpoint, agents)
        pick = [[deltas[(a * 7 + n) % len(deltas)] for n in range(per_agent)] for a in range(agents)]

        # throughput: everything at once
        epoch = 1
        _renew(pubs, epoch)
        payloads = [_messages(grid, pick[a], f"a{a + 1}", epoch) for a in range(agents)]
        t0 = time.perf_counter()
        threads = [
            threading.Thread(target=_put_all, args=(p, ms)) for p, ms in zip(pubs, payloads, strict=True)
        ]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        # what a full inbox refused comes back as the agents resend it (every 0.5 s here)
        resent, last_resend = 0, time.perf_counter()
        while not _all_acked(probe, agents, epoch, per_agent):
            if time.perf_counter() - last_resend > 0.5:
                acks = _acks(probe) or {}
                for a in range(agents):
                    acked = int(acks.get(f"a{a + 1}", {}).get(str(epoch), 0))
                    for m in payloads[a][acked : acked + 32]:  # in order: the next seq is taken
                        pubs[a].put(m)
                        resent += 1
                last_resend = time.perf_counter()
            time.sleep(0.002)
        elapsed = time.perf_counter() - t0
        updates = sum(len(d) for p in pick for d in p)

        # latency, first at a steady pace below capacity, then saturated (one in flight each)
        paced = _latencies(grid, pick, pubs, probe, epoch=2, period_s=period_s)
        saturated = _latencies(grid, pick, pubs, probe, epoch=3, period_s=None)
        return {
            "agents": agents,
            "deltas": agents * per_agent,
            "voxel_updates": updates,
            "throughput_updates_s": updates / elapsed,
            "throughput_deltas_s": agents * per_agent / elapsed,
            "throughput_resent": resent,
            "period_s": period_s,
            "paced_ms": _percentiles(paced),
            "saturated_ms": _percentiles(saturated),
        }
    finally:
        stop_server(server, sessions, timeout=30)


def run(
    agents: int = 8,
    per_agent: int = 25,
    lo: int = 2000,
    hi: int = 20000,
    period_s: float = 0.25,
    seed: int = 0,
) -> dict:
    """All figures; a temporary folder holds the stores (on the system's temp file system)."""
    grid = Grid.from_bounds(np.array(WORKSPACE[0]), np.array(WORKSPACE[1]), VOXEL)
    sensor = SensorModel()
    deltas = make_deltas(grid, sensor, 64, lo, hi, seed)
    with tempfile.TemporaryDirectory(
        prefix="swarm-bench-server-", dir=os.environ.get("SWARM_BENCH_DIR")
    ) as tmp:
        tmp = Path(tmp)
        rates = merge_rates(grid, sensor, deltas, tmp)
        over = zenoh_figures(grid, deltas, agents, per_agent, tmp, period_s)
    return {
        "grid_voxels": grid.size,
        "delta_voxels_mean": float(np.mean([len(d) for d in deltas])),
        "delta_voxels_range": [min(len(d) for d in deltas), max(len(d) for d in deltas)],
        "tmpdir": tempfile.gettempdir(),
        "merge_rates": rates,
        "zenoh": over,
    }


def format_table(f: dict) -> str:
    r, z = f["merge_rates"], f["zenoh"]
    lo, hi = f["delta_voxels_range"]
    rows = [
        f"map server, {f['grid_voxels']:,}-voxel grid, deltas of {lo:,}-{hi:,} voxels "
        f"(mean {f['delta_voxels_mean']:,.0f}); store in {f['tmpdir']}",
        f"{'merge path (one thread, in process)':<48} {'voxel updates/s':>16}",
        f"{'  apply: map + entropy cache':<48} {r['apply'] / 1e6:>14.2f} M",
        f"{'  decode + validate + apply':<48} {r['decode_apply'] / 1e6:>14.2f} M",
        f"{'  + WAL append, fsync per delta':<48} {r['wal_fsync_each'] / 1e6:>14.2f} M",
        f"{'  + WAL append, fsync per 8 deltas':<48} {r['wal_fsync_batch8'] / 1e6:>14.2f} M",
        f"over Zenoh: swarm server process (WAL fsync on), {z['agents']} agent sessions on loopback",
        f"{'  throughput, all deltas at once':<48} {z['throughput_updates_s'] / 1e6:>14.2f} M "
        f"({z['throughput_deltas_s']:.0f} deltas/s, {z['deltas']} deltas, {z['throughput_resent']} resent)",
        _latency_row(f"  publish -> acked, each agent every {z['period_s']:g} s", z["paced_ms"]),
        _latency_row("  publish -> acked, 1 in flight per agent", z["saturated_ms"]),
    ]
    return "\n".join(rows)


def _latency_row(label: str, p: dict) -> str:
    return f"{label:<48} p50 {p['p50']:.1f} ms, p99 {p['p99']:.1f} ms, max {p['max']:.1f} ms"
