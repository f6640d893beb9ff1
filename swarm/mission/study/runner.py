"""Running a study's cells: one ``swarm sim`` subprocess each, progress, Ctrl-C, ``--resume``."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from swarm.child_command import child_environment, swarm_argv
from swarm.mission.study.grid import Cell, StudySpec

STOP_GRACE_S = 60.0


# -- running the cells ---------------------------------------------------------------------------

#: Starts ``swarm ARGS`` writing its output to the log file; returns the process.
Launcher = Callable[[list[str], Path], subprocess.Popen]


def launch_sim(args: list[str], log_path: Path) -> subprocess.Popen:
    """``swarm ARGS`` as this process runs it (``swarm.child_command``), in its own session
    (Ctrl-C reaches it through the study only)."""
    log_path.parent.mkdir(parents=True, exist_ok=True)
    with open(log_path, "w") as log:
        return subprocess.Popen(
            swarm_argv(*args),
            stdout=log,
            stderr=subprocess.STDOUT,
            env=child_environment(PYTHONUNBUFFERED="1"),
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


def _matches(cell: Cell, metrics: Mapping[str, Any], spec: StudySpec | None = None) -> bool:
    """Whether a run folder's metrics are this cell's, run to its end (not interrupted) with this
    study's --max-time and --observable-threshold (when the study gives them)."""
    if metrics.get("interrupted"):
        return False
    same_cell = (
        len(metrics.get("robots") or []) == cell.robots
        and metrics.get("strategy") == cell.strategy
        and metrics.get("coordination") == cell.coordination
        and metrics.get("seed") == cell.seed
    )
    if not same_cell or spec is None:
        return same_cell
    if spec.max_time_s is not None and metrics.get("max_time_s") != spec.max_time_s:
        return False
    if spec.observable_threshold is not None:
        parts = metrics.get("threshold_parts") or {}
        return parts.get("fraction") == spec.observable_threshold
    return True


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
                    if metrics is not None and _matches(cell, metrics, spec):
                        log = out / "logs" / f"{cell.name}.log"
                        results[k] = RunResult(
                            cell, "resumed", run_dir, log if log.exists() else None, metrics
                        )
                        report(k, f"resumed from {run_dir / 'metrics.json'}: {outcome_text(metrics)}")
                        continue
                    if metrics is not None:
                        why = (
                            "metrics.json is of an interrupted run"
                            if metrics.get("interrupted")
                            else "metrics.json is of another cell, --max-time or --observable-threshold"
                        )
                        echo(f"[{k + 1}/{total}] {cell.name}: {why}; running")
                echo(f"[{k + 1}/{total}] {cell.name}: started")
                args = cell.sim_args(run_dir, spec.max_time_s, spec.observable_threshold)
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
