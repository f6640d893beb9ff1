"""A sharded map service across three hosts: network namespaces joined by veth pairs, with
addresses of these test hosts only (TEST-NET-2 and TEST-NET-3, reachable only inside them).

Host ``a`` runs map server shard 0 (the Zenoh router the others connect to) and the
coordinator; host ``b`` runs shard 1, connected to ``a``; host ``c`` is the robot: its agent
(its own router, the world on loopback) connected to ``a``, so its deltas for shard 1 cross
``a``'s router. The link a-b is down while the robot maps its whole mission (at least 20 s);
once it is back, shard 1 is killed (SIGKILL) while the resends come in and is started again on
its store. In the end every delta the robot produced is applied exactly once on its shard, and
the shards' maps side by side equal the central fusion of every delta the robot sent (recorded
on its own host, each once).

Needs root and ``ip`` (iproute2); skipped with the reason otherwise. Zenoh's shared memory is
off in every process (on one machine it would carry payloads around the links under test).
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
import uuid
from pathlib import Path

import numpy as np
import pytest

from tests.support.missions import MISSION, PLAN
from tests.support.net_namespaces import NO_SHM, ip, require_namespaces, wait_for
from tests.support.paths import ROOT

pytestmark = pytest.mark.slow  # whole roles as processes on three hosts

A_B, B_A = "198.51.100.1", "198.51.100.2"  # the a-b link
A_C, C_A = "203.0.113.1", "203.0.113.2"  # the a-c link
OUTAGE_S = 20.0


@pytest.fixture
def three_hosts():
    """Namespaces a, b, c; veth pairs a-b and a-c; removed afterwards whatever happens."""
    require_namespaces()
    tag = uuid.uuid4().hex[:5]
    ns = {h: f"sh{tag}{h}" for h in "abc"}
    try:
        for name in ns.values():
            ip("netns", "add", name)
    except (subprocess.CalledProcessError, OSError) as exc:
        for name in ns.values():
            subprocess.run(["ip", "netns", "del", name], capture_output=True)
        pytest.skip(f"cannot create network namespaces here: {exc}")
    try:
        for far, (near_ip, far_ip) in (("b", (A_B, B_A)), ("c", (A_C, C_A))):
            near_dev, far_dev = f"sh{tag}a{far}", f"sh{tag}{far}a"
            ip("link", "add", near_dev, "type", "veth", "peer", "name", far_dev)
            ip("link", "set", near_dev, "netns", ns["a"])
            ip("link", "set", far_dev, "netns", ns[far])
            ip("-n", ns["a"], "addr", "add", f"{near_ip}/24", "dev", near_dev)
            ip("-n", ns[far], "addr", "add", f"{far_ip}/24", "dev", far_dev)
            ip("-n", ns["a"], "link", "set", near_dev, "up")
            ip("-n", ns[far], "link", "set", far_dev, "up")
        for name in ns.values():
            ip("-n", name, "link", "set", "lo", "up")
        yield {**ns, "b_dev": f"sh{tag}ba"}
    finally:
        for name in ns.values():
            subprocess.run(["ip", "netns", "del", name], capture_output=True)  # the veths go too


def _start(ns: str, args: list[str], log: Path, module: str = "swarm.cli") -> subprocess.Popen:
    env = {**os.environ, "PYTHONUNBUFFERED": "1", "PYTHONPATH": str(ROOT)}
    cmd = ["ip", "netns", "exec", ns, sys.executable, "-m", module, *args]
    return subprocess.Popen(cmd, stdout=log.open("a"), stderr=subprocess.STDOUT, env=env)


def _applied(log: Path) -> int:
    found = re.findall(r"(\d+) deltas applied", log.read_text())
    return int(found[-1]) if found else 0


def _team(ns: str, endpoint: str, zenoh_config: Path, out: Path | None = None) -> dict:
    """The sharded service's figures as a client on host ``ns`` sees them (and its map to ``out``)."""
    code = (
        "import json, sys, numpy as np\n"
        "from swarm.protocol import bus\n"
        "from swarm.protocol.sharded_client import ShardedMapClient, discover_layout\n"
        f"s = bus.open_session(connect=[{endpoint!r}], config_file=sys.argv[1])\n"
        "layout = discover_layout(s, 'tiny', 10.0)\n"
        "c = ShardedMapClient(s, 'tiny', layout, 10.0)\n"
        "st = c.stats()\n"
        "if len(sys.argv) > 2:\n"
        "    snap = c.team_snapshot(); np.savez(sys.argv[2], lam=snap.lam, eta=snap.eta)\n"
        "print(json.dumps({'applied': [x['deltas_applied'] for x in st['shards']], 'acks': c.acks(),\n"
        "    'rejected': sum(st['rejected'].values()), 'duplicates': st['duplicates']}))\n"
        "s.close()\n"
    )
    args = [str(zenoh_config), *([str(out)] if out is not None else [])]
    done = subprocess.run(
        ["ip", "netns", "exec", ns, sys.executable, "-c", code, *args],
        capture_output=True, text=True, timeout=60, check=True, env={**os.environ, "PYTHONPATH": str(ROOT)},
    )  # fmt: skip
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_two_shards_on_two_hosts_take_every_delta_once_through_a_cut_and_a_kill(three_hosts, tmp_path):
    (tmp_path / "plan.yaml").write_text(PLAN)
    mission = MISSION.replace("agent_timeout_s: 30", "agent_timeout_s: 120").replace(
        "max_time_s: 400", "max_time_s: 100"
    )
    (tmp_path / "tiny.yaml").write_text(mission + "map_service: {shards: 2}\n")
    no_shm = tmp_path / "no-shm.json5"
    no_shm.write_text(NO_SHM)
    config, zc = str(tmp_path / "tiny.yaml"), ["--zenoh-config", str(no_shm)]
    hub, robot_local = "tcp/0.0.0.0:7447", "tcp/127.0.0.1:7450"
    names = ("shard0", "shard1", "coordinator", "agent", "world", "recorder")
    logs = {n: tmp_path / f"{n}.log" for n in names}
    shard1_args = ["server", "--config", config, "--shard", "1", "--store", str(tmp_path / "store-1"),
                   "--listen", f"tcp/{B_A}:7448", "--connect", f"tcp/{A_B}:7447",
                   "--log-every", "0.2", *zc]  # fmt: skip
    procs: dict[str, subprocess.Popen] = {}
    try:
        procs["shard0"] = _start(
            three_hosts["a"],
            ["server", "--config", config, "--shard", "0", "--store", str(tmp_path / "store-0"),
             "--listen", hub, "--log-every", "0.2", *zc],
            logs["shard0"],
        )  # fmt: skip
        wait_for(lambda: "listening on" in logs["shard0"].read_text(), 60, "shard 0", logs.values())
        procs["shard1"] = _start(three_hosts["b"], shard1_args, logs["shard1"])
        procs["coordinator"] = _start(
            three_hosts["a"], ["coordinator", "--config", config, "--connect", "tcp/127.0.0.1:7447", *zc],
            logs["coordinator"],
        )  # fmt: skip
        wait_for(lambda: "listening on" in logs["shard1"].read_text(), 60, "shard 1", logs.values())
        procs["agent"] = _start(
            three_hosts["c"],
            ["agent", "--id", "r1", "--config", config, "--listen", robot_local,
             "--connect", f"tcp/{A_C}:7447", "--on-mission-done", "continue", *zc],
            logs["agent"],
        )  # fmt: skip
        recorded = tmp_path / "recorded.npz"
        procs["recorder"] = _start(
            three_hosts["c"], [config, robot_local, str(no_shm), str(recorded)], logs["recorder"],
            module="tests.support.delta_recorder",
        )  # fmt: skip
        wait_for(
            lambda: "recording deltas" in logs["recorder"].read_text(), 60, "the recorder", logs.values()
        )
        issued = lambda: logs["agent"].read_text().count("epoch 1 issued") == 2  # noqa: E731
        wait_for(issued, 60, "the robot's epoch on each shard", logs.values())

        # the a-b link goes down: the robot maps all its mission while shard 1 hears nothing
        ip("-n", three_hosts["b"], "link", "set", three_hosts["b_dev"], "down")
        cut = time.monotonic()
        procs["world"] = _start(three_hosts["c"], ["sim", "world", config, "--connect", robot_local, *zc],
                                logs["world"])  # fmt: skip
        procs["world"].wait(timeout=240)
        time.sleep(max(OUTAGE_S - (time.monotonic() - cut), 0.0))
        assert _applied(logs["shard0"]) > 0, "shard 0 took its part during the cut"
        assert _applied(logs["shard1"]) == 0, "the a-b link really was down"
        ip("-n", three_hosts["b"], "link", "set", three_hosts["b_dev"], "up")
        wait_for(lambda: _applied(logs["shard1"]) > 0, 60, "shard 1 after the cut", logs.values())

        # shard 1 dies without a word while the resends come in, and comes back on its store
        procs["shard1"].send_signal(signal.SIGKILL)
        procs["shard1"].wait(timeout=10)
        procs["shard1"] = _start(three_hosts["b"], shard1_args, logs["shard1"])
        hub_client = "tcp/127.0.0.1:7447"
        produced = int(re.findall(r"recorded (\d+) deltas", logs["recorder"].read_text())[-1])
        wait_for(
            lambda: sum(_team(three_hosts["a"], hub_client, no_shm)["applied"]) >= produced,
            120, f"the {produced} deltas recorded, applied over both shards", logs.values(),
        )  # fmt: skip
        procs["agent"].send_signal(signal.SIGTERM)
        procs["agent"].wait(timeout=60)
        text = logs["agent"].read_text()
        sent = int(re.search(r"(\d[\d,]*) deltas \([\d,]+ voxels", text).group(1).replace(",", ""))
        wait_for(
            lambda: sum(_team(three_hosts["a"], hub_client, no_shm)["applied"]) >= sent,
            90, f"{sent} deltas applied over both shards", logs.values(),
        )  # fmt: skip
        served = tmp_path / "served.npz"
        team = _team(three_hosts["a"], hub_client, no_shm, served)
        assert sum(team["applied"]) == sent, "each delta exactly once: none lost, none doubled"
        for k, applied in enumerate(team["applied"]):
            (acked,) = team["acks"][k]["r1"].values()
            assert acked == applied > 0, f"shard {k}: acks cover every delta it applied"
        assert team["rejected"] == 0
        procs["recorder"].send_signal(signal.SIGTERM)
        procs["recorder"].wait(timeout=30)
        central, merged = np.load(recorded), np.load(served)
        assert int(central["applied"]) == sent
        rel = np.abs(merged["lam"] - central["lam"]) / central["lam"]
        assert rel.max() <= 1e-6, (
            f"the shards' map is the central fusion (max relative difference {rel.max():.2e})"
        )
        np.testing.assert_allclose(merged["eta"], central["eta"], rtol=1e-6, atol=1e-6)
        print(
            f"three hosts: {sent} deltas ({team['applied']} per shard) each applied once through a "
            f"{OUTAGE_S:g} s cut of a-b and a SIGKILL of shard 1; {team['duplicates']} resent copies "
            f"ignored; max relative difference to central fusion {rel.max():.1e}"
        )
    finally:
        for p in procs.values():
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        for p in procs.values():
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()
