"""``swarm bench team``: whole missions of several team sizes, with every role process measured.

Each team size runs ``swarm sim CONFIG --robots N --max-time T`` as a child process while this
process samples, once a second, every process below it from ``/proc``: CPU time (user and
system), resident set size and its peak (``VmHWM``), and the proportional set size (``Pss`` of
``smaps_rollup``: shared library pages split among the processes that map them). Roles are told
apart by their command lines (``swarm agent``, ``swarm server``, ``swarm coordinator``,
``swarm sim world``; the runner is the child itself). After the run it reads the run folder's
``metrics.json`` (entropy, the coordinator's answer times) and the world's log (how long the
simulated time took once every agent was there). Linux only (``/proc``).
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import time
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path

from swarm.bench.proc_memory import memory_kb
from swarm.child_command import child_environment, swarm_argv

CLOCK_TICKS = os.sysconf("SC_CLK_TCK")  # the unit of /proc/<pid>/stat's CPU times, a second
_STAMP = re.compile(r"^(\d{4}-\d\d-\d\d \d\d:\d\d:\d\d,\d{3}) ")


@dataclass
class ProcessSample:
    """The samples of one process: CPU s at the last; peak RSS and PSS (MB); PSS at the last (MB)."""

    role: str
    cpu_user_s: float = 0.0
    cpu_sys_s: float = 0.0
    rss_peak_mb: float = 0.0
    pss_peak_mb: float = 0.0
    pss_last_mb: float = 0.0


@dataclass
class TeamRun:
    """What one mission of ``robots`` robots measured."""

    robots: int
    processes: dict[int, ProcessSample] = field(default_factory=dict)
    metrics: dict = field(default_factory=dict)
    world_run_s: float | None = None  # wall time of the simulated run, agents all there
    wall_s: float = 0.0  # the whole command


def role_of(cmdline: list[str]) -> str:
    """``agent``, ``server``, ``coordinator``, ``world``, ``runner`` or ``other`` from a command line."""
    args = cmdline[cmdline.index("swarm.cli") + 1 :] if "swarm.cli" in cmdline else cmdline[1:]
    if args[:2] == ["sim", "world"]:
        return "world"
    if args and args[0] in ("agent", "server", "coordinator"):
        return args[0]
    return "runner" if args[:1] == ["sim"] else "other"


def _descendants(root: int) -> list[int]:
    parents: dict[int, list[int]] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                ppid = int((entry / "stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, IndexError, ValueError):
                continue
            parents.setdefault(ppid, []).append(int(entry.name))
    out, todo = [], [root]
    while todo:
        pid = todo.pop()
        out.append(pid)
        todo += parents.get(pid, [])
    return out


def _sample(pid: int, into: dict[int, ProcessSample]) -> None:
    proc = Path("/proc") / str(pid)
    try:
        cmdline = (proc / "cmdline").read_bytes().decode(errors="replace").split("\0")[:-1]
        stat = (proc / "stat").read_text().rsplit(")", 1)[1].split()
        kb = memory_kb(pid)
    except (OSError, IndexError):
        return  # exited between the listing and the reads
    s = into.setdefault(pid, ProcessSample(role_of(cmdline)))
    s.cpu_user_s, s.cpu_sys_s = int(stat[11]) / CLOCK_TICKS, int(stat[12]) / CLOCK_TICKS
    if "VmHWM" in kb:
        s.rss_peak_mb = max(s.rss_peak_mb, kb["VmHWM"] / 1024)
    if "Pss" in kb:
        s.pss_last_mb = kb["Pss"] / 1024
        s.pss_peak_mb = max(s.pss_peak_mb, s.pss_last_mb)


def world_run_seconds(log: Path) -> float | None:
    """Seconds from the world's "every robot's agent is there" line to its last line."""
    try:
        lines = log.read_text(errors="replace").splitlines()
    except OSError:
        return None
    stamps = [(m.group(1), line) for line in lines if (m := _STAMP.match(line))]
    start = next((t for t, line in stamps if "agent is there" in line), None)
    if start is None or not stamps:
        return None
    return (_stamp_time(stamps[-1][0]) - _stamp_time(start)).total_seconds()


def _stamp_time(stamp: str) -> datetime:
    return datetime.strptime(stamp, "%Y-%m-%d %H:%M:%S,%f")


