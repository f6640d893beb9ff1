"""docs/cli.md names every ``swarm`` command the parser has, so that the page stays whole."""

from __future__ import annotations

import argparse

from swarm.cli.main import build_parser
from tests.support.paths import ROOT


def commands(parser: argparse.ArgumentParser, path: str) -> list[str]:
    """Every leaf command of ``parser``, e.g. ``swarm map stats``, ``swarm bench ros2 latency``."""
    found = []
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                found += commands(sub, f"{path} {name}") or [f"{path} {name}"]
    return found


def test_the_cli_page_names_every_command():
    page = (ROOT / "docs" / "cli.md").read_text(encoding="utf-8")
    named = page.replace("swarm sim [run]", "swarm sim run")  # `swarm sim` alone is `swarm sim run`
    ros2 = "swarm bench ros2 latency\\|euroc\\|mission"  # the three, written as one row
    named = named.replace(ros2, "swarm bench ros2 latency swarm bench ros2 euroc swarm bench ros2 mission")
    leaves = commands(build_parser(), "swarm")
    assert len(leaves) > 25  # the parser was walked, not an empty list compared
    missing = [c for c in leaves if f"`{c}" not in named and f" {c}" not in named]
    assert not missing, "docs/cli.md does not name: " + ", ".join(missing)
