"""``swarm study``: run a grid of missions and compare them (DESIGN.md section 7).

A study crosses mission sources (CONFIG files and ``--map`` ROS maps) with robot counts,
strategies, coordination modes and seeds. Each point of that grid is a *cell*: one
``swarm sim`` run, started as a subprocess that writes its run folder to
``DIR/runs/<name>`` (name = ``<config>-<N>r-<strategy>-<coordination>-s<seed>``) and its
console output to ``DIR/logs/<name>.log``. Cells that mean the same mission are run once:
coordination only matters for more than one robot with the entropy strategy, so the other
cells run as coordination ``none``. A cell asking for more robots than its mission places
is reported and skipped.

When every cell has ended the study writes ``results.csv`` (one row per run),
``summary.csv`` and ``summary.md`` (one row per *setting*: a cell without its seed,
aggregated over seeds), ``time_to_threshold.png`` and ``speedup.png``. A run that did not
reach H_th contributes its sim time as a lower bound of its time to H_th; every mean that
includes one is marked (``>=``), and the runs that did reach H_th are also summarised alone.

``swarm study ... --resume`` reads the cells whose run folder already holds a metrics.json
instead of running them again, so an interrupted study can be finished.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, ValidationError, field_validator, model_validator

Strategy = Literal["entropy", "frontier", "random"]
Coordination = Literal["coordinator", "none"]
STRATEGIES: tuple[str, ...] = ("entropy", "frontier", "random")
COORDINATIONS: tuple[str, ...] = ("coordinator", "none")

#: The command-line option behind each field of :class:`StudySpec` (for error messages).
OPTION_OF = {
    "configs": "CONFIG",
    "maps": "--map",
    "robots": "--robots",
    "strategies": "--strategies",
    "coordination": "--coordination",
    "seeds": "--seeds",
    "max_time_s": "--max-time",
    "jobs": "--jobs",
    "out": "--out",
    "resume": "--resume",
}
#: Seconds a mission gets to stop its processes after Ctrl-C before its process group is killed.
STOP_GRACE_S = 60.0


class StudyError(ValueError):
    """An invalid study: the message names the option and the problem."""


# -- the grid ----------------------------------------------------------------------------------


def _unique(values: Iterable[Any]) -> tuple:
    out: list[Any] = []
    for v in values:
        if v not in out:
            out.append(v)
    return tuple(out)


class StudySpec(BaseModel):
    """A study: the grid of missions to run and where to write it."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    configs: tuple[Path, ...] = ()
    maps: tuple[Path, ...] = ()
    robots: tuple[int, ...] = (1, 2, 4)
    strategies: tuple[Strategy, ...] = ("entropy",)
    coordination: tuple[Coordination, ...] = ("coordinator", "none")
    seeds: tuple[int, ...] = (0, 1, 2)
    max_time_s: float | None = None
    jobs: int = 1
    out: Path
    resume: bool = False

    @field_validator("configs", "maps")
    @classmethod
    def _files_exist(cls, paths: tuple[Path, ...]) -> tuple[Path, ...]:
        for p in paths:
            if not p.is_file():
                raise ValueError(f"{p}: no such file")
        return _unique(paths)

    @field_validator("robots")
    @classmethod
    def _robots_positive(cls, robots: tuple[int, ...]) -> tuple[int, ...]:
        if not robots:
            raise ValueError("give at least one robot count")
        bad = [n for n in robots if n < 1]
        if bad:
            raise ValueError(f"every robot count must be >= 1 (got {bad[0]})")
        return _unique(robots)

    @field_validator("seeds")
    @classmethod
    def _seeds_valid(cls, seeds: tuple[int, ...]) -> tuple[int, ...]:
        if not seeds:
            raise ValueError("give at least one seed")
        bad = [s for s in seeds if s < 0]
        if bad:
            raise ValueError(f"seeds must be >= 0 (got {bad[0]})")
        return _unique(seeds)

    @field_validator("strategies", "coordination")
    @classmethod
    def _not_empty(cls, values: tuple[str, ...]) -> tuple[str, ...]:
        if not values:
            raise ValueError("give at least one value")
        return _unique(values)

    @field_validator("max_time_s")
    @classmethod
    def _max_time_positive(cls, t: float | None) -> float | None:
        if t is not None and not (math.isfinite(t) and t > 0):
            raise ValueError(f"must be a positive number of sim seconds (got {t})")
        return t

    @field_validator("jobs")
    @classmethod
    def _jobs_positive(cls, jobs: int) -> int:
        if jobs < 1:
            raise ValueError(f"must be >= 1 (got {jobs})")
        return jobs

    @model_validator(mode="after")
    def _sources(self) -> StudySpec:
        if not self.configs and not self.maps:
            raise ValueError("give at least one mission CONFIG or --map MAP.yaml")
        labels: dict[str, Path] = {}
        for path, kind in self.sources:
            label = source_label(path, kind)
            if label in labels:
                raise ValueError(f"{labels[label]} and {path} would both be named {label!r}; rename one")
            labels[label] = path
        return self

    @property
    def sources(self) -> list[tuple[Path, str]]:
        """(path, kind) of every mission source, kind "config" or "map"."""
        return [(p, "config") for p in self.configs] + [(p, "map") for p in self.maps]


