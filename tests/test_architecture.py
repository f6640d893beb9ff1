"""The house's import rules (docs/architecture.md) hold, and the check catches a wrong import."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from tests.support.architecture_rules import PACKAGES, cycles, module_imports, violations
from tests.support.paths import ROOT


def test_the_house_keeps_its_import_rules():
    assert violations(ROOT) == []


def test_every_package_is_seen():
    groups = {m.split(".")[0] for m in module_imports(ROOT)}
    assert groups == {"swarm", "robot_agent", "map_server", "coordinator", "sim2d", "replay", "ros2_map"}
    assert "swarm.map.fusion" in module_imports(ROOT)


@pytest.fixture
def tree(tmp_path: Path) -> Path:
    """A copy of the project's packages to break on purpose."""
    for package in PACKAGES:
        shutil.copytree(ROOT / package, tmp_path / package, ignore=shutil.ignore_patterns("__pycache__"))
    return tmp_path


@pytest.mark.slow
@pytest.mark.parametrize(
    ("module", "line", "expected"),
    [
        (
            "robot_agent/agent.py",
            "from coordinator.state import CoordinatorState",
            "robot_agent may not import coordinator",
        ),
        ("map_server/server.py", "import sim2d.render", "map_server may not import sim2d"),
        (
            "ros2_map/role.py",
            "from coordinator.replica import CoordinatorReplica",
            "ros2_map may not import coordinator",
        ),
        (
            "swarm/map/fusion.py",
            "from swarm.protocol.wire import DeltaMessage",
            "swarm.map may not import swarm.protocol",
        ),
        ("swarm/map/grid.py", "import zenoh", "the maths uses numpy, scipy and numba only"),
        (
            "swarm/navigation/planner.py",
            "from swarm.mission import evaluation",
            "swarm.navigation may not import swarm.mission",
        ),
        (
            "swarm/protocol/bus.py",
            "from robot_agent.agent import Agent",
            "swarm.protocol may not import robot_agent",
        ),
    ],
)
def test_a_wrong_import_is_reported(tree: Path, module: str, line: str, expected: str):
    path = tree / module
    path.write_text(path.read_text(encoding="utf-8") + f"\n{line}\n", encoding="utf-8")
    found = violations(tree)
    assert any(expected in problem for problem in found), found


def test_an_import_cycle_is_reported(tree: Path):
    path = tree / "swarm" / "map" / "grid.py"
    path.write_text(path.read_text(encoding="utf-8") + "\nfrom swarm.map.fusion import batch_information\n")
    found = cycles(module_imports(tree))
    assert any("swarm.map.grid" in c and "swarm.map.fusion" in c for c in found), found
