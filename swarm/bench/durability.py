"""``swarm bench durability``: acked deltas lost by the map server's store under SIGKILL and
under simulated power cuts (the figure to keep: 0).

Power cuts (in process, ``swarm.bench.crash_model``): a map server merges two robots' deltas
in small batches, compacting every few records, on a store whose file operations are
recorded. For every instant of that recording and every way a cut may leave the disk
(unsynced data and folder names dropped, torn or zeroed tails), the store is rebuilt in a
fresh folder and opened by a new server; its acks must cover every delta acked before the
cut, and its map must equal the map of exactly the deltas it says it holds, each applied
once (a fresh MergedMap fed them in merge order).

SIGKILL (processes): a ``swarm server`` on loopback takes both robots' deltas; after a few
are acked it is killed with SIGKILL, restarted on the same store, and the acks it recovers
are compared with those seen before the kill; the publishers resend the rest; ``kills``
rounds, then the final map against the map of every delta once.
"""

from __future__ import annotations

import shutil
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml

from map_server.options import ServerOptions
from map_server.server import MapServer
from map_server.team_map import MergedMap
from swarm.bench.crash_model import RecordingFiles, crash_states, materialize
from swarm.config import Mission, mission_from_dict
from swarm.map.fusion import batch_information
from swarm.protocol.wire import DeltaMessage

MISSION = {
    "mission": "durability",
    "workspace": {"lo": [0.0, 0.0, 0.0], "hi": [3.0, 2.0, 1.0], "voxel": 0.1},
    "robots": [{"id": "r1", "start": {"x": 0.5, "y": 0.5}}, {"id": "r2", "start": {"x": 2.5, "y": 1.5}}],
}
#: the epoch a fresh store issues each robot first (map_server.epochs)
EPOCH = 1


@dataclass
class PowerCutReport:
    """What :func:`power_cuts` checked and found."""

    operations: int = 0
    cuts: int = 0
    states: int = 0
    acked: int = 0
    lost: int = 0
    doubled: int = 0
    unopenable: int = 0
    #: the first few failures, one line each (cut, variant, what was wrong)
    failures: list[str] = field(default_factory=list)


def bench_mission() -> Mission:
    return mission_from_dict(MISSION)


def deltas(
    mission: Mission, per_robot: int, seed: int = 0, rays: int = 60, epoch: int = EPOCH
) -> list[tuple[str, int, bytes]]:
    """``(robot, seq, payload)`` of each robot's deltas of random rays, interleaved by seq."""
    grid, sensor = mission.workspace.grid(), mission.sensor.model()
    rng = np.random.default_rng(seed)
    out = []
    for seq in range(1, per_robot + 1):
        for rid in mission.robot_ids:
            origin = rng.uniform(grid.lo + 0.3, grid.hi - 0.3)
            points = rng.uniform(grid.lo, grid.hi - 1e-6, size=(rays, 3))
            d = batch_information(grid, sensor, origin, points).delta
            out.append(
                (rid, seq, DeltaMessage(rid, epoch, seq, float(seq), grid, d.idx, d.dlam, d.deta).encode())
            )
    return out


def record_workload(root: Path, mission: Mission, sent, batch: int = 3, compact_records: int = 5, **server):
    """Merge ``sent`` in batches on a recorded store under ``root``; the recording, with an
    ``("acked", robot, seq)`` marker after each delta the server made durable."""
    root.mkdir(parents=True, exist_ok=True)
    files = RecordingFiles(root)
    options = ServerOptions(compact_records=compact_records, log_reserve_bytes=0, **server)
    srv = MapServer(mission, root / "store", options=options, files=files)
    grants = {rid: srv.admission.issue(rid) for rid in mission.robot_ids}  # epoch 1 each, durable
    assert all(g.epoch == EPOCH for g in grants.values())
    for start in range(0, len(sent), batch):
        chunk = sent[start : start + batch]
        srv.merge([(rid, payload, grants[rid].sign(payload)) for rid, _, payload in chunk])
        for rid, seq, _ in chunk:
            files.note("acked", rid, seq)
    srv.stop()
    return files.ops