def source_label(path: Path, kind: str) -> str:
    """The name of a mission source in run names and tables: the file stem, ``-map`` for ROS maps."""
    return Path(path).stem + ("-map" if kind == "map" else "")


def effective_coordination(robots: int, strategy: str, coordination: str) -> str:
    """The coordination a mission really uses: only entropy teams of 2+ robots have a coordinator."""
    return coordination if robots > 1 and strategy == "entropy" else "none"


@dataclass(frozen=True)
class Cell:
    """One mission of the study: a point of the grid, run once."""

    source: Path
    kind: str  # "config" or "map"
    robots: int
    strategy: str
    coordination: str
    seed: int

    @property
    def label(self) -> str:
        return source_label(self.source, self.kind)

    @property
    def name(self) -> str:
        return f"{self.label}-{self.robots}r-{self.strategy}-{self.coordination}-s{self.seed}"

    @property
    def setting(self) -> tuple[str, int, str, str]:
        """The cell without its seed: (label, robots, strategy, coordination)."""
        return (self.label, self.robots, self.strategy, self.coordination)

    def sim_args(self, out: Path, max_time_s: float | None) -> list[str]:
        """Arguments of ``swarm`` that run this cell into run folder ``out``."""
        where = [str(self.source)] if self.kind == "config" else ["--map", str(self.source)]
        args = ["sim", "run", *where, "--robots", str(self.robots), "--strategy", self.strategy]
        args += ["--coordination", self.coordination, "--seed", str(self.seed), "--quiet", "--out", str(out)]
        if max_time_s is not None:
            args += ["--max-time", f"{max_time_s:g}"]
        return args


@dataclass(frozen=True)
class Skipped:
    """Cells of a source and robot count that were not run, and why."""

    label: str
    robots: int
    reason: str


def expand_grid(spec: StudySpec, capacity: Mapping[Path, int]) -> tuple[list[Cell], list[Skipped]]:
    """The cells of ``spec``, seeds outermost, and the skipped (source, robots) pairs.

    ``capacity`` maps each source path to the most robots its mission places. Cells whose
    coordination makes no difference (one robot, or a strategy other than entropy) are run
    once as coordination ``none``; duplicates are dropped.
    """
    cells: list[Cell] = []
    skipped: list[Skipped] = []
    for path, kind in spec.sources:
        cap = capacity[path]
        for n in spec.robots:
            if n > cap:
                reason = f"asks for {n} robots; the mission places {cap}"
                skipped.append(Skipped(source_label(path, kind), n, reason))
    too_many = {(s.label, s.robots) for s in skipped}
    for seed in spec.seeds:
        for path, kind in spec.sources:
            for n in spec.robots:
                if (source_label(path, kind), n) in too_many:
                    continue
                for strategy in spec.strategies:
                    for coordination in spec.coordination:
                        coord = effective_coordination(n, strategy, coordination)
                        cell = Cell(path, kind, n, strategy, coord, seed)
                        if cell not in cells:
                            cells.append(cell)
    return cells, skipped


def mission_capacity(spec: StudySpec) -> dict[Path, int]:
    """The most robots each source's mission places (for a ROS map: the most of those asked for)."""
    from swarm.config import ConfigError, load_mission, mission_from_map

    capacity: dict[Path, int] = {}
    for path in spec.configs:
        try:
            capacity[path] = len(load_mission(path).robots)
        except ConfigError as exc:
            raise StudyError(f"CONFIG: {exc}") from exc
    for path in spec.maps:
        error: ConfigError | None = None
        for n in sorted(spec.robots, reverse=True):
            try:
                mission_from_map(path, robots=n)
            except ConfigError as exc:
                error = exc
                continue
            capacity[path] = n
            break
        else:
            raise StudyError(f"--map: {error}")
    return capacity


# -- running the cells ---------------------------------------------------------------------------

#: Starts ``swarm ARGS`` writing its output to the log file; returns the process.
Launcher = Callable[[list[str], Path], subprocess.Popen]


def launch_sim(args: list[str], log_path: Path) -> subprocess.Popen:
    """``python -m swarm.cli ARGS`` in its own session (Ctrl-C reaches it through the study only)."""
    log_path.parent.mkdir(parents=True, exist_ok=True)
    with open(log_path, "w") as log:
        return subprocess.Popen(
            [sys.executable, "-m", "swarm.cli", *args],
            stdout=log,
            stderr=subprocess.STDOUT,
            env={**os.environ, "PYTHONUNBUFFERED": "1"},
            start_new_session=True,
            preexec_fn=_default_sigint,  # a study started in the background ignores SIGINT; its runs must not
        )


def _default_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)


@dataclass
class RunResult:
    """What became of one cell: ``ran`` or ``resumed`` (with metrics) or ``failed``."""

    cell: Cell
    status: str
    run_dir: Path
    log: Path | None = None
    metrics: dict[str, Any] | None = None
    returncode: int | None = None
    wall_s: float | None = None
    note: str = ""


