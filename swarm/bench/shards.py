"""``swarm bench shards``: one map server beside a map service of two shards, same deltas.

For each configuration (1 shard, then 2), ``swarm server`` processes (WAL fsync on) on
loopback: shard 0 listens, the others connect to it; N agent sessions, each with one
signing publisher per shard (its own epoch there). Every delta of 2,000-20,000 voxels from
fused random rays on a 20 m x 10 m x 2 m grid at 0.1 m is split by owner
(``ShardLayout.split``) and each part goes to its shard. Throughput: every agent publishes
all its deltas back to back, resending what ``map/acks`` does not cover every 0.5 s, until
every shard's acks cover every part. Latency: each agent publishes one delta every
``period_s`` (random phase); a watcher polls every shard's ``map/acks``; a delta's
publish-to-acked time is that of its last part to be acked. Both configurations run on this
machine's cores: two shards on one host show the cost of the fan-out, not the gain of a
second host.
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
from swarm.bench.server import MISSION, VOXEL, WORKSPACE, make_deltas
from swarm.child_command import child_environment, swarm_argv
from swarm.map.grid import Grid
from swarm.map.sensor_model import SensorModel
from swarm.map.shard_layout import ShardLayout
from swarm.protocol import bus
from swarm.protocol.epochs import SigningPublisher
from swarm.protocol.wire import DeltaMessage


def _mission_yaml(agents: int, shards: int) -> str:
    (x0, y0, z0), (x1, y1, z1) = WORKSPACE
    robots = "\n".join(f"  - {{id: a{i + 1}, start: {{x: {1 + i}, y: 1}}}}" for i in range(agents))
    return (
        f"mission: {MISSION}\nworkspace: {{lo: [{x0}, {y0}, {z0}], hi: [{x1}, {y1}, {z1}], voxel: {VOXEL}}}\n"
        f"robots:\n{robots}\nmap_service: {{shards: {shards}}}\n"
    )


def _acks(session, prefix: str) -> dict:
    for reply in session.get(bus.key(prefix, "map", "acks"), timeout=2.0):
        if reply.ok is not None:
            return json.loads(reply.ok.payload.to_bytes())
    return {}


class _Service:
    """``shards`` server processes for the bench mission in ``workdir``."""

    def __init__(self, workdir: Path, agents: int, shards: int) -> None:
        config = workdir / f"mission-{shards}.yaml"
        config.write_text(_mission_yaml(agents, shards))
        grid = Grid.from_bounds(np.array(WORKSPACE[0]), np.array(WORKSPACE[1]), VOXEL)
        self.layout = ShardLayout.even(grid, shards)
        self.prefixes = [bus.shard_mission(MISSION, k, shards) for k in range(shards)]
        self.endpoint = bus.tcp_endpoint(bus.free_port())
        self.servers = []
        for k in range(shards):
            listen = self.endpoint if k == 0 else bus.tcp_endpoint(bus.free_port())
            cmd = swarm_argv("server", "--listen", listen, "--config", str(config))
            cmd += ["--store", str(workdir / f"store-{shards}-{k}")]
            cmd += ["--shard", str(k)] + ([] if k == 0 else ["--connect", self.endpoint])
            with open(workdir / f"server-{shards}-{k}.log", "w") as log:  # the child keeps its copy
                env = child_environment()
                self.servers.append(subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=env))
            if k == 0:
                time.sleep(0.5)

    def wait(self, probe, timeout: float = 60.0) -> None:
        deadline = time.monotonic() + timeout
        for prefix, server in zip(self.prefixes, self.servers, strict=True):
            while not any(r.ok is not None for r in probe.get(bus.key(prefix, "map", "acks"), timeout=1.0)):
                if server.poll() is not None or time.monotonic() > deadline:
                    raise RuntimeError(f"the map server {prefix} did not start (see the bench's server logs)")
                time.sleep(0.1)

    def parts(self, delta, robot: str, epochs: list[int], seqs: list[int]) -> list[tuple[int, int, bytes]]:
        """``(shard, seq, payload)`` of each part of ``delta`` (``seqs`` advanced per shard)."""
        out = []
        for k, part in self.layout.split(delta).items():
            seqs[k] += 1
            grid = self.layout.grid_of(k)
            msg = DeltaMessage(robot, epochs[k], seqs[k], 0.0, grid, part.idx, part.dlam, part.deta)
            out.append((k, seqs[k], msg.encode()))
        return out


def _figures(workdir: Path, deltas: list, agents: int, per_agent: int, shards: int, period_s: float) -> dict:
    service = _Service(workdir, agents, shards)
    sessions = []
    try:
        probe = bus.open_session(connect=[service.endpoint], wait_s=120)
        sessions.append(probe)
        service.wait(probe)
        for _ in range(agents):
            sessions.append(bus.open_session(connect=[service.endpoint]))
        pubs = [
            [SigningPublisher(s, prefix, f"a{a + 1}") for prefix in service.prefixes]
            for a, s in enumerate(sessions[1:])
        ]
        bus.wait_for_subscribers([p for row in pubs for p in row], timeout=10)
        pick = [[deltas[(a * 7 + n) % len(deltas)] for n in range(per_agent)] for a in range(agents)]

        def messages(a: int) -> tuple[list, list[int], list[int]]:
            epochs = [p.renew() for p in pubs[a]]
            seqs = [0] * shards
            # (each delta's parts, the epoch and the last seq on each shard)
            return [service.parts(d, f"a{a + 1}", epochs, seqs) for d in pick[a]], epochs, seqs

        # throughput: everything at once, resends of what a full inbox refused
        made = [messages(a) for a in range(agents)]
        t0 = time.perf_counter()

        def put_all(a: int) -> None:
            for parts in made[a][0]:
                for k, _seq, payload in parts:
                    pubs[a][k].put(payload)

        threads = [threading.Thread(target=put_all, args=(a,)) for a in range(agents)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        resent, last = 0, time.perf_counter()
        while True:
            acks = [_acks(probe, prefix) for prefix in service.prefixes]
            acked = {
                (a, k): int(acks[k].get(f"a{a + 1}", {}).get(str(made[a][1][k]), 0))
                for a in range(agents)
                for k in range(shards)
            }
            lagging = [(a, k, n) for (a, k), n in acked.items() if n < made[a][2][k]]
            if not lagging:
                break
            if time.perf_counter() - last > 0.5:
                for a, k, acked in lagging:
                    mine = [p for parts in made[a][0] for p in parts if p[0] == k]
                    for _k, _seq, payload in mine[acked : acked + 32]:
                        pubs[a][k].put(payload)
                        resent += 1
                last = time.perf_counter()
            time.sleep(0.005)
        elapsed = time.perf_counter() - t0
        updates = sum(len(d) for p in pick for d in p)
        latency = _paced(service, probe, pubs, pick, messages, period_s)
        return {
            "shards": shards,
            "deltas": agents * per_agent,
            "parts": sum(len(parts) for m in made for parts in m[0]),
            "voxel_updates": updates,
            "throughput_updates_s": updates / elapsed,
            "throughput_resent": resent,
            "paced_ms": {"p50": float(np.percentile(latency, 50)), "p99": float(np.percentile(latency, 99))},
        }
    finally:
        for server in service.servers[1:]:
            server.terminate()
        stop_server(service.servers[0], sessions, timeout=30)
        for server in service.servers[1:]:
            server.wait(timeout=30)


def _paced(service: _Service, probe, pubs, pick, messages, period_s: float) -> np.ndarray:
    """Milliseconds from each delta's publish to the acks covering its last part."""
    agents = len(pubs)
    made = [messages(a) for a in range(agents)]
    published: dict[tuple[int, int], tuple[float, list[tuple[int, int]]]] = {}
    phases = np.random.default_rng(1).uniform(0, period_s, agents)

    def agent(a: int) -> None:
        t0 = time.perf_counter() + phases[a]
        for n, parts in enumerate(made[a][0]):
            time.sleep(max(0.0, t0 + n * period_s - time.perf_counter()))
            published[(a, n)] = (time.perf_counter(), [(k, seq) for k, seq, _ in parts])
            for k, _seq, payload in parts:
                pubs[a][k].put(payload)

    threads = [threading.Thread(target=agent, args=(a,)) for a in range(agents)]
    for t in threads:
        t.start()
    seen: dict[tuple[int, int], float] = {}
    while len(seen) < sum(len(m[0]) for m in made):
        now = time.perf_counter()
        acks = [_acks(probe, prefix) for prefix in service.prefixes]
        for key, (_t, parts) in list(published.items()):
            a = key[0]
            if key not in seen and all(
                int(acks[k].get(f"a{a + 1}", {}).get(str(made[a][1][k]), 0)) >= seq for k, seq in parts
            ):
                seen[key] = now
        time.sleep(0.002)
    for t in threads:
        t.join()
    return np.array([(seen[k] - t) * 1e3 for k, (t, _) in published.items()])


