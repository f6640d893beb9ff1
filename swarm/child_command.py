"""How the runners start ``swarm`` in a child process so that it runs the parent's own copy.

``python -m swarm.cli`` puts the working directory first on ``sys.path``. Started from the
project folder (as the README's quick start is), the children of an installed ``swarm sim``
then imported the checkout's sources while the runner ran the installed copy: two versions of
the code in one mission, and every compiled kernel compiled twice on a first run (the runner's
warm-up filled the installed copy's cache, which the children never read). The children are
started with ``-P`` (no working directory on the path, Python 3.11) and, when the parent's
``swarm`` is not an installed package, with its folder first on ``PYTHONPATH``.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path


def swarm_argv(*args: str) -> list[str]:
    """``[python, -P, -m, swarm.cli, *args]``: this interpreter, the ``swarm`` command."""
    return [sys.executable, "-P", "-m", "swarm.cli", *args]


def child_environment(**extra: str) -> dict[str, str]:
    """This process's environment plus ``extra``, with the folder holding this process's
    ``swarm`` package first on ``PYTHONPATH`` unless it is a site-packages folder (an installed
    copy, which the child finds there anyway)."""
    env = {**os.environ, **extra}
    root = Path(__file__).resolve().parent.parent
    if not {"site-packages", "dist-packages"} & set(root.parts):
        rest = env.get("PYTHONPATH", "")
        env["PYTHONPATH"] = str(root) + (os.pathsep + rest if rest else "")
    return env