def read_metrics(run_dir: Path) -> dict[str, Any] | None:
    """The run folder's metrics.json, or None when it is missing or unreadable."""
    try:
        data = json.loads((run_dir / "metrics.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return data if isinstance(data, dict) else None


def _matches(cell: Cell, metrics: Mapping[str, Any]) -> bool:
    return (
        len(metrics.get("robots") or []) == cell.robots
        and metrics.get("strategy") == cell.strategy
        and metrics.get("coordination") == cell.coordination
        and metrics.get("seed") == cell.seed
    )


def _duration(seconds: float) -> str:
    s = int(round(seconds))
    if s < 60:
        return f"{s}s"
    if s < 3600:
        return f"{s // 60}m{s % 60:02d}s"
    return f"{s // 3600}h{(s % 3600) // 60:02d}m"


def outcome_text(metrics: Mapping[str, Any]) -> str:
    """``reached H_th at 123.4 s, final H 7,900 bits`` or the not-reached equivalent."""
    final = metrics.get("final_entropy_bits")
    h = f"final H {final:,.0f} bits" if isinstance(final, int | float) else "final H ?"
    if metrics.get("reached_threshold"):
        return f"reached H_th at {metrics.get('mission_time_s', float('nan')):.1f} s, {h}"
    sim = metrics.get("sim_time_s")
    sim_text = f"{sim:.1f}" if isinstance(sim, int | float) else "?"
    return f"H_th NOT reached (stopped at {sim_text} s sim), {h}"


def _signal_group(proc: subprocess.Popen, sig: int) -> None:
    """Send ``sig`` to the process group of ``proc`` (its own session), ignoring a vanished group."""
    try:
        os.killpg(proc.pid, sig)
    except (ProcessLookupError, PermissionError):
        pass


def stop_children(procs: Sequence[subprocess.Popen], grace_s: float = STOP_GRACE_S) -> None:
    """Stop running missions cleanly: SIGINT to each runner (it stops its own processes), then
    wait up to ``grace_s``; whatever is left of their process groups is killed."""
    for p in procs:
        if p.poll() is None:
            p.send_signal(signal.SIGINT)
    deadline = time.monotonic() + grace_s
    try:
        for p in procs:
            try:
                p.wait(timeout=max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                pass
    except KeyboardInterrupt:
        pass  # a second Ctrl-C: no more waiting
    for p in procs:
        _signal_group(p, signal.SIGKILL)  # leftovers: a runner that hung, or children it could not stop
        p.wait()


def execute(
    cells: Sequence[Cell],
    spec: StudySpec,
    launch: Launcher = launch_sim,
    echo: Callable[[str], None] = print,
    poll_s: float = 0.5,
) -> tuple[list[RunResult], bool]:
    """Run (or, with ``spec.resume``, read) every cell, ``spec.jobs`` at a time.

    Returns the results in cell order and whether the study was interrupted (Ctrl-C or
    SIGTERM: the running missions are stopped and left out of the results).
    """
    out = spec.out
    total = len(cells)
    results: dict[int, RunResult] = {}
    running: dict[int, tuple[subprocess.Popen, float]] = {}
    walls: list[float] = []
    started = time.monotonic()
    pending = list(range(total))

    def report(k: int, text: str) -> None:
        elapsed = time.monotonic() - started
        left = total - len(results)
        if walls:
            eta = _duration(sum(walls) / len(walls) * left / min(spec.jobs, max(left, 1)))
        else:
            eta = "?" if left else "0s"
        echo(f"[{k + 1}/{total}] {cells[k].name}: {text} | elapsed {_duration(elapsed)}, ETA {eta}")

    def finish(k: int, proc: subprocess.Popen, t0: float) -> None:
        cell = cells[k]
        run_dir, log = out / "runs" / cell.name, out / "logs" / f"{cell.name}.log"
        wall = time.monotonic() - t0
        metrics = read_metrics(run_dir) if proc.returncode == 0 else None
        if metrics is None:
            _signal_group(proc, signal.SIGTERM)  # a crashed runner may leave its processes behind
            why = f"exit {proc.returncode}" if proc.returncode else "exit 0 but no metrics.json"
            results[k] = RunResult(cell, "failed", run_dir, log, None, proc.returncode, wall, why)
            report(k, f"FAILED ({why}), log: {log}")
        else:
            walls.append(wall)
            results[k] = RunResult(cell, "ran", run_dir, log, metrics, 0, wall)
            report(k, f"{outcome_text(metrics)} (wall {_duration(wall)})")

    interrupted = False
    try:
        while pending or running:
            while pending and len(running) < spec.jobs:
                k = pending.pop(0)
                cell = cells[k]
                run_dir = out / "runs" / cell.name
                if spec.resume:
                    metrics = read_metrics(run_dir)
                    if metrics is not None and _matches(cell, metrics):
                        log = out / "logs" / f"{cell.name}.log"
                        results[k] = RunResult(
                            cell, "resumed", run_dir, log if log.exists() else None, metrics
                        )
                        report(k, f"resumed from {run_dir / 'metrics.json'}: {outcome_text(metrics)}")
                        continue
                    if metrics is not None:
                        echo(f"[{k + 1}/{total}] {cell.name}: metrics.json does not match the cell; running")
                echo(f"[{k + 1}/{total}] {cell.name}: started")
                args = cell.sim_args(run_dir, spec.max_time_s)
                running[k] = (launch(args, out / "logs" / f"{cell.name}.log"), time.monotonic())
            for k in list(running):
                proc, t0 = running[k]
                if proc.poll() is not None:
                    del running[k]
                    finish(k, proc, t0)
            if running:
                time.sleep(poll_s)
    except KeyboardInterrupt:
        interrupted = True
        names = ", ".join(cells[k].name for k in running) or "none"
        echo(
            f"interrupted: stopping the running missions ({names}), which are not recorded; waiting up "
            f"to {STOP_GRACE_S:g} s for them to stop their processes (Ctrl-C again to kill them now)"
        )
        stop_children([proc for proc, _ in running.values()])
    return [results[k] for k in sorted(results)], interrupted


# -- tables ----------------------------------------------------------------------------------------

RESULT_COLUMNS = (
    "name",
    "status",
    "config",
    "source",
    "robots",
    "strategy",
    "coordination",
    "seed",
    "reached_threshold",
    "mission_time_s",
    "sim_time_s",
    "time_to_threshold_s",
    "time_is_lower_bound",
    "wall_time_s",
    "initial_entropy_bits",
    "final_entropy_bits",
    "threshold_bits",
    "occupancy_f1",
    "occupancy_f1_observed",
    "coverage_mae",
    "coverage_mae_observed",
    "explored_fraction",
    "overlap_fraction",
    "overlap_halfway",
    "overlap_before_threshold",
    "distance_total_m",
    "distance_mean_m",
    "distance_max_m",
    "bytes_total",
    "bytes_mean",
    "stop_reason",
    "run_dir",
    "log",
    "note",
)
_COPIED = (
    "reached_threshold",
    "mission_time_s",
    "sim_time_s",
    "wall_time_s",
    "initial_entropy_bits",
    "final_entropy_bits",
    "threshold_bits",
    "occupancy_f1",
    "occupancy_f1_observed",
    "coverage_mae",
    "coverage_mae_observed",
    "explored_fraction",
    "overlap_fraction",
    "overlap_halfway",
    "overlap_before_threshold",
    "stop_reason",
)


def result_row(result: RunResult) -> dict[str, Any]:
    """The results.csv row of one run: its metrics flattened (per-robot figures as total/mean)."""
    c = result.cell
    row: dict[str, Any] = dict.fromkeys(RESULT_COLUMNS)
    row.update(
        name=c.name,
        status=result.status,
        config=c.label,
        source=str(c.source),
        robots=c.robots,
        strategy=c.strategy,
        coordination=c.coordination,
        seed=c.seed,
        run_dir=str(result.run_dir),
        log=None if result.log is None else str(result.log),
        note=result.note or None,
    )
    m = result.metrics
    if m is None:
        return row
    row.update({k: m.get(k) for k in _COPIED})
    reached = bool(m.get("reached_threshold"))
    row["reached_threshold"] = reached
    row["time_to_threshold_s"] = m.get("mission_time_s") if reached else m.get("sim_time_s")
    row["time_is_lower_bound"] = not reached
    dist = [float(v) for v in (m.get("distance_m") or {}).values() if v is not None]
    if dist:
        row.update(
            distance_total_m=sum(dist), distance_mean_m=sum(dist) / len(dist), distance_max_m=max(dist)
        )
    sent = [int(v) for v in (m.get("bytes_shared") or {}).values() if v is not None]
    row["bytes_total"] = sum(sent)
    row["bytes_mean"] = sum(sent) / c.robots
    return row


@dataclass
class SettingSummary:
    """One row of summary.csv: the runs of one (config, robots, strategy, coordination), all seeds.

    ``time_*``: time to H_th over every completed run, an unreached run counting with its sim
    time; ``time_is_lower_bound`` when any did not reach H_th. ``reached_time_*``: over the
    runs that reached H_th only. ``speedup`` = time of 1 robot (same config and strategy) /
    ``time_mean_s``; ``speedup_bound`` is ">=" when only the 1-robot time is a lower bound,
    "<=" when only this setting's is, "?" when both are. Std: sample std (n - 1), None for n < 2.
    """

    config: str
    robots: int
    strategy: str
    coordination: str
    n_runs: int = 0
    n_failed: int = 0
    n_reached: int = 0
    n_not_reached: int = 0
    time_mean_s: float | None = None
    time_std_s: float | None = None
    time_is_lower_bound: bool = False
    reached_time_mean_s: float | None = None
    reached_time_std_s: float | None = None
    final_entropy_mean_bits: float | None = None
    overlap_mean: float | None = None
    overlap_halfway_mean: float | None = None
    overlap_before_threshold_mean: float | None = None
    f1_mean: float | None = None
    f1_observed_mean: float | None = None
    explored_mean: float | None = None
    distance_total_mean_m: float | None = None
    distance_per_robot_mean_m: float | None = None
    bytes_total_mean: float | None = None
    speedup: float | None = None
    speedup_bound: str = ""
    seeds: list[int] = field(default_factory=list)

    @property
    def key(self) -> tuple[str, int, str, str]:
        return (self.config, self.robots, self.strategy, self.coordination)


def _mean(values: Iterable[Any]) -> float | None:
    xs = [float(v) for v in values if v is not None and math.isfinite(float(v))]
    return sum(xs) / len(xs) if xs else None


def _std(values: Iterable[Any]) -> float | None:
    xs = [float(v) for v in values if v is not None and math.isfinite(float(v))]
    if len(xs) < 2:
        return None
    m = sum(xs) / len(xs)
    return math.sqrt(sum((x - m) ** 2 for x in xs) / (len(xs) - 1))


def summarize(rows: Sequence[Mapping[str, Any]]) -> list[SettingSummary]:
    """Aggregate results.csv rows over seeds: one :class:`SettingSummary` per setting."""
    groups: dict[tuple[str, int, str, str], list[Mapping[str, Any]]] = {}
    for row in rows:
        key = (str(row["config"]), int(row["robots"]), str(row["strategy"]), str(row["coordination"]))
        groups.setdefault(key, []).append(row)
    configs = _unique(k[0] for k in groups)
    order = sorted(
        groups,
        key=lambda k: (configs.index(k[0]), k[1], _index(STRATEGIES, k[2]), _index(COORDINATIONS, k[3])),
    )
    out: list[SettingSummary] = []
    for key in order:
        runs = groups[key]
        done = [r for r in runs if r["status"] != "failed"]
        reached = [r for r in done if r["reached_threshold"]]
        times = [r["time_to_threshold_s"] for r in done]
        reached_times = [r["mission_time_s"] for r in reached]
        s = SettingSummary(*key)
        s.seeds = sorted(int(r["seed"]) for r in runs)
        s.n_runs, s.n_failed, s.n_reached = len(done), len(runs) - len(done), len(reached)
        s.n_not_reached = len(done) - len(reached)
        s.time_mean_s, s.time_std_s = _mean(times), _std(times)
        s.time_is_lower_bound = s.n_not_reached > 0
        s.reached_time_mean_s, s.reached_time_std_s = _mean(reached_times), _std(reached_times)
        s.final_entropy_mean_bits = _mean(r["final_entropy_bits"] for r in done)
        s.overlap_mean = _mean(r["overlap_fraction"] for r in done)
        s.overlap_halfway_mean = _mean(r.get("overlap_halfway") for r in done)
        s.overlap_before_threshold_mean = _mean(r.get("overlap_before_threshold") for r in done)
        s.f1_mean = _mean(r["occupancy_f1"] for r in done)
        s.f1_observed_mean = _mean(r["occupancy_f1_observed"] for r in done)
        s.explored_mean = _mean(r["explored_fraction"] for r in done)
        s.distance_total_mean_m = _mean(r["distance_total_m"] for r in done)
        s.distance_per_robot_mean_m = _mean(r["distance_mean_m"] for r in done)
        s.bytes_total_mean = _mean(r["bytes_total"] for r in done)
        out.append(s)
    by_key = {s.key: s for s in out}
    for s in out:
        base = by_key.get((s.config, 1, s.strategy, "none"))
        if base is None or not base.time_mean_s or not s.time_mean_s:
            continue
        if base is s:
            s.speedup = 1.0  # by definition, whatever the bound on its time
            continue
        s.speedup = base.time_mean_s / s.time_mean_s
        s.speedup_bound = {
            (False, False): "",
            (True, False): ">=",
            (False, True): "<=",
            (True, True): "?",
        }[(base.time_is_lower_bound, s.time_is_lower_bound)]
    return out


def _index(values: Sequence[str], value: str) -> int:
    return values.index(value) if value in values else len(values)


def _csv_value(v: Any) -> Any:
    if v is None:
        return ""
    if isinstance(v, list):
        return " ".join(str(x) for x in v)
    return v


def write_csv(path: Path, rows: Sequence[Mapping[str, Any]], columns: Sequence[str]) -> None:
    """A CSV with a header of ``columns``; None as an empty field."""
    with open(path, "w", newline="", encoding="utf-8") as f:
        writer = csv.DictWriter(f, fieldnames=list(columns))
        writer.writeheader()
        for row in rows:
            writer.writerow({c: _csv_value(row.get(c)) for c in columns})


def _num(x: float | None, fmt: str) -> str:
    return "—" if x is None else format(x, fmt)


def _pm(mean: float | None, std: float | None, fmt: str = ".1f") -> str:
    if mean is None:
        return "—"
    return format(mean, fmt) + ("" if std is None else f" ± {format(std, fmt)}")


def summary_markdown(
    summary: Sequence[SettingSummary],
    spec: StudySpec,
    results: Sequence[RunResult],
    skipped: Sequence[Skipped],
    interrupted: bool = False,
) -> str:
    """summary.md: the grid, one table row per setting, notes on bounds, failed and skipped cells."""
    n_ran = sum(r.status == "ran" for r in results)
    n_resumed = sum(r.status == "resumed" for r in results)
    failed = [r for r in results if r.status == "failed"]
    max_time = "as in each mission" if spec.max_time_s is None else f"{spec.max_time_s:g} s"
    lines = [
        f"# Study {spec.out}",
        "",
        f"- missions: {', '.join(str(p) for p, _ in spec.sources)}",
        f"- robots {' '.join(map(str, spec.robots))}; strategies {' '.join(spec.strategies)}; "
        f"coordination {' '.join(spec.coordination)}; seeds {' '.join(map(str, spec.seeds))}; "
        f"max time {max_time}",
        f"- runs: {n_ran} ran, {n_resumed} resumed, {len(failed)} failed; "
        f"{len(skipped)} (mission, robots) pair(s) skipped"
        + ("; INTERRUPTED: incomplete" if interrupted else ""),
        "",
        "| config | robots | strategy | coordination | runs | reached H_th | time to H_th, all runs (s) "
        "| time, reached runs (s) | final H (bits) | overlap | overlap halfway | overlap before H_th "
        "| F1 | F1 observed "
        "| distance, team (m) "
        "| speed-up |",
        "|---|---:|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for s in summary:
        runs = f"{s.n_runs}" + (f" (+{s.n_failed} failed)" if s.n_failed else "")
        t_all = _pm(s.time_mean_s, s.time_std_s)
        if s.time_is_lower_bound and s.time_mean_s is not None:
            t_all = f">= {t_all} ({s.n_not_reached} not reached)"
        t_reached = f"{_pm(s.reached_time_mean_s, s.reached_time_std_s)} (n={s.n_reached})"
        speed = "—" if s.speedup is None else f"{s.speedup_bound} {s.speedup:.2f}".strip()
        cells = [
            s.config,
            str(s.robots),
            s.strategy,
            s.coordination,
            runs,
            f"{s.n_reached}/{s.n_runs}",
            t_all,
            t_reached,
            _num(s.final_entropy_mean_bits, ",.0f"),
            _num(s.overlap_mean, ".3f"),
            _num(s.overlap_halfway_mean, ".3f"),
            _num(s.overlap_before_threshold_mean, ".3f"),
            _num(s.f1_mean, ".3f"),
            _num(s.f1_observed_mean, ".3f"),
            _num(s.distance_total_mean_m, ".1f"),
            speed,
        ]
        lines.append("| " + " | ".join(cells) + " |")
    lines += [
        "",
        "Means over seeds; ± is the sample standard deviation (n - 1), left out for one run.",
        "",
        '- "time to H_th, all runs": a run that did not reach H_th counts with its sim time when it '
        'stopped, a lower bound of its time to H_th; a mean that includes one is marked ">=".',
        '- "time, reached runs": only the runs that reached H_th (n of them).',
        "- speed-up = time of 1 robot (same config and strategy) / time of the row, both over all runs; "
        '">=" when only the 1-robot time is a lower bound, "<=" when only the row\'s is, "?" when both are.',
        "- final H: map entropy at the end of the run; overlap: fraction of observed voxels seen by 2+ "
        "robots (DESIGN.md section 7: every delta, the agents' flushes included); overlap halfway: "
        "the same over what the robots had shared when the team entropy was first halfway from its "
        "start to H_th; overlap before H_th: over what they had shared before the delta that brought "
        "the team map to H_th (usually the first agent's end-of-work flush, so: what the agents shared "
        "through their utility filter); "
        "F1: occupancy F1 over observable voxels (F1 observed: over the voxels the team saw).",
    ]
    if failed:
        lines += ["", "## Failed runs", ""]
        lines += [f"- {r.cell.name}: {r.note}; log {r.log}" for r in failed]
    if skipped:
        lines += ["", "## Skipped", ""]
        lines += [f"- {s.label}, {s.robots} robots: {s.reason}" for s in skipped]
    return "\n".join(lines) + "\n"


# -- plots -----------------------------------------------------------------------------------------


def _lines(summary: Sequence[SettingSummary], config: str) -> dict[tuple[str, str], list[SettingSummary]]:
    """(strategy, coordination) -> its settings of ``config`` by robots; the 1-robot setting of a
    strategy (coordination none) starts each of that strategy's lines."""
    rows = [s for s in summary if s.config == config]
    keys = _unique((s.strategy, s.coordination) for s in rows if s.robots > 1)
    keys = keys or _unique((s.strategy, s.coordination) for s in rows)
    lines: dict[tuple[str, str], list[SettingSummary]] = {}
    for strategy, coordination in keys:
        lines[(strategy, coordination)] = sorted(
            (s for s in rows if s.strategy == strategy and (s.coordination == coordination or s.robots == 1)),
            key=lambda s: s.robots,
        )
    return lines


def _figure(n: int):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, n, figsize=(5.2 * n + 0.6, 4.4), dpi=120, layout="constrained", squeeze=False)
    return plt, fig, list(axes[0])


def plot_time_to_threshold(path: Path, summary: Sequence[SettingSummary]) -> None:
    """Mean ± std time to H_th vs robots, one line per (strategy, coordination), a subplot per config.

    Points that include runs which did not reach H_th (lower bounds) are drawn as hollow triangles.
    """
    from matplotlib.lines import Line2D

    configs = _unique(s.config for s in summary) or ("(no runs)",)
    plt, fig, axes = _figure(len(configs))
    for ax, config in zip(axes, configs, strict=True):
        bound_seen = False
        for n, ((strategy, coordination), pts) in enumerate(_lines(summary, config).items()):
            pts = [p for p in pts if p.time_mean_s is not None]
            if not pts:
                continue
            colour = f"C{n}"
            x = [p.robots for p in pts]
            y = [p.time_mean_s for p in pts]
            err = [p.time_std_s or 0.0 for p in pts]
            ax.errorbar(
                x, y, yerr=err, marker="o", capsize=3, color=colour, label=f"{strategy}, {coordination}"
            )
            lb = [p for p in pts if p.time_is_lower_bound]
            if lb:
                bound_seen = True
                ax.plot(
                    [p.robots for p in lb], [p.time_mean_s for p in lb], "^", ms=12, mfc="none", color=colour
                )
        _robot_axis(ax, summary, config)
        ax.set_ylabel("time to H_th (sim s)")
        ax.set_ylim(bottom=0.0)
        ax.set_title(config)
        handles, _ = ax.get_legend_handles_labels()
        if bound_seen:
            handles.append(
                Line2D(
                    [], [], ls="", marker="^", ms=10, mfc="none", color="grey", label=">= (H_th not reached)"
                )
            )
        if handles:
            ax.legend(handles=handles, fontsize="small")
    fig.savefig(path)
    plt.close(fig)


def plot_speedup(path: Path, summary: Sequence[SettingSummary]) -> None:
    """Speed-up over one robot vs robots, the ideal y = N dashed, a subplot per config.

    Bounded points get a hollow marker: ^ a lower bound, v an upper bound, x no bound (see
    :class:`SettingSummary`).
    """
    from matplotlib.lines import Line2D

    configs = _unique(s.config for s in summary) or ("(no runs)",)
    plt, fig, axes = _figure(len(configs))
    markers = {">=": "^", "<=": "v", "?": "x"}
    meaning = {
        ">=": ">= (1 robot did not reach H_th)",
        "<=": "<= (this team did not)",
        "?": "? (neither did)",
    }
    for ax, config in zip(axes, configs, strict=True):
        robots = sorted({s.robots for s in summary if s.config == config}) or [1]
        ax.plot([1, max(robots)], [1, max(robots)], "--", color="grey", lw=1.0, label="ideal (y = N)")
        bounds: set[str] = set()
        for n, ((strategy, coordination), pts) in enumerate(_lines(summary, config).items()):
            pts = [p for p in pts if p.speedup is not None]
            if not pts:
                continue
            colour = f"C{n}"
            x, y = [p.robots for p in pts], [p.speedup for p in pts]
            ax.plot(x, y, "-o", color=colour, label=f"{strategy}, {coordination}")
            for p in pts:
                if p.speedup_bound:
                    bounds.add(p.speedup_bound)
                    mark = markers[p.speedup_bound]
                    ax.plot([p.robots], [p.speedup], mark, ms=12, mfc="none", color=colour)
        _robot_axis(ax, summary, config)
        ax.set_ylabel("speed-up over 1 robot")
        ax.set_ylim(bottom=0.0)
        ax.set_title(config)
        handles, _ = ax.get_legend_handles_labels()
        for b in sorted(bounds):
            handles.append(
                Line2D([], [], ls="", marker=markers[b], ms=10, mfc="none", color="grey", label=meaning[b])
            )
        ax.legend(handles=handles, fontsize="small")
    fig.savefig(path)
    plt.close(fig)


def _robot_axis(ax: Any, summary: Sequence[SettingSummary], config: str) -> None:
    robots = sorted({s.robots for s in summary if s.config == config})
    if robots:
        ax.set_xticks(robots)
    ax.set_xlabel("robots")
    ax.grid(True, alpha=0.3)


# -- the study -------------------------------------------------------------------------------------


def write_outputs(
    spec: StudySpec,
    results: Sequence[RunResult],
    skipped: Sequence[Skipped],
    interrupted: bool = False,
) -> list[SettingSummary]:
    """results.csv, summary.csv, summary.md and the two plots in ``spec.out``; returns the summary."""
    out = spec.out
    out.mkdir(parents=True, exist_ok=True)
    rows = [result_row(r) for r in results]
    write_csv(out / "results.csv", rows, RESULT_COLUMNS)
    summary = summarize(rows)
    columns = [f for f in SettingSummary.__dataclass_fields__]
    write_csv(out / "summary.csv", [asdict(s) for s in summary], columns)
    (out / "summary.md").write_text(
        summary_markdown(summary, spec, results, skipped, interrupted), encoding="utf-8"
    )
    plot_time_to_threshold(out / "time_to_threshold.png", summary)
    plot_speedup(out / "speedup.png", summary)
    return summary


def run_study(spec: StudySpec, launch: Launcher = launch_sim, echo: Callable[[str], None] = print) -> int:
    """Run the study; 0 when every cell gave metrics, 1 when some failed, 130 when interrupted."""
    capacity = mission_capacity(spec)
    cells, skipped = expand_grid(spec, capacity)
    for s in skipped:
        echo(f"skipped: {s.label}, {s.robots} robots: {s.reason}")
    echo(
        f"study: {len(cells)} run(s) ({len(spec.seeds)} seed(s)), {spec.jobs} at a time -> {spec.out}"
        + (" (resuming)" if spec.resume else "")
    )
    spec.out.mkdir(parents=True, exist_ok=True)
    previous = _raise_on_sigterm()
    try:
        results, interrupted = execute(cells, spec, launch, echo)
    finally:
        _restore_sigterm(previous)
    write_outputs(spec, results, skipped, interrupted)
    failed = [r for r in results if r.status == "failed"]
    echo(
        f"wrote {spec.out}/results.csv, summary.csv, summary.md, time_to_threshold.png, speedup.png "
        f"({len(results)} run(s), {len(failed)} failed)"
    )
    if interrupted:
        done = f"{len(results)}/{len(cells)} done"
        echo(f"interrupted ({done}): finish the study with the same command and --resume")
        return 130
    return 1 if failed else 0


def _raise_on_sigterm() -> Any:
    def handler(_sig: int, _frame: Any) -> None:
        raise KeyboardInterrupt

    try:
        return signal.signal(signal.SIGTERM, handler)
    except ValueError:  # not the main thread
        return None


def _restore_sigterm(previous: Any) -> None:
    if previous is not None:
        signal.signal(signal.SIGTERM, previous)


# -- command line ----------------------------------------------------------------------------------


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Arguments of ``swarm study``."""
    parser.description = (
        "Run a grid of simulated missions and compare them. The grid crosses every mission "
        "(CONFIG files and --map ROS maps) with --robots, --strategies, --coordination and --seeds; "
        "each cell is one 'swarm sim run' subprocess writing DIR/runs/<name> "
        "(<config>-<N>r-<strategy>-<coordination>-s<seed>) and DIR/logs/<name>.log. Coordination "
        "only matters for entropy teams of 2+ robots, so other cells run once as coordination none; "
        "a robot count larger than a mission places is reported and skipped. Outputs in DIR: "
        "results.csv (one row per run), summary.csv and summary.md (one row per config, robots, "
        "strategy and coordination, over seeds: runs reached H_th, mean ± std time to H_th, final "
        "entropy, overlap, F1, distance, speed-up over one robot), time_to_threshold.png and "
        "speedup.png. A run that did not reach H_th counts with its sim time as a lower bound, "
        "marked '>='. Exit code 0, 1 when some run failed, 2 for a bad option, 130 when interrupted. "
        "See docs/study.md."
    )
    parser.epilog = (
        "Example: swarm study configs/office.yaml --robots 1 2 4 --seeds 0 1 2 --out runs/study-office "
        "(Ctrl-C stops it cleanly; run the same command with --resume to finish it)."
    )
    parser.add_argument(
        "configs",
        nargs="*",
        type=Path,
        metavar="CONFIG",
        help="mission YAML file(s), given before the options",
    )
    parser.add_argument(
        "--map",
        dest="maps",
        action="append",
        nargs="+",
        type=Path,
        metavar="MAP.yaml",
        help="ROS map_server map(s) to explore, robots placed automatically; repeatable",
    )
    parser.add_argument(
        "--robots", nargs="+", type=int, default=[1, 2, 4], metavar="N", help="robot counts (default: 1 2 4)"
    )
    parser.add_argument(
        "--strategies",
        nargs="+",
        choices=STRATEGIES,
        default=["entropy"],
        metavar="STRATEGY",
        help=f"exploration strategies, of {', '.join(STRATEGIES)} (default: entropy)",
    )
    parser.add_argument(
        "--coordination",
        nargs="+",
        choices=COORDINATIONS,
        default=["coordinator", "none"],
        metavar="MODE",
        help="coordination modes, of coordinator, none (default: both); used for entropy teams of 2+ robots",
    )
    parser.add_argument(
        "--seeds", nargs="+", type=int, default=[0, 1, 2], metavar="S", help="seeds (default: 0 1 2)"
    )
    parser.add_argument(
        "--max-time",
        type=float,
        metavar="T",
        help="simulated seconds at most per run (default: each mission's)",
    )
    parser.add_argument(
        "--jobs",
        type=int,
        default=1,
        metavar="J",
        help="missions run at once (default 1: each mission already runs several processes)",
    )
    parser.add_argument("--out", type=Path, required=True, metavar="DIR", help="study folder")
    parser.add_argument(
        "--resume",
        action="store_true",
        help="read the cells whose run folder already holds a metrics.json instead of running them",
    )


def spec_from_args(args: argparse.Namespace) -> StudySpec:
    """The validated study of parsed arguments; StudyError names the bad option."""
    try:
        return StudySpec(
            configs=tuple(args.configs),
            maps=tuple(p for group in args.maps or [] for p in group),
            robots=tuple(args.robots),
            strategies=tuple(args.strategies),
            coordination=tuple(args.coordination),
            seeds=tuple(args.seeds),
            max_time_s=args.max_time,
            jobs=args.jobs,
            out=args.out,
            resume=args.resume,
        )
    except ValidationError as exc:
        raise StudyError(describe_spec_error(exc)) from exc


def describe_spec_error(err: ValidationError) -> str:
    """One line per problem, each starting with the option it is about."""
    lines = []
    for e in err.errors():
        option = OPTION_OF.get(str(e["loc"][0]), str(e["loc"][0])) + ": " if e["loc"] else ""
        msg = str(e.get("ctx", {}).get("error", e["msg"])) if e["type"] == "value_error" else e["msg"]
        if e["type"] != "value_error":
            msg += f" (got {e.get('input')!r})"
        line = f"{option}{msg}"
        if line not in lines:
            lines.append(line)
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    """``swarm study``: validate the options, run the study, write its outputs."""
    try:
        spec = spec_from_args(args)
        return run_study(spec)
    except StudyError as exc:
        for line in str(exc).splitlines():
            print(f"swarm study: error: {line}", file=sys.stderr)
        return 2


def main(argv: list[str] | None = None) -> int:
    """``python -m swarm.mission.study``: the same as ``swarm study``."""
    parser = argparse.ArgumentParser(prog="swarm study")
    add_arguments(parser)
    return run(parser.parse_args(argv))


if __name__ == "__main__":
    sys.exit(main())