def run_team(config: Path, robots: int, max_time: float, out: Path, progress=print) -> TeamRun:
    """Run one mission of ``robots`` robots for ``max_time`` simulated seconds into ``out``;
    raises RuntimeError (with the log's tail) when ``swarm sim`` fails."""
    run = TeamRun(robots)
    args = [
        "sim",
        str(config),
        "--robots",
        str(robots),
        "--max-time",
        str(max_time),
        "--out",
        str(out),
        "--quiet",
    ]
    log = out.with_suffix(".log")
    out.parent.mkdir(parents=True, exist_ok=True)
    started = time.monotonic()
    with open(log, "w") as sink:
        child = subprocess.Popen(
            swarm_argv(*args), stdout=sink, stderr=subprocess.STDOUT, env=child_environment()
        )
        last = started
        while child.poll() is None:
            for pid in _descendants(child.pid):
                _sample(pid, run.processes)
            if time.monotonic() - last > 30:
                last = time.monotonic()
                progress(f"  {robots} robots: {last - started:.0f} s, {len(run.processes)} processes seen")
            time.sleep(1.0)
    run.wall_s = time.monotonic() - started
    if child.returncode != 0:
        tail = "\n".join(log.read_text(errors="replace").splitlines()[-5:])
        raise RuntimeError(f"swarm sim exited with {child.returncode} (log {log}):\n{tail}")
    run.metrics = json.loads((out / "metrics.json").read_text())
    run.world_run_s = world_run_seconds(out / "world.log")
    return run


def role_figures(run: TeamRun) -> dict[str, dict[str, float]]:
    """Per role: process count, CPU s in all (user + system), the largest peak RSS and PSS, and
    the largest PSS at a process's last sample (MB: after its start-up, near the run's end)."""
    out: dict[str, dict[str, float]] = {}
    for s in run.processes.values():
        r = out.setdefault(s.role, {"processes": 0, "cpu_s": 0.0, "rss_peak_mb": 0.0, "pss_peak_mb": 0.0})
        r["processes"] += 1
        r["cpu_s"] += s.cpu_user_s + s.cpu_sys_s
        r["rss_peak_mb"] = max(r["rss_peak_mb"], s.rss_peak_mb)
        r["pss_peak_mb"] = max(r["pss_peak_mb"], s.pss_peak_mb)
        r["pss_last_mb"] = max(r.get("pss_last_mb", 0.0), s.pss_last_mb)
    return out


def format_run(run: TeamRun) -> str:
    """The figures of one run, as printed lines."""
    m = run.metrics
    sim_s = float(m.get("sim_time_s") or 0.0)
    removed = removed_bits(run)
    lines = [f"{run.robots} robots, {sim_s:.1f} s simulated:"]
    if run.world_run_s:
        factor = sim_s / run.world_run_s
        lines.append(f"  world: {sim_s:.1f} s simulated in {run.world_run_s:.1f} s: x{factor:.2f} real time")
    lines.append(f"  whole command {run.wall_s:.1f} s (start-up and evaluation included)")
    explored, overlap = float(m.get("explored_fraction") or 0), float(m.get("overlap_fraction") or 0)
    end = f"reached at {m['mission_time_s']:.1f} s" if m.get("reached_threshold") else "not reached"
    lines.append(
        f"  entropy removed {removed:,.0f} bits ({removed / float(m['initial_entropy_bits']):.1%}); "
        f"explored {explored:.1%}; overlap {overlap:.3f}; H_th {end}"
    )
    answers = m.get("coordinator_answer_ms") or {}
    if answers.get("count"):
        lines.append(
            f"  coordinator: {answers['count']} answers, p50 {answers['p50']:.1f} ms, "
            f"p95 {answers['p95']:.1f} ms, max {answers['max']:.1f} ms"
        )
    for role, r in sorted(role_figures(run).items()):
        lines.append(
            f"  {role:<11} x{int(r['processes']):<2} CPU {r['cpu_s']:7.1f} s  "
            f"peak RSS {r['rss_peak_mb']:5.0f} MB  PSS peak {r['pss_peak_mb']:5.0f} MB, "
            f"last {r['pss_last_mb']:5.0f} MB (its largest process)"
        )
    return "\n".join(lines)


def speed_up(big: TeamRun, small: TeamRun) -> float:
    """Entropy removed by ``big`` over that removed by ``small`` in the same simulated time."""
    return removed_bits(big) / removed_bits(small) if removed_bits(small) > 0 else float("inf")


def removed_bits(run: TeamRun) -> float:
    """The entropy a run removed (bits): its metrics' initial minus final."""
    return float(run.metrics["initial_entropy_bits"]) - float(run.metrics["final_entropy_bits"])
