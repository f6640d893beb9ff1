"""The explorer's state machine: the tilt head's look-up after a gaze."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from robot_agent.explorer import Explorer
from swarm.config import load_mission
from swarm.navigation.exploration import ExplorationTarget

CONFIGS = Path(__file__).resolve().parent.parent / "configs"


def gazing_explorer(tilt_range_deg: float) -> Explorer:
    mission = load_mission(CONFIGS / "lab.yaml")
    mission.rig.tilt_range_deg = tilt_range_deg
    explorer = Explorer(mission, "r1")
    explorer.state = "gaze"
    explorer.target = ExplorationTarget(np.array([1.0, 1.0]), 0.3, 1.0, None, "entropy")
    return explorer


def test_a_gaze_ends_with_one_frame_looking_up_then_level():
    explorer = gazing_explorer(35.0)
    turning = explorer.decide(1.0, 1.0, 1.3)  # 1 rad left of the gaze: turn right, head level
    assert turning.omega < 0 and turning.tilt == 0.0 and turning.state == "gaze"
    aligned = explorer.decide(1.0, 1.0, 0.3)  # on the gaze: raise the head for the next frame
    assert (aligned.v, aligned.omega) == (0.0, 0.0)
    assert aligned.tilt == pytest.approx(-math.radians(35.0))
    assert explorer.state == "look_up"
    lowered = explorer.decide(1.0, 1.0, 0.3)  # that frame was seen looking up: level again
    assert lowered.tilt == 0.0 and explorer.state == "choose"


def test_a_fixed_camera_sends_no_tilt_and_chooses_after_the_gaze():
    explorer = gazing_explorer(0.0)
    aligned = explorer.decide(1.0, 1.0, 0.3)
    assert aligned.tilt is None and explorer.state == "choose"


def test_a_robot_boxed_in_by_unseen_floor_steps_out_to_the_free_area_beyond():
    # A level camera never sees the floor right around the robot: everything is known free
    # except a disc of unknown columns around it, so only its own cell is reachable.
    mission = load_mission(CONFIGS / "lab.yaml")
    explorer = Explorer(mission, "r1", strategy="frontier")
    grid, cmap = explorer.grid, explorer.map
    centres = grid.centres().reshape(-1, 3)
    robot = np.array([1.05, 1.05])
    near = np.hypot(*(centres[:, :2] - robot).T) < 0.6
    free = ~near & (centres[:, 2] < 1.0)
    cmap.lam[free] = 400.0  # a sure, empty belief: mu = 0, sigma = 0.05
    cmap.eta[free] = 0.0
    explorer.entropy = type(explorer.entropy).from_information(cmap.lam, cmap.eta, table=explorer.table)
    explorer.state = "choose"
    decision = explorer.decide(robot[0], robot[1], 0.0)
    assert explorer.state == "drive" and decision.target is not None
    path = explorer.follower.remaining_path()
    assert np.allclose(path[0], robot)  # it leaves from where it stands...
    assert np.hypot(*(path[1] - robot)) >= 0.5  # ...straight to free floor beyond the unseen disc


def test_a_target_at_the_robots_own_cell_is_avoided_after_two_looks():
    # A target the robot stands on (within 0.15 m) means "look from here"; when the same
    # answer keeps coming back, looking has not settled it and the spot is avoided.
    explorer = gazing_explorer(0.0)
    here = np.array([1.0, 1.0])
    explorer.assigner = lambda: ExplorationTarget(here + 0.05, 0.3, 1.0, None, "entropy")
    explorer.state = "choose"
    states = []
    for _ in range(3):
        decision = explorer.decide(here[0], here[1], 0.3)  # facing the gaze already
        states.append(decision.state)
    assert states == ["gaze", "gaze", "choose"]
    assert len(explorer.failed) == 1 and np.allclose(explorer.failed[0], here + 0.05)