def power_cuts(per_robot: int = 8, seed: int = 0, limit_failures: int = 5, **server) -> PowerCutReport:
    """Check every crash state of a recorded workload (module docstring); ``server``: options
    of the recorded server (e.g. ``fsync=False`` to see the check catch a store that loses)."""
    mission = bench_mission()
    sent = deltas(mission, per_robot, seed)
    payload_of = {(rid, seq): p for rid, seq, p in sent}
    order = [(rid, seq) for rid, seq, _ in sent]
    report = PowerCutReport()
    with tempfile.TemporaryDirectory(prefix="swarm-powercut-") as tmp:
        ops = record_workload(Path(tmp) / "live", mission, sent, **server)
        report.operations, report.acked = len(ops), sum(op[0] == "acked" for op in ops)
        acked_upto = [set()]
        for op in ops:
            acked_upto.append(acked_upto[-1] | ({(op[1], op[2])} if op[0] == "acked" else set()))
        cuts = set()
        for n, (cut, variant, tree) in enumerate(crash_states(ops)):
            cuts.add(cut)
            report.states += 1
            folder = Path(tmp) / f"cut-{n}"
            folder.mkdir()
            materialize(tree, folder)
            problem = _check(mission, folder / "store", acked_upto[cut], order, payload_of, report)
            if problem and len(report.failures) < limit_failures:
                report.failures.append(
                    f"cut {cut} ({ops[cut - 1][0] if cut else 'start'}), {variant}: {problem}"
                )
            shutil.rmtree(folder)
        report.cuts = len(cuts)
    return report


def _check(mission, store: Path, acked: set, order: list, payload_of: dict, report: PowerCutReport) -> str:
    """Open ``store`` with a new server; '' when it holds every acked delta exactly once."""
    try:
        srv = MapServer(mission, store, options=ServerOptions(fsync=False))
    except Exception as exc:  # noqa: BLE001 (a store the next start refuses is a finding)
        report.unopenable += 1
        return f"the next start fails: {exc}"
    try:
        acks = srv.team.acks()
        held = {
            (rid, seq)
            for rid, by_epoch in acks.items()
            for top in by_epoch.values()
            for seq in range(1, top + 1)
        }
        missing = acked - held
        # exactly the held deltas, once each, in the order they were merged
        expected = _map_of(mission, [payload_of[key] for key in order if key in held])
        same = np.array_equal(srv.team.cmap.lam, expected.cmap.lam) and np.array_equal(
            srv.team.cmap.eta, expected.cmap.eta
        )
    finally:
        srv.store.close()
    report.lost += len(missing)
    if not same:
        report.doubled += 1
    if missing:
        return f"{len(missing)} acked deltas lost: {sorted(missing)[:4]}"
    return "" if same else "the map is not the map of the deltas it holds, each once"


