"""``swarm bench soak``: a map server over mutual TLS and access control under a steady team load.

A ``swarm server`` process listens on a loopback TLS endpoint with the rules ``swarm security
init`` writes; ``agents`` sessions, each holding its own agent certificate, publish one delta of
``voxels`` voxels every ``period_s`` (staggered) for ``minutes``; a ``tool`` session polls
``map/acks`` (through the trusted-reply check) every 20 ms. Printed each minute: the server's
resident memory (``/proc/<pid>/status`` VmRSS), its CPU use (``/proc/<pid>/stat`` user+system
time over wall time, 100 % = one core), deltas acked, and the publish-to-ack latency p50/p99
(resolution: the 20 ms poll). Nothing is asserted: these are figures to read.
"""

from __future__ import annotations

import os
import subprocess
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from swarm.bench import stop_server
from swarm.bench.server import MISSION, VOXEL, WORKSPACE, _messages, _mission_yaml, make_deltas
from swarm.child_command import child_environment, swarm_argv
from swarm.map.grid import Grid
from swarm.map.sensor_model import SensorModel
from swarm.protocol import bus
from swarm.protocol.epochs import SigningPublisher
from swarm.protocol.map_client import MapClient, MapQueryError, MapServerUnavailable
from swarm.security.access_rules import TOOL, agent_name
from swarm.security.team_setup import init_team

POLL_S = 0.02
EPOCH = 1


def _rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def _cpu_s(pid: int) -> float:
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


class _Team:
    """Agents publishing on a schedule and a watcher noting when each (agent, seq) is acked."""

    def __init__(self, sessions: list, grid: Grid, deltas: list, period_s: float) -> None:
        self.pubs = [SigningPublisher(s, MISSION, f"a{i + 1}") for i, s in enumerate(sessions)]
        for pub in self.pubs:  # the first epoch a fresh store issues
            if pub.renew() != EPOCH:
                raise RuntimeError(f"{pub.robot}: the server issued another epoch than {EPOCH}")
        self.grid, self.deltas, self.period_s = grid, deltas, period_s
        self.sent: dict[tuple[str, int], float] = {}
        self.latencies: list[tuple[float, float]] = []  # (ack time, latency s)
        self.acked: dict[str, int] = {}
        self.refused = 0
        self.lock = threading.Lock()

    def publish_until(self, stop_at: float) -> None:
        agents = len(self.pubs)
        seq = 0
        start = time.monotonic()
        while time.monotonic() < stop_at:
            seq += 1
            for a, pub in enumerate(self.pubs):
                due = start + (seq - 1) * self.period_s + a * self.period_s / agents
                time.sleep(max(0.0, due - time.monotonic()))
                rid = f"a{a + 1}"
                delta = self.deltas[(a * 7 + seq) % len(self.deltas)]
                (payload,) = _messages(self.grid, [delta], rid, EPOCH, first_seq=seq)
                with self.lock:
                    self.sent[(rid, seq)] = time.monotonic()
                pub.put(payload)

    def watch(self, client: MapClient, stop: threading.Event) -> None:
        while not stop.wait(POLL_S):
            try:
                acks = client.acks()
            except MapQueryError:
                self.refused += 1
                continue
            except MapServerUnavailable:
                continue
            now = time.monotonic()
            with self.lock:
                for rid, by_epoch in acks.items():
                    last = by_epoch.get(EPOCH, 0)
                    for seq in range(self.acked.get(rid, 0) + 1, last + 1):
                        sent = self.sent.get((rid, seq))
                        if sent is not None:
                            self.latencies.append((now, now - sent))
                    self.acked[rid] = max(last, self.acked.get(rid, 0))


def run(
    agents: int = 16, minutes: float = 10.0, period_s: float = 1.0, voxels: int = 2000, seed: int = 0
) -> list[dict]:
    """Run the soak and print one line per minute; returns those rows."""
    grid = Grid.from_bounds(np.array(WORKSPACE[0]), np.array(WORKSPACE[1]), VOXEL)
    deltas = make_deltas(grid, SensorModel(), 32, voxels, int(voxels * 1.5), seed)
    with tempfile.TemporaryDirectory(
        prefix="swarm-bench-soak-", dir=os.environ.get("SWARM_BENCH_DIR")
    ) as tmp:
        tmp = Path(tmp)
        robots = [f"a{i + 1}" for i in range(agents)]
        team = init_team(MISSION, robots, tmp / "security")
        (tmp / "mission.yaml").write_text(_mission_yaml(agents))
        endpoint = f"tls/127.0.0.1:{bus.free_port()}"
        cmd = swarm_argv("server", "--config", str(tmp / "mission.yaml"))
        cmd += [
            "--store",
            str(tmp / "store"),
            "--listen",
            endpoint,
            "--zenoh-config",
            str(team.configs["server"]),
        ]
        with open(tmp / "server.log", "w") as log:
            server = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=child_environment())
        sessions = []
        stop = threading.Event()
        rows: list[dict] = []
        try:
            client = MapClient.connect([endpoint], MISSION, timeout=30, zenoh_config=team.configs[TOOL])
            client.stats()  # the server is up
            sessions = [
                bus.open_session(connect=[endpoint], config_file=team.configs[agent_name(r)]) for r in robots
            ]
            load = _Team(sessions, grid, deltas, period_s)
            watcher = threading.Thread(target=load.watch, args=(client, stop), daemon=True)
            watcher.start()
            t0 = time.monotonic()
            publisher = threading.Thread(target=load.publish_until, args=(t0 + minutes * 60,), daemon=True)
            publisher.start()
            cpu0, mark = _cpu_s(server.pid), t0
            print(
                f"soak: {agents} agents over TLS + access control, one ~{voxels}-voxel delta each "
                f"every {period_s:g} s, {minutes:g} min"
            )
            print(f"{'min':>4} {'RSS MB':>8} {'CPU %':>6} {'acked':>7} {'ack p50 ms':>10} {'ack p99 ms':>10}")
            for minute in range(1, int(np.ceil(minutes)) + 1):
                time.sleep(max(0.0, t0 + minute * 60 - time.monotonic()))
                now, cpu = time.monotonic(), _cpu_s(server.pid)
                with load.lock:
                    window = np.array([lat for at, lat in load.latencies if mark <= at < now])
                    acked = sum(load.acked.values())
                row = {
                    "minute": minute, "rss_mb": _rss_mb(server.pid),
                    "cpu_pct": 100 * (cpu - cpu0) / (now - mark), "acked": acked,
                    "p50_ms": float(np.percentile(window, 50) * 1e3) if len(window) else float("nan"),
                    "p99_ms": float(np.percentile(window, 99) * 1e3) if len(window) else float("nan"),
                }  # fmt: skip
                rows.append(row)
                print(
                    f"{minute:4d} {row['rss_mb']:8.1f} {row['cpu_pct']:6.1f} {acked:7d} "
                    f"{row['p50_ms']:10.1f} {row['p99_ms']:10.1f}",
                    flush=True,
                )
                cpu0, mark = cpu, now
            publisher.join()
            sent = len(load.sent)
            if len(rows) > 2:
                growth = rows[-1]["rss_mb"] - rows[1]["rss_mb"]
                print(
                    f"RSS from minute 2 to the end: {growth:+.1f} MB; deltas sent {sent}; "
                    f"conflicting answers {load.refused}"
                )
        finally:
            stop.set()
            stop_server(server, sessions, timeout=60)
    return rows
