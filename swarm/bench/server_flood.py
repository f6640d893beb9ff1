"""``swarm bench server --flood``: every publisher with no pause; the server's peak memory, its inbox's
high-water mark and refusals, and that every delta is applied exactly once after the senders' resends."""

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
from swarm.bench.server import (
    MISSION,
    VOXEL,
    WORKSPACE,
    _acked,
    _acks,
    _mission_yaml,
    make_deltas,
    open_agents,
)
from swarm.child_command import child_environment, swarm_argv
from swarm.map.grid import Grid
from swarm.map.sensor_model import SensorModel
from swarm.protocol import bus
from swarm.protocol.wire import DeltaMessage


def _memory_kb(pid: int) -> tuple[int, int]:
    """(current, peak) resident memory of a process in KiB, from /proc (Linux)."""
    fields = {}
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        name, _, value = line.partition(":")
        if name in ("VmRSS", "VmHWM"):
            fields[name] = int(value.split()[0])
    return fields.get("VmRSS", 0), fields.get("VmHWM", 0)


def flood_figures(
    grid: Grid,
    deltas: list,
    agents: int,
    seconds: float,
    workdir: Path,
    settle_s: float = 300.0,
    window: int = 500,
) -> dict:
    """``agents`` sessions publish deltas back to back for ``seconds`` against a ``swarm server``
    process; then each resends what ``map/acks`` does not cover, as an agent does, until all is
    acked (or ``settle_s`` passes). Reports the server's peak memory, the inbox's high-water
    mark and refusals, and whether every delta was applied exactly once."""
    endpoint = bus.tcp_endpoint(bus.free_port())
    config = workdir / "mission.yaml"
    config.write_text(_mission_yaml(agents))
    log_path = workdir / "flood-server.log"
    cmd = swarm_argv("server", "--listen", endpoint, "--log-every", "5")
    cmd += ["--store", str(workdir / "flood-store"), "--config", str(config)]
    with open(log_path, "w") as log_file:
        server = subprocess.Popen(cmd, stdout=log_file, stderr=subprocess.STDOUT, env=child_environment())
    sessions, rss_mb = [], []
    try:
        probe = bus.open_session(connect=[endpoint], wait_s=120)  # a loaded machine starts slowly
        sessions.append(probe)
        deadline = time.monotonic() + 30
        while _acked(probe, "a1", 0) < 0:
            if server.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"the server did not start; see {log_path}")
            time.sleep(0.1)
        start_kb = _memory_kb(server.pid)[0]
        pubs = open_agents(sessions, endpoint, agents)
        epoch = 1  # the first epoch the fresh store issues each agent
        for pub in pubs:
            if pub.renew() != epoch:
                raise RuntimeError(f"{pub.robot}: the server issued another epoch than {epoch}")
        sent = [0] * agents  # highest seq each agent has published
        puts = [0] * agents  # payloads published, resends included
        acked = [0] * agents  # the agents' view of map/acks

        def message(a: int, seq: int) -> bytes:
            d = deltas[(a * 7 + seq) % len(deltas)]
            return DeltaMessage(f"a{a + 1}", epoch, seq, 0.5 * seq, grid, d.idx, d.dlam, d.deta).encode()

        stop, done = threading.Event(), threading.Event()

        def watch() -> None:
            while not done.is_set():
                acks = _acks(probe) or {}
                for a in range(agents):
                    acked[a] = max(acked[a], int(acks.get(f"a{a + 1}", {}).get(str(epoch), 0)))
                time.sleep(0.1)

        def flood(a: int) -> None:
            # no pause: a new seq while fewer than `window` are unacked (an agent keeps at most
            # 2,000), else the unacked ones again from the oldest, round and round
            cursor = 1
            while not stop.is_set():
                if sent[a] < acked[a] + window:
                    sent[a] += 1
                    seq = sent[a]
                else:
                    cursor = cursor if acked[a] < cursor <= sent[a] else acked[a] + 1
                    seq, cursor = cursor, cursor + 1
                pubs[a].put(message(a, seq))
                puts[a] += 1

        watcher = threading.Thread(target=watch, daemon=True)
        watcher.start()
        threads = [threading.Thread(target=flood, args=(a,)) for a in range(agents)]
        t0 = time.perf_counter()
        for t in threads:
            t.start()
        while time.perf_counter() - t0 < seconds:
            rss_mb.append(_memory_kb(server.pid)[0] / 1024)
            time.sleep(0.5)
        stop.set()
        for t in threads:
            t.join()
        flood_s = time.perf_counter() - t0
        # then as agents do: resend what map/acks does not cover, a few at a time
        rounds, resent = 0, 0
        t1 = time.perf_counter()
        while time.perf_counter() - t1 < settle_s:
            if all(acked[a] >= sent[a] for a in range(agents)):
                break
            rounds += 1
            for a in range(agents):
                for seq in range(acked[a] + 1, min(acked[a] + 32, sent[a]) + 1):
                    pubs[a].put(message(a, seq))
                    resent += 1
            rss_mb.append(_memory_kb(server.pid)[0] / 1024)
            time.sleep(0.3)
        done.set()
        settle = time.perf_counter() - t1
        stats = json.loads(
            next(iter(probe.get(bus.key(MISSION, "map", "stats"), timeout=10))).ok.payload.to_bytes()
        )
        _, peak_kb = _memory_kb(server.pid)
        reasons = [line.strip() for line in log_path.read_text().splitlines() if "rejected delta" in line]
        robots = stats["robots"]
        exactly_once = all(
            robots.get(f"a{a + 1}", {}).get("deltas") == sent[a] == robots[f"a{a + 1}"]["acked_seq"]
            for a in range(agents)
        ) and stats["deltas_applied"] == sum(sent)
        return {
            "agents": agents,
            "flood_s": flood_s,
            "sent": sum(sent),
            "puts": sum(puts),
            "puts_mb": sum(len(message(a, 1)) for a in range(agents)) / agents * sum(puts) / 2**20,
            "window": window,
            "resent": resent,
            "resend_rounds": rounds,
            "settle_s": settle,
            "applied": stats["deltas_applied"],
            "duplicates": stats["duplicates"],
            "exactly_once": exactly_once,
            "inbox": stats["inbox"],
            "rejected": {k: v for k, v in stats["rejected"].items() if v},
            "rejection_lines": reasons[:5],
            "rss_start_mb": start_kb / 1024,
            "rss_max_sampled_mb": max(rss_mb, default=0.0),
            "peak_rss_mb": peak_kb / 1024,
        }
    finally:
        stop_server(server, sessions, timeout=60)


