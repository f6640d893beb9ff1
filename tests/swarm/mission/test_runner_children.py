"""The mission runner's child processes: why one exited, in the runner's own words."""

from __future__ import annotations

from pathlib import Path

import pytest

from swarm.cli import main
from swarm.mission.role_processes import start_role, why_it_exited
from tests.support.paths import CONFIGS


@pytest.mark.slow
def test_a_child_that_exits_is_explained_by_its_last_error_line(tmp_path) -> None:
    child = start_role(["server", "--config", str(tmp_path / "nowhere.yaml"), "--store", str(tmp_path / "s")],
                   tmp_path / "server.log")  # fmt: skip
    child.wait(timeout=120)
    why = why_it_exited(child)
    assert why.startswith("exited with code 2: swarm: error: ") and "nowhere.yaml" in why, why


def test_a_negative_max_time_is_refused_before_anything_starts(tmp_path, capsys) -> None:
    out = tmp_path / "run"
    lab = CONFIGS / "lab.yaml"
    assert main(["sim", str(lab), "--max-time", "-5", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.strip() == "swarm: error: --max-time -5: must be > 0 (simulated seconds)", err
    assert not out.exists()


@pytest.mark.slow
def test_a_terminated_mission_stops_every_role_and_says_where_its_run_folder_is(tmp_path) -> None:
    """SIGTERM to `swarm sim` (a job scheduler, `kill`): every role it started stops, the run
    folder is written from the map server's map with ``interrupted: true`` (a resumed study
    runs it again), the command says where and exits 130."""
    import json
    import os
    import signal
    import subprocess
    import sys
    import time

    from tests.support.endless_lab import endless_lab

    lab = endless_lab(tmp_path)  # it must not end by itself before the SIGTERM
    out = tmp_path / "run"
    sim = subprocess.Popen(
        [sys.executable, "-m", "swarm.cli", "sim", str(lab), "--out", str(out), "--max-time", "600"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    lines = []
    for line in sim.stdout:  # until the world has started
        lines.append(line)
        if "sim t=" in line and "sim t=    0.0" not in line:
            break
    sim.send_signal(signal.SIGTERM)
    rest, _ = sim.communicate(timeout=120)
    assert sim.returncode == 130, "".join(lines) + rest
    assert "swarm: interrupted (SIGTERM)" in rest and "wrote metrics.json" in rest, rest
    assert json.loads((out / "metrics.json").read_text())["interrupted"] is True
    time.sleep(1.0)
    mine = []
    for pid in os.listdir("/proc"):
        if pid.isdigit():
            try:
                cmdline = (Path("/proc") / pid / "cmdline").read_bytes().decode(errors="replace")
                state = (Path("/proc") / pid / "stat").read_text().rsplit(")", 1)[1].split()[0]
            except OSError:
                continue
            if str(out) in cmdline and state != "Z":
                mine.append(cmdline.replace("\0", " "))
    assert mine == [], mine


def test_the_stop_reason_says_which_end_the_world_reached() -> None:
    """A mission that ended by itself said "world stopped (max time or all agents dead)"; a
    user had to read world.log to learn which. The runner now tells them apart from the
    world's last truth message."""
    from types import SimpleNamespace

    from swarm.config import load_mission
    from swarm.mission.runner import why_the_world_stopped

    lab = load_mission(CONFIGS / "lab.yaml")
    lab = lab.model_copy(update={"stop": lab.stop.model_copy(update={"max_time_s": 40.0})})
    ids = lab.robot_ids

    def reason(sim_time: float, dead: list[str]) -> str:
        return why_the_world_stopped(SimpleNamespace(sim_time=sim_time, dead=dead), lab)

    assert reason(40.0, []) == "max time (40 s simulated)"
    assert reason(40.0 - lab.sim.frame_period_s, []) == "max time (40 s simulated)"  # last message unread
    dead = reason(12.5, list(ids))
    assert dead.startswith(f"every agent dead ({', '.join(ids)}") and "agent_timeout_s" in dead
    assert reason(12.5, list(ids[:-1])) == "world stopped"  # one agent still live: not known why


TINY = """
mission: tiny
workspace: {lo: [0.0, 0.0, 0.0], hi: [2.4, 2.4, 0.8], voxel: 0.1}
floor_plan: plan.yaml
robots:
  - id: r1
    start: {x: 0.6, y: 0.6, yaw: 0.0}
rig: {mode: range, camera_height: 0.4, width: 40, height: 30}
stop: {max_time_s: 2}
sim: {agent_timeout_s: 30}
"""

BOX = """
name: box
wall_height: 1.0
walls:
  - points: [[-0.05, -0.05], [2.45, -0.05], [2.45, 2.45], [-0.05, 2.45]]
    closed: true
"""


@pytest.mark.slow
def test_a_mission_that_runs_out_of_time_says_so(tmp_path: Path) -> None:
    import json
    import subprocess
    import sys

    (tmp_path / "plan.yaml").write_text(BOX)
    (tmp_path / "m.yaml").write_text(TINY)
    out = tmp_path / "run"
    proc = subprocess.run(
        [sys.executable, "-m", "swarm.cli", "sim", str(tmp_path / "m.yaml"), "--out", str(out), "--quiet"],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stdout + proc.stderr
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["reached_threshold"] is False
    assert metrics["stop_reason"] == "max time (2 s simulated)"
    assert "stopped: max time (2 s simulated);" in proc.stdout
