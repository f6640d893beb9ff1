"""The compiled kernels an agent runs per frame, loaded before its first frame (a first run:
compiled into Numba's cache, with a progress line per kernel: ``swarm.compile_progress``)."""

from __future__ import annotations

from collections.abc import Callable

from robot_agent import stereo
from swarm.compile_progress import compile_progress
from swarm.map import fusion
from swarm.navigation import planner


def agent_kernels() -> tuple:
    """The compiled kernels :func:`load_kernels` loads."""
    return (*fusion.warm_up_kernels(), *stereo.warm_up_kernels(), *planner.warm_up_kernels())


def load_kernels(say: Callable[[str], None] | None = None, role: str = "") -> None:
    """Load (on a fresh install: compile into Numba's cache) every compiled kernel an agent runs
    per frame: fusion (``swarm.map.fusion``, with the map's update), world points
    (``robot_agent.stereo``) and planning (``swarm.navigation.planner``). ``say`` (a log's
    ``info``): told each kernel as it compiles (``swarm.compile_progress``), ``role`` first."""
    with compile_progress(agent_kernels(), say, role):
        fusion.warm_up()
        stereo.warm_up()
        planner.warm_up()
