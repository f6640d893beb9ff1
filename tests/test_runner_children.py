"""The mission runner's child processes: why one exited, in the runner's own words."""

from __future__ import annotations

from pathlib import Path

from swarm.cli import main
from swarm.mission.role_processes import start_role, why_it_exited


def test_a_child_that_exits_is_explained_by_its_last_error_line(tmp_path) -> None:
    child = start_role(["server", "--config", str(tmp_path / "nowhere.yaml"), "--store", str(tmp_path / "s")],
                   tmp_path / "server.log")  # fmt: skip
    child.wait(timeout=120)
    why = why_it_exited(child)
    assert why.startswith("exited with code 2: swarm: error: ") and "nowhere.yaml" in why, why


def test_a_negative_max_time_is_refused_before_anything_starts(tmp_path, capsys) -> None:
    out = tmp_path / "run"
    lab = Path(__file__).resolve().parents[1] / "configs" / "lab.yaml"
    assert main(["sim", str(lab), "--max-time", "-5", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.strip() == "swarm: error: --max-time -5: must be > 0 (simulated seconds)", err
    assert not out.exists()


def test_a_terminated_mission_stops_every_role_and_writes_no_metrics(tmp_path) -> None:
    """SIGTERM to `swarm sim` (a job scheduler, `kill`): every role it started stops, the
    command says so and exits 130, and the run folder holds no metrics.json (a resumed study
    would take one for a finished run)."""
    import os
    import signal
    import subprocess
    import sys
    import time

    lab = Path(__file__).resolve().parents[1] / "configs" / "lab.yaml"
    out = tmp_path / "run"
    sim = subprocess.Popen(
        [sys.executable, "-m", "swarm.cli", "sim", str(lab), "--out", str(out), "--max-time", "600"],
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    lines = []
    for line in sim.stdout:  # until the world has started
        lines.append(line)
        if "sim t=" in line:
            break
    sim.send_signal(signal.SIGTERM)
    rest, _ = sim.communicate(timeout=120)
    assert sim.returncode == 130, "".join(lines) + rest
    assert "interrupted: every role was stopped" in rest
    assert not (out / "metrics.json").exists()
    time.sleep(1.0)
    mine = []
    for pid in os.listdir("/proc"):
        if pid.isdigit():
            try:
                cmdline = (Path("/proc") / pid / "cmdline").read_bytes().decode(errors="replace")
            except OSError:
                continue
            if str(out) in cmdline:
                mine.append(cmdline.replace("\0", " "))
    assert mine == [], mine
