"""``swarm study``: run a grid of missions and compare them.

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

Modules: ``grid`` (the cells), ``runner`` (the subprocesses), ``tables`` (CSV and Markdown),
``plots``, ``orchestration`` (a whole study) and ``command`` (``swarm study``).
"""

from importlib import import_module

#: Each name this package offers -> the module of the package that defines it (imported when
#: first asked for: ``swarm study --help`` needs the arguments only, not the runs' machinery).
_HOMES = {
    **dict.fromkeys(("add_arguments", "main", "run", "spec_from_args"), "command"),
    **dict.fromkeys(
        ("Cell", "Skipped", "StudyError", "StudySpec", "expand_grid", "mission_capacity"), "grid"
    ),
    **dict.fromkeys(("run_study", "write_outputs"), "orchestration"),
    **dict.fromkeys(("RunResult", "execute", "launch_sim", "stop_children"), "runner"),
    **dict.fromkeys(("SettingSummary", "result_row", "summarize", "summary_markdown"), "tables"),
}


def __getattr__(name: str):
    if name not in _HOMES:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(import_module(f"{__name__}.{_HOMES[name]}"), name)


__all__ = [
    "Cell",
    "RunResult",
    "SettingSummary",
    "Skipped",
    "StudyError",
    "StudySpec",
    "add_arguments",
    "execute",
    "expand_grid",
    "launch_sim",
    "main",
    "mission_capacity",
    "result_row",
    "run",
    "run_study",
    "spec_from_args",
    "stop_children",
    "summarize",
    "summary_markdown",
    "write_outputs",
]