def run_flood(agents: int = 16, seconds: float = 30.0, lo: int = 200, hi: int = 2000, seed: int = 0) -> dict:
    """The flood figures (:func:`flood_figures`) on the benchmark's grid."""
    grid = Grid.from_bounds(np.array(WORKSPACE[0]), np.array(WORKSPACE[1]), VOXEL)
    deltas = make_deltas(grid, SensorModel(), 64, lo, hi, seed)
    with tempfile.TemporaryDirectory(
        prefix="swarm-bench-flood-", dir=os.environ.get("SWARM_BENCH_DIR")
    ) as tmp:
        figures = flood_figures(grid, deltas, agents, seconds, Path(tmp))
    figures["delta_voxels_range"] = [min(len(d) for d in deltas), max(len(d) for d in deltas)]
    return figures


def format_flood(f: dict) -> str:
    inbox = f["inbox"]
    lo, hi = f["delta_voxels_range"]
    refused = sum(inbox["refused"].values())
    return "\n".join(
        [
            f"flood: {f['agents']} publishers with no pause for {f['flood_s']:.0f} s, deltas of "
            f"{lo:,}-{hi:,} voxels, against a swarm server process (WAL fsync on), loopback",
            f"  published {f['puts']:,} payloads ({f['puts_mb']:,.0f} MB) of {f['sent']:,} deltas (each "
            f"agent at most {f['window']} unacked, sent again and again); inbox refused {refused:,}",
            f"  then resent {f['resent']:,} in {f['resend_rounds']} rounds over {f['settle_s']:.0f} s "
            "until map/acks covered every delta",
            f"  server memory: {f['rss_start_mb']:.0f} MB at start, peak {f['peak_rss_mb']:.0f} MB "
            f"(highest sample {f['rss_max_sampled_mb']:.0f} MB)",
            f"  inbox high-water {inbox['high_water']} deltas / {inbox['high_water_bytes'] / 2**20:.1f} MB "
            f"(bound {inbox['max_per_robot']} deltas or {inbox['max_bytes_per_robot'] / 2**20:.0f} MB "
            "per robot)",
            f"  applied {f['applied']:,}, duplicates {f['duplicates']:,}, rejected {f['rejected'] or 0}: "
            f"every delta applied exactly once: {'yes' if f['exactly_once'] else 'NO'}",
            *(f"  server log: {line[:200]}" for line in f["rejection_lines"]),
        ]
    )