def sigkills(kills: int = 15, per_robot: int = 40, seed: int = 1, timeout_s: float = 60.0) -> dict:
    """``kills`` SIGKILLs of a ``swarm server`` process mid-stream (module docstring): acked
    deltas lost, deltas applied twice, and the final map against every delta once."""
    from swarm.protocol import bus
    from swarm.protocol.epochs import put_delta, wait_for_epoch
    from swarm.protocol.map_client import MapClient

    mission = bench_mission()
    grants: dict = {}  # asked once: the restarted server keeps the epochs and their keys
    sent = deltas(mission, per_robot, seed)
    lost = doubled = 0
    seen: dict[str, int] = {}
    same = False
    with tempfile.TemporaryDirectory(prefix="swarm-sigkill-") as tmp:
        config = Path(tmp) / "mission.yaml"
        config.write_text(yaml.safe_dump(MISSION))
        store, log = Path(tmp) / "store", Path(tmp) / "server.log"
        endpoint = bus.tcp_endpoint(bus.free_port())
        for round_ in range(kills + 1):
            proc = _start_server(config, store, endpoint, log)
            session = bus.open_session(connect=[endpoint], wait_s=timeout_s)
            try:
                client = MapClient(session, mission.mission, timeout=2.0, endpoint=endpoint)
                _wait_up(client, proc, log, timeout_s)
                before = _acked(client.acks())
                if round_:
                    lost += sum(max(0, n - before.get(r, 0)) for r, n in seen.items())
                pubs = {
                    r: bus.reliable_publisher(session, bus.key(mission.mission, "delta", r))
                    for r in MISSION_IDS
                }
                for r in MISSION_IDS:
                    if r not in grants:
                        grants[r] = wait_for_epoch(session, mission.mission, r, timeout_s)
                        assert grants[r].epoch == EPOCH, grants[r]
                todo = [(r, s, p) for r, s, p in sent if s > before.get(r, 0)]
                target = sum(before.values()) + (len(todo) if round_ == kills else max(1, len(todo) // 4))
                seen = before
                for rid, _, payload in todo:
                    put_delta(pubs[rid], grants[rid], payload)
                    time.sleep(0.003)
                    seen = _acked(client.acks())
                    if sum(seen.values()) >= target and round_ < kills:
                        break
                deadline = time.monotonic() + timeout_s
                while round_ == kills and sum(seen.values()) < len(sent) and time.monotonic() < deadline:
                    time.sleep(0.1)
                    seen = _acked(client.acks())
                if round_ == kills:
                    doubled = client.stats()["deltas_applied"] - sum(seen.values())
                    snap, expected = client.snapshot(), _map_of(mission, [p for _, _, p in sent])
                    same = np.allclose(snap.lam, expected.cmap.lam, rtol=1e-5, atol=1e-6)
                    same &= np.allclose(snap.eta, expected.cmap.eta, rtol=1e-5, atol=1e-6)
            finally:
                session.close()
                if round_ < kills:
                    proc.send_signal(signal.SIGKILL)
                    proc.wait(timeout=10)
                else:
                    proc.terminate()
                    proc.wait(timeout=60)
    acked = sum(seen.values())
    return {
        "kills": kills,
        "deltas": len(sent),
        "acked": acked,
        "lost": lost,
        "doubled": doubled,
        "map_equal": same,
    }


def _map_of(mission: Mission, payloads: list[bytes]) -> MergedMap:
    """The map of exactly these deltas, each once, merged without a server."""
    team = MergedMap(mission.workspace.grid(), mission.sensor.model())
    for payload in payloads:
        msg = DeltaMessage.decode(payload)
        if team.admit(msg):
            team.apply(msg)
    return team


MISSION_IDS = [r["id"] for r in MISSION["robots"]]


def _acked(acks: dict) -> dict[str, int]:
    return {r: acks.get(r, {}).get(str(EPOCH), acks.get(r, {}).get(EPOCH, 0)) for r in MISSION_IDS}


def _start_server(config: Path, store: Path, endpoint: str, log: Path) -> subprocess.Popen:
    cmd = [sys.executable, "-m", "swarm.cli", "server", "--listen", endpoint, "--store", str(store)]
    cmd += ["--config", str(config), "--compact-records", "8"]
    with open(log, "a") as out:
        return subprocess.Popen(cmd, stdout=out, stderr=subprocess.STDOUT)


def _wait_up(client, proc: subprocess.Popen, log: Path, timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while True:
        try:
            client.stats()
            return
        except ConnectionError:
            if proc.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"server did not come up:\n{log.read_text()[-2000:]}") from None


def run(kills: int = 15, per_robot: int = 8) -> int:
    """Print both figures; exit status 1 when anything acked was lost or applied twice."""
    import logging

    logging.getLogger("swarm.server").setLevel(logging.ERROR)  # each cut state's recovery lines
    report = power_cuts(per_robot)
    print(
        f"power cuts: {report.operations} recorded file operations, {report.cuts} cut points, "
        f"{report.states} distinct disk states checked; {report.acked} deltas acked in all: "
        f"{report.lost} acked lost, {report.doubled} states with a delta applied twice or missing "
        f"from the map, {report.unopenable} stores the next start refused"
    )
    for line in report.failures:
        print(f"  {line}")
    killed = sigkills(kills)
    print(
        f"SIGKILL: {killed['kills']} kills of a swarm server mid-stream, {killed['deltas']} deltas, "
        f"{killed['acked']} acked at the end: {killed['lost']} acked lost, "
        f"{killed['doubled']} applied twice; "
        f"final map {'equal to' if killed['map_equal'] else 'DIFFERENT from'} the map of every delta once"
    )
    bad = report.lost or report.doubled or report.unopenable or killed["lost"] or killed["doubled"]
    bad = bad or not killed["map_equal"]
    return 1 if bad else 0
