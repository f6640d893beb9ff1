"""`swarm sim --secure`: a mission where every role holds its own certificate and the map server is
the TLS router enforcing the access rules. One robot keeps it short (the coordinator's side of the
rules is shown in tests/swarm/security/test_team_bus.py on real sessions)."""

import json
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from swarm.formats.map_file import load_map
from swarm.formats.octomap_file import write_bt
from swarm.formats.octomap_map import coverage_to_leaves, states_to_prior
from swarm.map.grid import Grid
from tests.support.missions import MISSION, PLAN
from tests.support.prior_mission import MISSION as PRIOR_MISSION

pytestmark = pytest.mark.slow  # whole missions: every role a process


def test_secure_mission_reaches_its_threshold(tmp_path: Path):
    (tmp_path / "plan.yaml").write_text(PLAN)
    (tmp_path / "tiny.yaml").write_text(MISSION)
    out = tmp_path / "run"
    cmd = [sys.executable, "-m", "swarm.cli", "sim", str(tmp_path / "tiny.yaml"), "--out", str(out)]
    proc = subprocess.run([*cmd, "--secure", "--quiet"], capture_output=True, text=True, timeout=300)
    logs = "\n".join(f"--- {p.name}\n{p.read_text()[-3000:]}" for p in sorted(out.glob("*.log")))
    assert proc.returncode == 0, proc.stdout + proc.stderr + logs
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["reached_threshold"] is True, f"{proc.stdout}\n{logs}"
    assert metrics["server_map_max_rel_diff"] <= 1e-5  # the server saw every delta the monitor did
    server_log = (out / "server.log").read_text()
    assert re.search(r"listening on tls/127\.0\.0\.1:\d+", server_log)
    assert re.search(r" 0 rejected", server_log)
    agent_log = (out / "agent-r1.log").read_text()
    assert re.search(r"\b[1-9][\d,]* deltas \([\d,]+ voxels", agent_log), logs
    for identity in ("server", "coordinator", "world", "tool", "agent-r1", "source-r1"):
        assert (out / "security" / identity / "zenoh.json5").is_file()


def test_secure_mission_on_a_two_shard_map_service(tmp_path: Path):
    """``map_service: {shards: 2}`` with --secure: shard 0 is the TLS router with the rules, shard 1
    connects to it as ``server-shard-1``; the robot shares with both and the mission reaches H_th
    with the shards' map equal to the monitor's (docs/sharding.md)."""
    (tmp_path / "plan.yaml").write_text(PLAN)
    (tmp_path / "tiny.yaml").write_text(MISSION + "map_service: {shards: 2}\n")
    out = tmp_path / "run"
    cmd = [sys.executable, "-m", "swarm.cli", "sim", str(tmp_path / "tiny.yaml"), "--out", str(out)]
    proc = subprocess.run([*cmd, "--secure"], capture_output=True, text=True, timeout=240)
    logs = "\n".join(f"--- {p.name}\n{p.read_text()[-3000:]}" for p in sorted(out.glob("*.log")))
    assert proc.returncode == 0, proc.stdout + proc.stderr + logs
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["reached_threshold"] is True, f"{proc.stdout}\n{logs}"
    (final,) = [
        line for line in proc.stdout.splitlines() if line.startswith("final, after the shutdown flush")
    ]
    monitor_h = re.search(r"^final, after the shutdown flush: H=([\d,]+) bits", final).group(1)
    assert re.search(r"the map server's map: H=([\d,]+) bits", final).group(1) == monitor_h, final
    shard0, shard1 = ((out / f"server-shard-{k}.log").read_text() for k in (0, 1))
    assert re.search(r"listening on tls/127\.0\.0\.1:\d+", shard0)
    assert re.search(r"connected to tls/127\.0\.0\.1:\d+ \(listening on none\)", shard1)
    for log in (shard0, shard1):
        assert re.search(r"[1-9][\d,]* deltas applied", log) and " 0 rejected" in log, logs
    assert "started from 2 of 2 map server shards' snapshots" in (out / "agent-r1.log").read_text()
    for identity in ("server", "server-shard-1", "agent-r1", "operator"):
        assert (out / "security" / identity / "zenoh.json5").is_file()


@pytest.mark.parametrize("service", ["", "map_service: {shards: 2}\n"], ids=["one-server", "two-shards"])
def test_secure_mission_loads_a_previous_map_as_the_operator(tmp_path: Path, service: str):
    """The runner's `operator` certificate may put delta/prior (with two shards, each shard's
    `shard/K/delta/prior`, its slab's part); the server takes the previous map. The known part
    (x >= 1.4 m) lies in shard 1's slab of the two."""
    grid = Grid((0.0, 0.0, 0.0), 0.1, (24, 24, 8))
    states = np.zeros(grid.shape, np.uint8)
    states[14:, :, :] = 1
    leaves = coverage_to_leaves(states_to_prior(grid, states, known_sigma=0.1))
    write_bt(tmp_path / "previous.bt", leaves.resolution, leaves.key, leaves.occupied)
    (tmp_path / "m.yaml").write_text(PRIOR_MISSION + service)
    out = tmp_path / "run"
    cmd = [sys.executable, "-m", "swarm.cli", "sim", str(tmp_path / "m.yaml"), "--out", str(out)]
    proc = subprocess.run([*cmd, "--secure", "--quiet"], capture_output=True, text=True, timeout=180)
    logs = "\n".join(f"--- {p.name}\n{p.read_text()[-2000:]}" for p in sorted(out.glob("*.log")))
    assert proc.returncode == 0, proc.stdout + proc.stderr + logs
    assert "started from the previous map" in proc.stdout
    final = load_map(out / "server_map.npz")
    far = np.zeros(grid.shape, bool)
    far[14:, :, :] = True
    assert np.all(final.sigma().reshape(grid.shape)[far] <= 0.1 + 1e-4)
