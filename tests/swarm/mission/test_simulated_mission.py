"""The mission ``swarm sim run`` simulates: robots without a start pose (real robots' missions
leave it out) are refused, naming each field, unless ``--robots`` leaves them out."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from swarm.config import ConfigError
from swarm.mission.simulated_mission import resolve_mission
from tests.support.paths import CONFIGS


def args(config: Path, robots: int | None = None) -> argparse.Namespace:
    return argparse.Namespace(config=config, map=None, robots=robots)


def test_only_the_robots_simulated_need_a_start(tmp_path):
    mission = tmp_path / "mission.yaml"
    mission.write_text(
        f"workspace: {{lo: [0, 0, 0], hi: [4, 2, 2]}}\nfloor_plan: {CONFIGS / 'plans' / 'lab.yaml'}\n"
        "robots: [{id: r1, start: {x: 0.6, y: 1.0}}, {id: r2}, {id: r3}]\n"
    )
    assert resolve_mission(args(mission, robots=1), "unused.yaml").robot_ids == ["r1"]
    with pytest.raises(ConfigError) as err:
        resolve_mission(args(mission), "unused.yaml")
    assert str(err.value).startswith(
        f"{mission}: robots[1].start, robots[2].start: are required by the simulator"
    )


def test_a_ros_map_mission_places_its_robots():
    # --map: the simulator places the robots itself (mission_from_map), no start to give
    namespace = argparse.Namespace(config=None, map=CONFIGS / "maps" / "tb3_sandbox.yaml", robots=2)
    mission = resolve_mission(namespace, "unused.yaml")
    assert len(mission.start_poses()) == 2
