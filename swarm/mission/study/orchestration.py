"""A whole study: run the cells, then write the tables and plots."""

from __future__ import annotations

import signal
from collections.abc import Callable, Sequence
from dataclasses import asdict
from typing import Any

from swarm.mission.study.grid import Skipped, StudySpec, expand_grid, mission_capacity
from swarm.mission.study.plots import plot_speedup, plot_time_to_threshold
from swarm.mission.study.runner import Launcher, RunResult, execute, launch_sim
from swarm.mission.study.tables import (
    RESULT_COLUMNS,
    SettingSummary,
    result_row,
    summarize,
    summary_markdown,
    write_csv,
)

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
