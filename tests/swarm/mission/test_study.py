"""`swarm study`: the grid, the aggregation over seeds, --resume, Ctrl-C and one real tiny study."""

from __future__ import annotations

import argparse
import csv
import json
import math
import subprocess
import sys
import time
from pathlib import Path

import pytest

from swarm.mission import study
from swarm.mission.study import Cell, Skipped, StudySpec, expand_grid, summarize
from tests.support.missions import PLAN
from tests.support.paths import CONFIGS

# The mission of tests/system/test_mission_e2e.py with a second robot.
MISSION = """
mission: tiny
workspace: {lo: [0.0, 0.0, 0.0], hi: [2.4, 2.4, 0.8], voxel: 0.1}
floor_plan: plan.yaml
robots:
  - {id: r1, start: {x: 0.6, y: 0.6, yaw: 0.0}}
  - {id: r2, start: {x: 0.6, y: 1.8, yaw: 0.0}}
rig: {mode: range, camera_height: 0.4, width: 80, height: 60}
stop: {entropy_threshold_bits: 8000, max_time_s: 400}
sim: {agent_timeout_s: 30}
"""


def _tiny(tmp_path: Path) -> Path:
    (tmp_path / "plan.yaml").write_text(PLAN)
    path = tmp_path / "tiny.yaml"
    path.write_text(MISSION)
    return path


