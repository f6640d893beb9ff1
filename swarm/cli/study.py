"""``swarm study``: a grid of missions."""

from __future__ import annotations

import argparse


# -- swarm study --------------------------------------------------------------------------
def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "study",
        help="run a grid of missions (robots x strategies x coordination x seeds) and tabulate them",
        description="Run a grid of simulated missions as swarm sim subprocesses, with progress, "
        "then write results.csv, summary.csv/.md (means over seeds, speed-up over one robot) and "
        "plots of time to threshold and speed-up. See docs/study.md.",
    )
    p.defer(_study_arguments)


def _study_arguments(p: argparse.ArgumentParser) -> None:
    from swarm.mission.study import command

    command.add_arguments(p)
    p.set_defaults(run=command.run)
