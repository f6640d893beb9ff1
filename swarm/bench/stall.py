"""``swarm bench stall``: the robots' ack latency and the end of a mission while a subscriber of
``merged`` stops draining and a stranger holds hundreds of idle connections to the map server.

Runs the same ``swarm sim`` mission (default ``configs/office.yaml``, 4 robots) twice: once
alone, once attacked. The attack joins the map server's own endpoint (read from its log) with
a Zenoh session behind a relay that stops reading after a second (``swarm.bench.stall_relay``:
the server's link to it fills up), and holds ``connections`` idle TCP connections to the same
endpoint for the whole mission (``swarm.bench.slowloris``). An observer on that endpoint notes
when each robot's delta first appears on ``delta/*`` and polls ``map/acks`` every 20 ms: a
delta's ack latency is from its arrival to the first ack that covers it (20 ms resolution).
Figures per run: ack latency p50/p99/max over every delta acked, deltas acked, whether the
mission reached H_th, its simulated and wall time, the machine's load, the map server's longest
put on merged (map/stats), and what the stalled subscriber received.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import zenoh

from swarm.bench.slowloris import NO_SHM, _hold
from swarm.bench.stall_relay import StallRelay
from swarm.protocol import bus
from swarm.protocol.map_client import MapClient
from swarm.protocol.wire import DeltaMessage, WireError

ACK_POLL_S = 0.02
_LISTENING = re.compile(r"listening on (tcp/127\.0\.0\.1:(\d+))")


@dataclass
class RunFigures:
    """What one mission run measured."""

    name: str
    stall: bool
    idle: int
    acked: int = 0
    p50_ms: float = float("nan")
    p99_ms: float = float("nan")
    max_ms: float = float("nan")
    reached_threshold: bool | None = None
    sim_time_s: float | None = None
    wall_s: float = 0.0
    stalled_received: int = 0
    published: int = 0
    longest_put_ms: float = float("nan")  # the map server's longest put on merged
    held: int = 0
    exit_code: int | None = None
    load: float = 0.0  # the machine's 1-minute load average at the end (other work shares the cores)


def _client(endpoint: str, wait_s: float = 30.0) -> zenoh.Session:
    """A client session to ``endpoint`` (payloads on the TCP link: no shared memory), retried for
    ``wait_s`` s (the server logs its endpoint a moment before it takes sessions)."""
    deadline = time.monotonic() + wait_s
    while True:
        conf, _, _ = bus.session_config([], [endpoint])
        conf.insert_json5(NO_SHM, "false")  # as between two machines
        try:
            return zenoh.open(conf)
        except zenoh.ZError:
            if time.monotonic() >= deadline:
                raise
            time.sleep(0.3)


def _server_endpoint(log: Path, proc: subprocess.Popen, timeout_s: float) -> tuple[str, int]:
    """The map server's listening endpoint and port, from its log; RuntimeError when it never says."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if log.is_file() and (found := _LISTENING.search(log.read_text(errors="replace"))):
            return found.group(1), int(found.group(2))
        if proc.poll() is not None:
            break
        time.sleep(0.2)
    raise RuntimeError(f"the map server never said where it listens ({log})")


class AckObserver:
    """Arrival of each delta on ``delta/*`` and the first ``map/acks`` that covers it."""

    def __init__(self, session: zenoh.Session, mission: str) -> None:
        self.arrived: dict[tuple[str, int, int], float] = {}
        self.latencies: list[float] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._client = MapClient(session, mission, timeout=2.0)
        self._sub = bus.subscribe(session, bus.key_pattern(mission, "delta", "*"), self._on_delta)
        self._thread = threading.Thread(target=self._poll, daemon=True)
        self._thread.start()

    def _on_delta(self, _key: str, payload: bytes) -> None:
        try:
            msg = DeltaMessage.decode(payload)
        except WireError:
            return
        with self._lock:
            self.arrived.setdefault((msg.robot, msg.epoch, msg.seq), time.monotonic())

    def _poll(self) -> None:
        while not self._stop.wait(ACK_POLL_S):
            try:
                acks = self._client.acks()
            except Exception:  # noqa: BLE001 (no answer this round: the next one)
                continue
            now = time.monotonic()
            with self._lock:
                for ident in [i for i in self.arrived if acks.get(i[0], {}).get(i[1], 0) >= i[2]]:
                    self.latencies.append(now - self.arrived.pop(ident))

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)
        self._sub.undeclare()


