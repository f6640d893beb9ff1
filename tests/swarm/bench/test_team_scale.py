"""swarm bench team: role names, the world's run time from its log, the printed figures, one real run."""

from __future__ import annotations

import os

import pytest

from swarm.bench import team_scale
from swarm.bench.team_scale import ProcessSample, TeamRun, role_of, world_run_seconds
from swarm.cli import main
from tests.support.paths import CONFIGS

PY = ["/usr/bin/python3", "-P", "-m", "swarm.cli"]


def test_roles_come_from_the_command_lines():
    assert role_of([*PY, "agent", "--id", "r1"]) == "agent"
    assert role_of([*PY, "sim", "world", "c.yaml"]) == "world"
    assert role_of([*PY, "server", "--config", "c.yaml"]) == "server"
    assert role_of([*PY, "coordinator"]) == "coordinator"
    assert role_of([*PY, "sim", "c.yaml", "--robots", "4"]) == "runner"
    assert role_of(["/usr/bin/swarm", "sim", "c.yaml"]) == "runner"
    assert role_of(["/bin/sh", "-c", "true"]) == "other"


def test_the_world_runs_from_every_agent_being_there_to_its_last_line(tmp_path):
    log = tmp_path / "world.log"
    log.write_text(
        "2026-12-04 02:42:10,000 sim2d.simulator: waiting up to 120 s for an agent\n"
        "2026-12-04 02:42:26,027 sim2d.simulator: every robot's agent is there: running\n"
        "2026-12-04 02:43:50,751 sim2d.simulator: frame 240, sim t = 120.0 s\n"
        "max_time: 240 frames, 120.0 s simulated in 131.2 s (x0.9)\n"
    )
    assert world_run_seconds(log) == pytest.approx(84.724)
    log.write_text("2026-12-04 02:42:10,000 sim2d.simulator: waiting up to 120 s for an agent\n")
    assert world_run_seconds(log) is None  # the agents never came
    assert world_run_seconds(tmp_path / "missing.log") is None


def test_the_figures_sum_cpu_per_role_and_keep_the_largest_memory():
    big = TeamRun(16, world_run_s=60.0, wall_s=90.0)
    big.metrics = {"sim_time_s": 120.0, "initial_entropy_bits": 1000.0, "final_entropy_bits": 600.0}
    big.processes = {
        1: ProcessSample("agent", 10.0, 2.0, 500.0, 400.0, 300.0),
        2: ProcessSample("agent", 8.0, 1.0, 450.0, 420.0, 310.0),
        3: ProcessSample("server", 3.0, 0.5, 900.0, 800.0, 700.0),
    }
    roles = team_scale.role_figures(big)
    assert roles["agent"] == {
        "processes": 2,
        "cpu_s": 21.0,
        "rss_peak_mb": 500.0,
        "pss_peak_mb": 420.0,
        "pss_last_mb": 310.0,
    }
    text = team_scale.format_run(big)
    assert "x2.00 real time" in text and "entropy removed 400 bits (40.0%)" in text
    small = TeamRun(4, metrics={"initial_entropy_bits": 1000.0, "final_entropy_bits": 900.0})
    assert team_scale.speed_up(big, small) == pytest.approx(4.0)


@pytest.mark.slow
@pytest.mark.skipif(not os.path.exists("/proc/self/smaps_rollup"), reason="reads /proc (Linux)")
def test_a_real_run_measures_every_role(tmp_path, capsys):
    code = main(
        [
            "bench",
            "team",
            str(CONFIGS / "lab.yaml"),
            "--robots",
            "1",
            "--max-time",
            "4",
            "--out",
            str(tmp_path),
        ]
    )
    out = capsys.readouterr().out
    assert code == 0, out
    assert "1 robots, 4.0 s simulated" in out and "real time" in out
    for role in ("agent", "server", "world", "runner"):
        assert f"  {role} " in out, out
