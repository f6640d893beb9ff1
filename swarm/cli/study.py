"""``swarm study``: a grid of missions."""

from __future__ import annotations

import argparse


# -- swarm study --------------------------------------------------------------------------
def register(sub: argparse._SubParsersAction) -> None:
    from swarm.mission import study

    p = sub.add_parser(
        "study",
        help="run a grid of missions (robots x strategies x coordination x seeds) and tabulate them",
        description="Run a grid of simulated missions as swarm sim subprocesses, with progress, "
        "then write results.csv, summary.csv/.md (means over seeds, speed-up over one robot) and "
        "plots of time to threshold and speed-up. See docs/study.md.",
    )
    study.add_arguments(p)
    p.set_defaults(run=study.run)