def run_once(config: Path, out: Path, name: str, stall: bool, idle: int, seed: int) -> RunFigures:
    """One ``swarm sim`` run of ``config`` into ``out``: with a stalled merged subscriber when
    ``stall``, with ``idle`` idle connections to the server (module doc)."""
    figures = RunFigures(name, stall, idle)
    out.mkdir(parents=True, exist_ok=True)
    cmd = [sys.executable, "-m", "swarm.cli", "sim", "run", str(config), "--out", str(out)]
    cmd += ["--seed", str(seed), "--quiet"]
    started = time.monotonic()
    with open(out.parent / f"{out.name}.log", "w") as log:
        proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT)
    stop, held = threading.Event(), [0]
    holder = relay = observer = session = slow = None
    got = [0]
    try:
        endpoint, port = _server_endpoint(out / "server.log", proc, 600.0)
        session = _client(endpoint)
        mission = _mission_name(out)
        observer = AckObserver(session, mission)
        if stall:
            relay = StallRelay(("127.0.0.1", port))
            slow = _client(relay.endpoint)
            slow.declare_subscriber(bus.key(mission, "merged"), lambda _s: got.__setitem__(0, got[0] + 1))
            threading.Timer(1.0, relay.stall).start()
        if idle:
            holder = threading.Thread(target=_hold, args=(port, idle, stop, held), daemon=True)
            holder.start()
        while proc.poll() is None:
            figures.held = max(figures.held, held[0])
            try:
                stats = MapClient(session, mission, timeout=1.0).stats()
                merged = stats.get("merged", {})
                figures.published = int(merged.get("published", figures.published))
                figures.longest_put_ms = float(merged.get("longest_put_ms", figures.longest_put_ms))
            except Exception:  # noqa: BLE001 (the server is stopping)
                pass
            time.sleep(1.0)
        figures.exit_code = proc.returncode
    finally:
        if proc.poll() is None:
            proc.terminate()
            proc.wait(timeout=60)
        stop.set()
        if holder is not None:
            holder.join(timeout=10)
        if observer is not None:
            observer.close()
        if relay is not None:
            relay.close()
        for s in (slow, session):
            if s is not None:
                s.close()
    figures.wall_s = time.monotonic() - started
    figures.load = os.getloadavg()[0]
    figures.stalled_received = got[0]
    lat = np.asarray(observer.latencies if observer is not None else [], np.float64) * 1e3
    if len(lat):
        figures.acked = len(lat)
        figures.p50_ms, figures.p99_ms = (float(v) for v in np.percentile(lat, [50, 99]))
        figures.max_ms = float(lat.max())
    metrics = out / "metrics.json"
    if metrics.is_file():
        data = json.loads(metrics.read_text())
        figures.reached_threshold = data.get("reached_threshold")
        figures.sim_time_s = data.get("sim_time_s")
    return figures


def _mission_name(out: Path) -> str:
    """The mission's name, from the config the runner wrote to the run folder."""
    import yaml

    deadline = time.monotonic() + 60.0
    while time.monotonic() < deadline:
        path = out / "config.yaml"
        if path.is_file():
            try:
                return str(yaml.safe_load(path.read_text())["mission"])
            except (yaml.YAMLError, KeyError, TypeError):
                pass
        time.sleep(0.2)
    raise RuntimeError(f"no config.yaml in {out}")


def describe(f: RunFigures) -> str:
    """One line of figures."""
    line = (
        f"{f.name:>9}: ack latency p50 {f.p50_ms:.0f} ms, p99 {f.p99_ms:.0f} ms, max {f.max_ms:.0f} ms over "
        f"{f.acked} deltas; reached H_th: {f.reached_threshold} (sim {f.sim_time_s or 0:.0f} s, "
        f"wall {f.wall_s:.0f} s, load {f.load:.1f}); server's longest merged put {f.longest_put_ms:.1f} ms"
    )
    if f.stall:
        line += f"; stalled subscriber received {f.stalled_received} of {f.published} merged samples"
    if f.idle:
        line += f"; {f.held} of {f.idle} idle connections held"
    return line


#: The runs ``--runs`` may name: (stalled merged subscriber, idle connections or None: --connections).
RUNS = {"alone": (False, 0), "stall": (True, 0), "idle": (False, None), "attacked": (True, None)}


def run(
    config: Path,
    out: Path,
    connections: int = 300,
    seed: int = 0,
    target_ms: float = 200.0,
    runs: tuple[str, ...] = ("alone", "attacked"),
) -> int:
    """The ``runs`` one after the other, side by side; exit status 1 when the attacked p99 misses
    ``target_ms`` or the attacked mission does not reach H_th while the one alone does."""
    done: dict[str, RunFigures] = {}
    for name in runs:
        stall, idle = RUNS[name]
        done[name] = run_once(config, out / name, name, stall, connections if idle is None else idle, seed)
        print(describe(done[name]), flush=True)
    attacked, alone = done.get("attacked"), done.get("alone")
    if attacked is None:
        return 0
    reached = attacked.reached_threshold or (alone is not None and not alone.reached_threshold)
    ok = attacked.p99_ms < target_ms and reached
    print(f"target: attacked ack p99 < {target_ms:.0f} ms and H_th reached: {'met' if ok else 'MISSED'}")
    return 0 if ok else 1
