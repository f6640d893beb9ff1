"""A study's plots: time to H_th and speed-up over robot count."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

from swarm.mission.study.grid import unique
from swarm.mission.study.tables import SettingSummary

# -- plots -----------------------------------------------------------------------------------------


def _lines(summary: Sequence[SettingSummary], config: str) -> dict[tuple[str, str], list[SettingSummary]]:
    """(strategy, coordination) -> its settings of ``config`` by robots; the 1-robot setting of a
    strategy (coordination none) starts each of that strategy's lines."""
    rows = [s for s in summary if s.config == config]
    keys = unique((s.strategy, s.coordination) for s in rows if s.robots > 1)
    keys = keys or unique((s.strategy, s.coordination) for s in rows)
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

    configs = unique(s.config for s in summary) or ("(no runs)",)
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

    configs = unique(s.config for s in summary) or ("(no runs)",)
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
