"""``swarm sim --view`` and ``swarm view`` on a machine with no display (ssh, containers, CI):
the viewer window failed in view.log only, and the console said nothing."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

from swarm.view import live

MISSION = """
mission: headless
workspace: {lo: [0.0, 0.0, 0.0], hi: [2.4, 2.4, 0.8], voxel: 0.1}
floor_plan: plan.yaml
robots:
  - id: r1
    start: {x: 0.6, y: 0.6, yaw: 0.0}
rig: {mode: range, camera_height: 0.4, width: 40, height: 30}
stop: {max_time_s: 2}
sim: {agent_timeout_s: 30}
"""

PLAN = """
name: box
wall_height: 1.0
walls:
  - points: [[-0.05, -0.05], [2.45, -0.05], [2.45, 2.45], [-0.05, 2.45]]
    closed: true
"""


def headless_env() -> dict[str, str]:
    return {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY", "WAYLAND_SOCKET")}


def test_missing_display_reads_the_environment(monkeypatch):
    monkeypatch.setattr(sys, "platform", "linux")
    for name in ("DISPLAY", "WAYLAND_DISPLAY", "WAYLAND_SOCKET"):
        monkeypatch.delenv(name, raising=False)
    assert "DISPLAY" in live.missing_display()
    monkeypatch.setenv("WAYLAND_DISPLAY", "wayland-0")
    assert live.missing_display() is None
    monkeypatch.delenv("WAYLAND_DISPLAY")
    monkeypatch.setenv("DISPLAY", ":0")
    assert live.missing_display() is None
    monkeypatch.delenv("DISPLAY")
    monkeypatch.setattr(sys, "platform", "darwin")  # a Mac opens windows without X
    assert live.missing_display() is None


@pytest.mark.slow
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="displays are an X/Wayland matter")
def test_swarm_view_without_a_display_refuses_in_one_line():
    pytest.importorskip("rerun", reason="swarm view first asks for the rerun SDK")
    proc = subprocess.run(
        [sys.executable, "-m", "swarm.cli", "view", "--mission", "nowhere", "--connect", "tcp/127.0.0.1:9"],
        capture_output=True, text=True, timeout=60, env=headless_env(),
    )  # fmt: skip
    assert proc.returncode == 2, proc.stdout + proc.stderr
    (line,) = proc.stderr.strip().splitlines()
    assert line.startswith("swarm: error: no display to open a viewer window on") and "--save RUN.rrd" in line


@pytest.mark.slow
@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="displays are an X/Wayland matter")
def test_sim_view_without_a_display_says_so_and_the_mission_runs(tmp_path: Path):
    (tmp_path / "plan.yaml").write_text(PLAN)
    (tmp_path / "m.yaml").write_text(MISSION)
    out = tmp_path / "run"
    proc = subprocess.run(
        [sys.executable, "-m", "swarm.cli", "sim", str(tmp_path / "m.yaml"), "--out", str(out), "--quiet",
         "--view"],
        capture_output=True, text=True, timeout=300, env=headless_env(),
    )  # fmt: skip
    logs = "\n".join(f"--- {p.name}\n{p.read_text()[-2000:]}" for p in sorted(out.glob("*.log")))
    assert proc.returncode == 0, proc.stdout + proc.stderr + logs
    warnings = [line for line in proc.stderr.splitlines() if "--view" in line]
    assert len(warnings) == 1, proc.stderr
    assert warnings[0].startswith("runner: warning: --view: no display")
    assert "run without --view" in warnings[0] and "--view RUN.rrd" in warnings[0]
    assert (out / "metrics.json").is_file()  # the mission ran to its end
    assert not (out / "view.log").exists()  # no viewer was started to fail in the dark