def _parse(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(prog="swarm study")
    study.add_arguments(parser)
    return parser.parse_args(argv)


def _never(args: list[str], log: Path) -> subprocess.Popen:
    raise AssertionError(f"the study ran a mission: swarm {' '.join(args)}")


# -- the grid ------------------------------------------------------------------------------------


def test_grid_runs_each_meaningful_cell_once_and_skips_too_many_robots(tmp_path: Path):
    a, b = tmp_path / "a.yaml", tmp_path / "b.yaml"
    a.touch()
    b.touch()
    spec = StudySpec(
        configs=(a, b),
        robots=(1, 2, 4, 8),
        strategies=("entropy", "frontier"),
        coordination=("coordinator", "none"),
        seeds=(0, 1),
        out=tmp_path / "out",
    )
    cells, skipped = expand_grid(spec, {a: 4, b: 8})

    assert skipped == [Skipped("a", 8, "asks for 8 robots; the mission places 4")]
    # Per seed: 1 robot -> entropy/none + frontier/none; N > 1 -> entropy x 2 modes + frontier/none.
    assert len(cells) == 2 * ((2 + 3 * 2) + (2 + 3 * 3))
    assert len({c.name for c in cells}) == len(cells)
    assert not [c for c in cells if c.coordination == "coordinator" and c.robots == 1]
    assert not [c for c in cells if c.coordination == "coordinator" and c.strategy != "entropy"]
    assert not [c for c in cells if c.label == "a" and c.robots == 8]
    assert {c.setting for c in cells if c.robots == 1} == {
        (lab, 1, s, "none") for lab in ("a", "b") for s in ("entropy", "frontier")
    }
    assert [c.seed for c in cells] == sorted(c.seed for c in cells)  # seeds outermost
    assert Cell(b, "config", 8, "entropy", "coordinator", 1) in cells


def test_cell_name_and_sim_arguments(tmp_path: Path):
    cell = Cell(tmp_path / "office.yaml", "config", 4, "entropy", "coordinator", 2)
    assert cell.name == "office-4r-entropy-coordinator-s2"
    args = cell.sim_args(tmp_path / "runs" / cell.name, 30.0)
    assert args[:3] == ["sim", "run", str(tmp_path / "office.yaml")]
    for option, value in [
        ("--robots", "4"),
        ("--strategy", "entropy"),
        ("--coordination", "coordinator"),
        ("--seed", "2"),
        ("--max-time", "30"),
        ("--out", str(tmp_path / "runs" / cell.name)),
    ]:
        assert args[args.index(option) + 1] == value
    assert "--quiet" in args
    ros = Cell(tmp_path / "depot.yaml", "map", 2, "frontier", "none", 0)
    assert ros.name == "depot-map-2r-frontier-none-s0"
    assert ros.sim_args(tmp_path, None)[2:4] == ["--map", str(tmp_path / "depot.yaml")]
    assert "--max-time" not in ros.sim_args(tmp_path, None)


def test_map_capacity_skips_teams_the_map_cannot_place(tmp_path: Path):
    ros_map = CONFIGS / "maps" / "tb3_sandbox.yaml"
    spec = StudySpec(maps=(ros_map,), robots=(1, 2, 200), seeds=(0,), out=tmp_path)
    capacity = study.mission_capacity(spec)
    assert 2 <= capacity[ros_map] < 200
    cells, skipped = expand_grid(spec, capacity)
    assert [s.robots for s in skipped] == [200]
    assert {c.robots for c in cells} == {1, 2}


@pytest.mark.parametrize(
    ("argv", "expected"),
    [
        (["{cfg}", "--robots", "1", "0"], "--robots: every robot count must be >= 1 (got 0)"),
        (["{tmp}/missing.yaml"], "CONFIG: {tmp}/missing.yaml: no such file"),
        (["--map", "{tmp}/nomap.yaml"], "--map: {tmp}/nomap.yaml: no such file"),
        (["{cfg}", "--seeds", "-1"], "--seeds: seeds must be >= 0 (got -1)"),
        (["{cfg}", "--jobs", "0"], "--jobs: must be >= 1 (got 0)"),
        (["{cfg}", "--max-time", "-5"], "--max-time: must be a positive number"),
        ([], "give at least one mission CONFIG or --map"),
        (["{cfg}", "{tmp}/sub/tiny.yaml"], "would both be named 'tiny'"),
    ],
)
def test_bad_options_are_named(tmp_path: Path, capsys, argv: list[str], expected: str):
    cfg = _tiny(tmp_path)
    (tmp_path / "sub").mkdir()
    (tmp_path / "sub" / "tiny.yaml").write_text(MISSION)
    fill = {"cfg": str(cfg), "tmp": str(tmp_path)}
    args = _parse([a.format(**fill) for a in argv] + ["--out", str(tmp_path / "out")])
    assert study.run(args) == 2
    assert expected.format(**fill) in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_unknown_strategy_and_bad_mission_are_named(tmp_path: Path, capsys):
    with pytest.raises(SystemExit):
        _parse(["x.yaml", "--strategies", "entropy", "greedy", "--out", "o"])
    assert "--strategies: invalid choice: 'greedy'" in capsys.readouterr().err
    bad = tmp_path / "bad.yaml"
    bad.write_text(MISSION.replace("voxel: 0.1", "voxel: -0.1"))
    (tmp_path / "plan.yaml").write_text(PLAN)
    assert study.run(_parse([str(bad), "--out", str(tmp_path / "out")])) == 2
    err = capsys.readouterr().err
    assert "CONFIG:" in err and "workspace.voxel" in err


def test_help_explains_grid_and_outputs():
    parser = argparse.ArgumentParser(prog="swarm study")
    study.add_arguments(parser)
    text = " ".join(parser.format_help().split())
    for phrase in (
        "results.csv",
        "summary.md",
        "speedup.png",
        "time_to_threshold.png",
        "--resume",
        "lower bound",
        "skipped",
        "coordination none",
    ):
        assert phrase in text, phrase


# -- aggregation ---------------------------------------------------------------------------------


def _metrics(cell: Cell, time_s: float, reached: bool, h: float, f1: float, overlap: float) -> dict:
    robots = [f"r{i + 1}" for i in range(cell.robots)]
    return {
        "config": str(cell.source),
        "robots": robots,
        "strategy": cell.strategy,
        "coordination": cell.coordination,
        "seed": cell.seed,
        "reached_threshold": reached,
        "mission_time_s": time_s if reached else None,
        "sim_time_s": time_s if not reached else time_s + 1.0,
        "wall_time_s": 3.0,
        "initial_entropy_bits": 32000.0,
        "final_entropy_bits": h,
        "threshold_bits": 8000.0,
        "occupancy_f1": f1,
        "occupancy_f1_observed": f1 + 0.05,
        "coverage_mae": 0.1,
        "explored_fraction": 0.9,
        "distance_m": {r: 10.0 * (i + 1) for i, r in enumerate(robots)},
        "bytes_shared": {r: 1000 for r in robots},
        "overlap_fraction": overlap,
        "entropy_curve": [[0.0, 32000.0], [time_s, h]],
        "stop_reason": "threshold" if reached else "world stopped (max time or all agents dead)",
    }


# (robots, coordination) -> per seed: (time, reached, final H, F1, overlap)
SYNTHETIC = {
    (1, "none"): [
        (100.0, True, 7000.0, 0.8, 0.0),
        (120.0, True, 7500.0, 0.9, 0.0),
        (150.0, False, 9000.0, 0.7, 0.0),
    ],
    (2, "coordinator"): [
        (50.0, True, 7000.0, 0.9, 0.2),
        (60.0, True, 7100.0, 0.9, 0.3),
        (70.0, True, 7200.0, 0.9, 0.4),
    ],
    (2, "none"): [
        (80.0, True, 7000.0, 0.85, 0.5),
        (100.0, True, 7000.0, 0.85, 0.6),
        (90.0, True, 7000.0, 0.85, 0.7),
    ],
}


def _write_synthetic(out: Path, cells: list[Cell]) -> None:
    for cell in cells:
        t, reached, h, f1, overlap = SYNTHETIC[(cell.robots, cell.coordination)][cell.seed]
        run_dir = out / "runs" / cell.name
        run_dir.mkdir(parents=True)
        (run_dir / "metrics.json").write_text(json.dumps(_metrics(cell, t, reached, h, f1, overlap)))


def _read_csv(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def test_resume_reads_every_run_and_aggregates_over_seeds(tmp_path: Path):
    cfg = _tiny(tmp_path)
    out = tmp_path / "study"
    spec = StudySpec(configs=(cfg,), robots=(1, 2), seeds=(0, 1, 2), out=out, resume=True)
    cells, _ = expand_grid(spec, study.mission_capacity(spec))
    assert len(cells) == 9
    _write_synthetic(out, cells)
    lines: list[str] = []

    assert study.run_study(spec, launch=_never, echo=lines.append) == 0

    assert sum("resumed from" in line for line in lines) == 9, lines
    assert any("H_th NOT reached (stopped at 150.0 s sim)" in line for line in lines)
    rows = _read_csv(out / "results.csv")
    assert len(rows) == 9 and {r["status"] for r in rows} == {"resumed"}
    two = next(r for r in rows if r["name"] == "tiny-2r-entropy-coordinator-s1")
    assert float(two["distance_total_m"]) == 30.0 and float(two["distance_mean_m"]) == 15.0
    assert int(two["bytes_total"]) == 2000
    unreached = next(r for r in rows if r["name"] == "tiny-1r-entropy-none-s2")
    assert unreached["reached_threshold"] == "False" and unreached["mission_time_s"] == ""
    assert float(unreached["time_to_threshold_s"]) == 150.0 and unreached["time_is_lower_bound"] == "True"

    summary = {(int(r["robots"]), r["coordination"]): r for r in _read_csv(out / "summary.csv")}
    assert len(summary) == 3
    one = summary[(1, "none")]
    assert (one["n_runs"], one["n_reached"], one["n_not_reached"]) == ("3", "2", "1")
    assert float(one["time_mean_s"]) == pytest.approx(370 / 3)  # 150 s of the unreached run as a bound
    assert float(one["time_std_s"]) == pytest.approx(math.sqrt(1900 / 3))
    assert one["time_is_lower_bound"] == "True"
    assert float(one["reached_time_mean_s"]) == pytest.approx(110.0)
    assert float(one["reached_time_std_s"]) == pytest.approx(math.sqrt(200))
    assert float(one["speedup"]) == 1.0
    coord = summary[(2, "coordinator")]
    assert float(coord["time_mean_s"]) == pytest.approx(60.0)
    assert float(coord["time_std_s"]) == pytest.approx(10.0)
    assert coord["time_is_lower_bound"] == "False"
    assert float(coord["speedup"]) == pytest.approx((370 / 3) / 60.0)
    assert coord["speedup_bound"] == ">="  # the 1-robot time is only a lower bound
    assert float(coord["overlap_mean"]) == pytest.approx(0.3)
    assert float(coord["final_entropy_mean_bits"]) == pytest.approx(7100.0)
    assert float(coord["distance_total_mean_m"]) == pytest.approx(30.0)
    assert float(summary[(2, "none")]["f1_mean"]) == pytest.approx(0.85)
    assert float(summary[(2, "none")]["speedup"]) == pytest.approx((370 / 3) / 90.0)

    md = (out / "summary.md").read_text()
    row1 = next(line for line in md.splitlines() if line.startswith("| tiny | 1 |"))
    assert ">= 123.3 ± 25.2 (1 not reached)" in row1
    assert "110.0 ± 14.1 (n=2)" in row1 and "| 2/3 |" in row1
    row2 = next(line for line in md.splitlines() if line.startswith("| tiny | 2 | entropy | coordinator |"))
    assert "| 60.0 ± 10.0 |" in row2 and "60.0 ± 10.0 (n=3)" in row2 and "| 3/3 |" in row2
    assert "| >= 2.06 |" in row2 and "| 7,100 |" in row2 and "| 0.300 |" in row2
    assert (out / "time_to_threshold.png").stat().st_size > 0
    assert (out / "speedup.png").stat().st_size > 0


def _row(robots: int, seed: int, time_s: float, reached: bool, config: str = "c") -> dict:
    return {
        "config": config,
        "robots": robots,
        "strategy": "entropy",
        "coordination": "none",
        "seed": seed,
        "status": "ran",
        "reached_threshold": reached,
        "mission_time_s": time_s if reached else None,
        "time_to_threshold_s": time_s,
        "final_entropy_bits": 1.0,
        "overlap_fraction": None,
        "occupancy_f1": None,
        "occupancy_f1_observed": None,
        "explored_fraction": None,
        "distance_total_m": None,
        "distance_mean_m": None,
        "bytes_total": None,
    }


def test_speedup_bounds_and_failed_runs_in_the_summary():
    rows = [
        _row(1, 0, 100.0, True),
        _row(4, 0, 40.0, False),  # the team's time is a lower bound: speed-up at most 2.5
        _row(4, 1, 40.0, True),
        {**_row(4, 2, 0.0, False), "status": "failed"},
        _row(1, 0, 300.0, False, "d"),  # both lower bounds: no bound on the speed-up
        _row(2, 0, 200.0, False, "d"),
    ]
    by_key = {(s.config, s.robots): s for s in summarize(rows)}
    four = by_key[("c", 4)]
    assert (four.n_runs, four.n_failed, four.n_reached, four.n_not_reached) == (2, 1, 1, 1)
    assert four.speedup == pytest.approx(2.5) and four.speedup_bound == "<="
    assert four.reached_time_mean_s == 40.0 and four.reached_time_std_s is None
    assert by_key[("d", 2)].speedup == pytest.approx(1.5) and by_key[("d", 2)].speedup_bound == "?"
    assert by_key[("c", 1)].speedup == 1.0 and by_key[("c", 1)].speedup_bound == ""


@pytest.mark.slow
def test_failed_cell_is_recorded_with_its_log_and_the_study_goes_on(tmp_path: Path):
    cfg = _tiny(tmp_path)
    out = tmp_path / "study"
    spec = StudySpec(configs=(cfg,), robots=(1, 2), coordination=("none",), seeds=(0,), out=out)
    cells, _ = expand_grid(spec, {cfg: 2})
    _write_synthetic(out, [cells[1]])  # the 2-robot run "succeeds" by leaving its metrics
    calls: list[list[str]] = []

    def fake(args: list[str], log: Path) -> subprocess.Popen:
        calls.append(args)
        code = 3 if "--robots" in args and args[args.index("--robots") + 1] == "1" else 0
        log.parent.mkdir(parents=True, exist_ok=True)
        return subprocess.Popen(
            [sys.executable, "-c", f"print('boom'); raise SystemExit({code})"], stdout=log.open("w")
        )

    lines: list[str] = []
    assert study.run_study(spec, launch=fake, echo=lines.append) == 1
    assert len(calls) == 2  # without --resume the existing folder is run again
    rows = {r["name"]: r for r in _read_csv(out / "results.csv")}
    failed = rows["tiny-1r-entropy-none-s0"]
    assert failed["status"] == "failed" and failed["note"] == "exit 3"
    assert Path(failed["log"]).read_text().strip() == "boom"
    assert rows["tiny-2r-entropy-none-s0"]["status"] == "ran"
    assert any("FAILED (exit 3), log:" in line for line in lines)
    md = (out / "summary.md").read_text()
    assert "## Failed runs" in md and "tiny-1r-entropy-none-s0: exit 3" in md


# -- Ctrl-C --------------------------------------------------------------------------------------

SLEEPER = """
import pathlib, signal, sys, time
signal.signal(signal.SIGINT, signal.default_int_handler)  # as launch_sim's children (CI may ignore it)
flag = pathlib.Path(sys.argv[1])
try:
    flag.write_text("ready")
    time.sleep(60)
except KeyboardInterrupt:
    flag.write_text("stopped cleanly")
    raise SystemExit(130)
"""


def test_interrupt_stops_the_running_missions_cleanly(tmp_path: Path):
    cfg = _tiny(tmp_path)
    out = tmp_path / "study"
    spec = StudySpec(configs=(cfg,), robots=(1, 2), coordination=("none",), seeds=(0,), jobs=2, out=out)
    flag = tmp_path / "flag"
    procs: list[subprocess.Popen] = []

    def sleeper(args: list[str], log: Path) -> subprocess.Popen:
        procs.append(subprocess.Popen([sys.executable, "-c", SLEEPER, str(flag)], start_new_session=True))
        return procs[-1]

    interrupted_at: list[float] = []

    def echo(line: str) -> None:
        if line.startswith("[2/2]") and line.endswith("started"):  # Ctrl-C while mission 1 runs
            deadline = time.monotonic() + 120  # a loaded machine starts Python slowly
            while not flag.exists() and time.monotonic() < deadline:
                time.sleep(0.05)
            interrupted_at.append(time.monotonic())
            raise KeyboardInterrupt

    assert study.run_study(spec, launch=sleeper, echo=echo) == 130
    assert time.monotonic() - interrupted_at[0] < 20  # stopped without the 60 s grace
    assert len(procs) == 1 and procs[0].returncode == 130
    assert flag.read_text() == "stopped cleanly"
    assert _read_csv(out / "results.csv") == []
    assert "INTERRUPTED" in (out / "summary.md").read_text()


# -- a real study --------------------------------------------------------------------------------


@pytest.mark.slow
def test_tiny_study_end_to_end(tmp_path: Path):
    cfg = _tiny(tmp_path)
    out = tmp_path / "study"
    cmd = [
        sys.executable,
        "-m",
        "swarm.cli",
        "study",
        str(cfg),
        "--robots",
        "1",
        "2",
        "--coordination",
        "none",
        "--seeds",
        "0",
        "--max-time",
        "8",
        "--jobs",
        "2",
        "--out",
        str(out),
    ]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=240)
    logs = "\n".join(f"--- {p}\n{p.read_text()[-2000:]}" for p in sorted(out.glob("logs/*.log")))
    assert proc.returncode == 0, proc.stdout + proc.stderr + logs
    assert "[1/2]" in proc.stdout and "[2/2]" in proc.stdout and "ETA" in proc.stdout
    rows = _read_csv(out / "results.csv")
    assert [r["name"] for r in rows] == ["tiny-1r-entropy-none-s0", "tiny-2r-entropy-none-s0"]
    for r in rows:
        assert r["status"] == "ran"
        assert 0 < float(r["sim_time_s"]) <= 8.5
        assert float(r["final_entropy_bits"]) < float(r["initial_entropy_bits"])
        assert (Path(r["run_dir"]) / "metrics.json").exists()
    assert len(_read_csv(out / "summary.csv")) == 2
    for name in ("time_to_threshold.png", "speedup.png", "summary.md"):
        assert (out / name).stat().st_size > 0, name

    again = subprocess.run(cmd + ["--resume"], capture_output=True, text=True, timeout=60)
    assert again.returncode == 0, again.stdout + again.stderr
    assert again.stdout.count("resumed from") == 2 and "started" not in again.stdout


def test_resume_reruns_a_cell_run_with_another_max_time_or_threshold() -> None:
    """--resume takes a run folder only when it was run with the study's --max-time and
    --observable-threshold, not merely for the same cell."""
    from swarm.mission.study.grid import Cell, StudySpec
    from swarm.mission.study.runner import _matches

    lab = Path("configs/lab.yaml")
    cell = Cell(source=lab, kind="config", robots=1, strategy="entropy", coordination="none", seed=0)
    metrics = {"robots": ["r1"], "strategy": "entropy", "coordination": "none", "seed": 0}
    metrics |= {"max_time_s": 30.0, "threshold_parts": {"fraction": 0.16}}
    spec = StudySpec(configs=(lab,), robots=(1,), max_time_s=30.0, observable_threshold=0.16, out=Path("s"))
    assert _matches(cell, metrics, spec)
    assert not _matches(cell, metrics, spec.model_copy(update={"max_time_s": 60.0}))
    assert not _matches(cell, metrics, spec.model_copy(update={"observable_threshold": 0.5}))
    assert _matches(cell, metrics, spec.model_copy(update={"max_time_s": None, "observable_threshold": None}))
