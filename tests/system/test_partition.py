"""A network partition between a robot and the map server, on a real link: two network namespaces
joined by a veth pair (the server at 192.0.2.1, the robot at 192.0.2.2: TEST-NET-1 addresses,
reachable only inside these namespaces). The link goes down for 30 s while the robot maps its
whole mission, comes back, and every delta the robot produced is applied exactly once.

Needs root and ``ip`` (iproute2); skipped with the reason otherwise. Zenoh's shared memory is
off in every process: over loopback it would carry payloads around the link under test.
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

import pytest

from tests.support.missions import MISSION, PLAN
from tests.support.net_namespaces import NO_SHM, ip, require_namespaces, wait_for

pytestmark = pytest.mark.slow  # whole missions: every role a process

SERVER_IP, ROBOT_IP = "192.0.2.1", "192.0.2.2"
OUTAGE_S = 30.0


@pytest.fixture
def two_hosts():
    """Namespaces ``srv`` and ``rob`` joined by a veth pair; removed afterwards whatever happens."""
    require_namespaces()
    tag = uuid.uuid4().hex[:6]
    srv, rob, va, vb = f"sw{tag}s", f"sw{tag}r", f"sw{tag}a", f"sw{tag}b"
    try:
        ip("netns", "add", srv)
        ip("netns", "add", rob)
    except (subprocess.CalledProcessError, OSError) as exc:
        for ns in (srv, rob):
            subprocess.run(["ip", "netns", "del", ns], capture_output=True)
        pytest.skip(f"cannot create network namespaces here: {exc}")
    try:
        ip("link", "add", va, "type", "veth", "peer", "name", vb)
        ip("link", "set", va, "netns", srv)
        ip("link", "set", vb, "netns", rob)
        ip("-n", srv, "addr", "add", f"{SERVER_IP}/24", "dev", va)
        ip("-n", rob, "addr", "add", f"{ROBOT_IP}/24", "dev", vb)
        for ns, dev in ((srv, va), (rob, vb)):
            ip("-n", ns, "link", "set", "lo", "up")
            ip("-n", ns, "link", "set", dev, "up")
        yield {"srv": srv, "rob": rob, "srv_dev": va}
    finally:
        for ns in (srv, rob):
            subprocess.run(["ip", "netns", "del", ns], capture_output=True)  # removes the veth pair too


def _start(ns: str, args: list[str], log: Path) -> subprocess.Popen:
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    cmd = ["ip", "netns", "exec", ns, sys.executable, "-m", "swarm.cli", *args]
    return subprocess.Popen(cmd, stdout=log.open("w"), stderr=subprocess.STDOUT, env=env)


def _applied(log: Path) -> int:
    found = re.findall(r"(\d+) deltas applied", log.read_text())
    return int(found[-1]) if found else 0


def _server_stats(ns: str, endpoint: str, mission: str) -> dict:
    code = (
        "import json, sys; from swarm.protocol.map_client import MapClient\n"
        f"c = MapClient.connect([{endpoint!r}], {mission!r}, timeout=10, zenoh_config=sys.argv[1])\n"
        "print(json.dumps({'stats': c.stats(), 'acks': c.acks()})); c.close()\n"
    )
    out = subprocess.run(
        ["ip", "netns", "exec", ns, sys.executable, "-c", code, os.environ["ZENOH_TEST_CONFIG"]],
        capture_output=True, text=True, timeout=60, check=True,
    )  # fmt: skip
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_a_partitioned_robot_keeps_mapping_and_every_delta_lands_once(two_hosts, tmp_path, monkeypatch):
    (tmp_path / "plan.yaml").write_text(PLAN)
    (tmp_path / "tiny.yaml").write_text(
        MISSION.replace("agent_timeout_s: 30", "agent_timeout_s: 120").replace(
            "max_time_s: 400", "max_time_s: 100"
        )
    )
    no_shm = tmp_path / "no-shm.json5"
    no_shm.write_text(NO_SHM)
    monkeypatch.setenv("ZENOH_TEST_CONFIG", str(no_shm))
    config = str(tmp_path / "tiny.yaml")
    server_ep, local_ep = f"tcp/{SERVER_IP}:7447", "tcp/127.0.0.1:7448"
    logs = {name: tmp_path / f"{name}.log" for name in ("server", "agent", "world")}
    zc = ["--zenoh-config", str(no_shm)]
    procs: list[subprocess.Popen] = []
    try:
        server = _start(
            two_hosts["srv"],
            ["server", "--config", config, "--store", str(tmp_path / "store"), "--listen", server_ep,
             "--log-every", "0.2", *zc],
            logs["server"],
        )  # fmt: skip
        procs.append(server)
        wait_for(lambda: "listening on" in logs["server"].read_text(), 60, "the server", list(logs.values()))
        # the robot: its agent is its own router (the world meets it on loopback) and reaches the
        # server over the veth link
        agent = _start(
            two_hosts["rob"],
            ["agent", "--id", "r1", "--config", config, "--listen", local_ep, "--connect", server_ep,
             "--coordination", "none", "--on-mission-done", "continue", *zc],
            logs["agent"],
        )  # fmt: skip
        procs.append(agent)
        issued = lambda: "epoch 1 issued" in logs["agent"].read_text()  # noqa: E731
        wait_for(issued, 60, "the robot's epoch", list(logs.values()))
        # the link goes down before the world starts: the simulated world is not paced (a tiny
        # mission takes about a second), so the robot maps all of it during the outage
        ip("-n", two_hosts["srv"], "link", "set", two_hosts["srv_dev"], "down")
        cut = time.monotonic()
        world = _start(two_hosts["rob"], ["sim", "world", config, "--connect", local_ep, *zc], logs["world"])
        procs.append(world)
        world.wait(timeout=180)  # the robot finished mapping (it did not wait for the link)
        time.sleep(max(OUTAGE_S - (time.monotonic() - cut), 0.0))
        applied_at_cut = _applied(logs["server"])
        assert applied_at_cut == 0  # the link really was down
        ip("-n", two_hosts["srv"], "link", "set", two_hosts["srv_dev"], "up")
        stable = {"n": -1, "since": time.monotonic()}

        def settled() -> bool:  # the server's count unchanged for 8 s: the resends are through
            n = _applied(logs["server"])
            if n != stable["n"]:
                stable.update(n=n, since=time.monotonic())
            return time.monotonic() - stable["since"] > 8.0

        wait_for(settled, 120, "the resends", list(logs.values()))
        agent.send_signal(signal.SIGTERM)
        agent.wait(timeout=60)
        sent = int(
            re.search(r"(\d[\d,]*) deltas \([\d,]+ voxels", logs["agent"].read_text())
            .group(1)
            .replace(",", "")
        )
        assert sent > applied_at_cut, "the robot produced no delta during the outage"

        def all_applied() -> bool:
            return _server_stats(two_hosts["srv"], server_ep, "tiny")["stats"]["deltas_applied"] >= sent

        wait_for(all_applied, 60, f"{sent} deltas applied", list(logs.values()))
        final = _server_stats(two_hosts["srv"], server_ep, "tiny")
        assert final["stats"]["deltas_applied"] == sent  # each exactly once: no delta lost or doubled
        (epoch_acks,) = final["acks"]["r1"].values()
        assert epoch_acks == sent
        assert sum(final["stats"]["rejected"].values()) == 0
        print(
            f"partition: {applied_at_cut} deltas applied before the cut, {sent} produced in all, each "
            f"applied once after the link came back; {final['stats']['duplicates']} resent copies ignored"
        )
    finally:
        for p in procs:
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)
        for p in procs:
            try:
                p.wait(timeout=20)
            except subprocess.TimeoutExpired:
                p.kill()
