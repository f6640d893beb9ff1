"""The mission runner's child processes: why one exited, in the runner's own words."""

from __future__ import annotations

from pathlib import Path

from swarm.cli import main
from swarm.mission.runner import _child, why_it_exited


def test_a_child_that_exits_is_explained_by_its_last_error_line(tmp_path) -> None:
    child = _child(["server", "--config", str(tmp_path / "nowhere.yaml"), "--store", str(tmp_path / "s")],
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
