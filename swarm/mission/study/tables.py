"""A study's tables: ``results.csv`` (one row per run), ``summary.csv`` and ``summary.md`` (per setting)."""

from __future__ import annotations

import csv
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from swarm.mission.run_report import METRIC_KEYS
from swarm.mission.study.grid import COORDINATIONS, Skipped, StudySpec, unique
from swarm.mission.study.runner import RunResult
from swarm.navigation.strategies import STRATEGIES

# -- tables ----------------------------------------------------------------------------------------

#: The figures every run's metrics.json has, from the first to the map-quality ones.
_RUN_FIGURES = METRIC_KEYS[
    METRIC_KEYS.index("reached_threshold") : METRIC_KEYS.index("explored_fraction") + 1
]
RESULT_COLUMNS = (
    "name",
    "status",
    "config",
    "source",
    "robots",
    "strategy",
    "coordination",
    "seed",
    *_RUN_FIGURES,
    "time_to_threshold_s",
    "time_is_lower_bound",
    "overlap_fraction",
    "overlap_halfway",
    "overlap_before_threshold",
    "distance_total_m",
    "distance_mean_m",
    "distance_max_m",
    "bytes_total",
    "bytes_mean",
    "coordinator_answers",
    "coordinator_answer_ms_mean",
    "coordinator_answer_ms_p95",
    "coordinator_answer_ms_max",
    "stop_reason",
    "run_dir",
    "log",
    "note",
)
#: Columns computed from the metrics or the run rather than copied from metrics.json.
_DERIVED = (
    "time_to_threshold_s",
    "time_is_lower_bound",
    "distance_total_m",
    "distance_mean_m",
    "distance_max_m",
    "bytes_total",
    "bytes_mean",
    "coordinator_answers",
    "coordinator_answer_ms_mean",
    "coordinator_answer_ms_p95",
    "coordinator_answer_ms_max",
    "run_dir",
    "log",
    "note",
)
#: Columns copied as they are from metrics.json: those after the cell's own.
_COPIED = tuple(k for k in RESULT_COLUMNS[RESULT_COLUMNS.index("reached_threshold") :] if k not in _DERIVED)


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
    answers = m.get("coordinator_answer_ms")
    if isinstance(answers, dict):
        row["coordinator_answers"] = answers.get("count")
        for stat in ("mean", "p95", "max"):
            row[f"coordinator_answer_ms_{stat}"] = answers.get(stat)
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
    surface_accuracy_mean: float | None = None
    surface_completeness_mean: float | None = None
    mae_observed_mean: float | None = None
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
    configs = unique(k[0] for k in groups)
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
        s.surface_accuracy_mean = _mean(r.get("surface_accuracy") for r in done)
        s.surface_completeness_mean = _mean(r.get("surface_completeness") for r in done)
        s.mae_observed_mean = _mean(r.get("coverage_mae_observed") for r in done)
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
        "| F1 | F1 observed | surface accuracy | surface completeness | coverage MAE observed "
        "| distance, team (m) "
        "| speed-up |",
        "|---|---:|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
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
            _num(s.surface_accuracy_mean, ".3f"),
            _num(s.surface_completeness_mean, ".3f"),
            _num(s.mae_observed_mean, ".3f"),
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
        "robots (docs/design.md section 7: every delta, the agents' flushes included); overlap halfway: "
        "the same over what the robots had shared when the team entropy was first halfway from its "
        "start to H_th; overlap before H_th: over what they had shared before the delta that brought "
        "the team map to H_th (usually the first agent's end-of-work flush, so: what the agents shared "
        "through their utility filter); "
        "F1: occupancy F1 over observable voxels (F1 observed: over the voxels the team saw); "
        "surface accuracy: share of mapped occupied voxels (E[C] > 0.5) within 1.5 voxel edges of the "
        "true surface; surface completeness: share of the true surface (that a sensor could see) within "
        "1.5 voxel edges of a mapped occupied voxel; coverage MAE observed: mean |E[C] - true coverage| "
        "over the voxels the team saw.",
    ]
    if failed:
        lines += ["", "## Failed runs", ""]
        lines += [f"- {r.cell.name}: {r.note}; log {r.log}" for r in failed]
    if skipped:
        lines += ["", "## Skipped", ""]
        lines += [f"- {s.label}, {s.robots} robots: {s.reason}" for s in skipped]
    return "\n".join(lines) + "\n"