def run(
    agents: int = 16, per_agent: int = 20, lo: int = 2000, hi: int = 20000, period_s: float = 0.5
) -> dict:
    """The figures of one server and of two shards (a temporary folder holds the stores)."""
    grid = Grid.from_bounds(np.array(WORKSPACE[0]), np.array(WORKSPACE[1]), VOXEL)
    deltas = make_deltas(grid, SensorModel(), 64, lo, hi, 0)
    with tempfile.TemporaryDirectory(
        prefix="swarm-bench-shards-", dir=os.environ.get("SWARM_BENCH_DIR")
    ) as tmp:
        runs = [_figures(Path(tmp), deltas, agents, per_agent, n, period_s) for n in (1, 2)]
    return {
        "agents": agents,
        "per_agent": per_agent,
        "grid_voxels": grid.size,
        "period_s": period_s,
        "runs": runs,
    }


def format_table(f: dict) -> str:
    lines = [
        f"{f['agents']} publishers x {f['per_agent']} deltas on {f['grid_voxels']:,} voxels, WAL fsync on",
        f"{'map service':>14} {'parts':>7} {'updates/s':>12} {'resent':>7} "
        f"{'ack p50 ms':>11} {'ack p99 ms':>11}",
    ]
    for r in f["runs"]:
        name = "1 server" if r["shards"] == 1 else f"{r['shards']} shards"
        lines.append(
            f"{name:>14} {r['parts']:>7} {r['throughput_updates_s']:>12,.0f} {r['throughput_resent']:>7} "
            f"{r['paced_ms']['p50']:>11.1f} {r['paced_ms']['p99']:>11.1f}"
        )
    lines.append(f"(paced: one delta per publisher every {f['period_s']:g} s; ack = every part covered)")
    return "\n".join(lines)
