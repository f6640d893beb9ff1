"""Teammate avoidance (swarm.navigation.teammates): two robots' explorers that know each other's
statuses keep apart, and the one later in the robot list yields when they block each other."""

from __future__ import annotations

import math

import numpy as np
import pytest

from robot_agent.decision import ExplorerState
from robot_agent.explorer import REPLAN_EVERY, Explorer
from robot_agent.teammate_avoidance import YIELD_FRAMES, robot_rank
from swarm.config import load_mission
from swarm.navigation.exploration import ExplorationTarget
from swarm.navigation.teammates import MAX_TEAMMATES, Teammates, block_teammates, blocking_teammate
from swarm.navigation.traversability import TraversabilityGrid
from tests.support.paths import CONFIGS

RADIUS = 0.18
PERIOD = 0.5  # s per frame, as the simulator's default


def test_a_sighting_grows_with_its_age_and_goes_stale():
    mates = Teammates("r1", robot_radius=RADIUS, max_speed=0.5, margin=0.1, max_age_s=3.0)
    assert not mates.update("r1", 1.0, 0.0, 0.0)  # its own status
    assert mates.update("r2", 2.0, 1.0, 1.0)
    assert not mates.update("r2", 1.5, 9.0, 9.0)  # older than the one held
    (seen,) = mates.fresh(2.0)
    assert seen.xy == (1.0, 1.0)
    assert mates.keep_out(seen, 2.0) == pytest.approx(0.46)
    assert mates.keep_out(seen, 4.0) == pytest.approx(1.46)  # may have driven 1 m since
    assert mates.fresh(5.5) == []  # 3.5 s old: stale


def test_a_status_from_the_future_neither_holds_a_disc_nor_shuts_out_the_true_ones():
    """A forged status far ahead of the mission's clock (anyone on an open bus can send one)
    would, kept, be fresh for ever and make every later true status look older."""
    mates = Teammates("r1", robot_radius=RADIUS, max_speed=0.5, max_age_s=3.0)
    assert not mates.update("r2", 1e12, 5.0, 5.0, now=10.0)
    assert mates.update("r2", 10.0, 1.0, 1.0, now=10.0)
    assert [s.xy for s in mates.fresh(10.5)] == [(1.0, 1.0)]
    mates.latest["r3"] = type(mates.latest["r2"])("r3", (2.0, 2.0), 1e12)  # held from before
    assert [s.robot for s in mates.fresh(10.5)] == ["r2"]  # far ahead of now: not fresh


def test_invented_robot_ids_are_held_up_to_a_bound():
    mates = Teammates("r1", robot_radius=RADIUS, max_speed=0.5)
    kept = sum(mates.update(f"x{k}", 1.0, 0.0, 0.0) for k in range(MAX_TEAMMATES + 50))
    assert kept == MAX_TEAMMATES and len(mates.latest) == MAX_TEAMMATES
    assert mates.update("x0", 2.0, 1.0, 0.0)  # a robot already held is still updated


def test_a_teammate_blocks_the_cells_around_it_and_the_path_into_it():
    trav = TraversabilityGrid.from_blocked(np.zeros((40, 20), bool), (0.0, 0.0), 0.1, RADIUS)
    mates = Teammates("r1", robot_radius=RADIUS, max_speed=0.5)
    mates.update("r2", 10.0, 2.0, 1.0)
    here = np.array([0.5, 1.0])
    discs = mates.discs(10.0, here)
    blocked = block_teammates(trav, discs)
    assert not blocked.is_free(blocked.cell_of(np.array([2.3, 1.0])))
    assert blocked.is_free(blocked.cell_of(np.array([2.6, 1.0])))
    assert trav.is_free(trav.cell_of(np.array([2.3, 1.0])))  # the map's grid is untouched
    assert blocking_teammate(np.array([[3.5, 1.0]]), here, discs) is None  # 1.5 m away
    near = np.array([1.3, 1.0])
    assert blocking_teammate(np.array([[3.5, 1.0]]), near, mates.discs(10.0, near)) == "r2"
    # standing inside the disc already: moving away is allowed, coming nearer is not
    inside = np.array([1.7, 1.0])
    assert mates.discs(10.0, inside)[0][1] == pytest.approx(0.15)  # shrunk for planning
    discs = mates.discs(10.0)
    assert blocking_teammate(np.array([[0.5, 1.0]]), inside, discs) is None
    assert blocking_teammate(np.array([[1.9, 1.0]]), inside, discs) == "r2"


def two_robots(free_band: tuple[float, float] = (0.0, 2.0)) -> dict[str, Explorer]:
    """Explorers r1 at x 1.05 and r2 at x 3.05 of the 4 m x 2 m lab, each driving to the
    other's place along y 1.05, on floor known free (below 1 m) within ``free_band`` of y and
    occupied outside it."""
    mission = load_mission(CONFIGS / "lab.yaml")
    first = mission.robots[0]
    mission.robots = [first, first.model_copy(update={"id": "r2"})]
    robots = {}
    for rid, (start, goal) in {"r1": (1.05, 3.05), "r2": (3.05, 1.05)}.items():
        explorer = Explorer(mission, rid, strategy="entropy")
        cmap, centres = explorer.map, explorer.grid.centres().reshape(-1, 3)
        low = centres[:, 2] < 1.0
        inside = (centres[:, 1] > free_band[0]) & (centres[:, 1] < free_band[1])
        cmap.lam[low] = 400.0
        cmap.eta[low] = np.where(inside[low], 0.0, 400.0)  # mu = 0 free, mu = 1 a wall
        explorer.local.recompute_entropy()
        explorer.target = ExplorationTarget(np.array([goal, 1.05]), 0.0, 1.0, None, "entropy")
        explorer.follower.set_path(np.array([[start, 1.05], [goal, 1.05]]))
        explorer.state = ExplorerState.DRIVE
        explorer.ground.swept = [(start, 1.05)]
        robots[rid] = explorer
    return robots


def drive(
    robots: dict[str, Explorer], frames: int, pose: dict[str, list[float]] | None = None
) -> tuple[float, dict[str, list[str]]]:
    """Run both explorers ``frames`` frames on unicycle kinematics from ``pose`` (rid: [x, y,
    yaw]; default: where ``two_robots`` puts them, facing each other), each told the other's
    pose every frame (as the agents' statuses do): the least distance between them (m) and
    the states each went through."""
    pose = pose or {"r1": [1.05, 1.05, 0.0], "r2": [3.05, 1.05, math.pi]}
    states: dict[str, list[str]] = {rid: [] for rid in robots}
    least = math.inf
    for n in range(frames):
        t = n * PERIOD
        for explorer in robots.values():
            for other, (x, y, _yaw) in pose.items():
                explorer.teammates.update(other, t, x, y)
        decisions = {rid: e.decide(*pose[rid], t) for rid, e in robots.items()}
        for rid, d in decisions.items():
            states[rid].append(d.state)
            x, y, yaw = pose[rid]
            for _ in range(5):  # 0.1 s steps
                x, y, yaw = x + d.v * math.cos(yaw) * 0.1, y + d.v * math.sin(yaw) * 0.1, yaw + d.omega * 0.1
            pose[rid] = [x, y, yaw]
        least = min(least, math.dist(pose["r1"][:2], pose["r2"][:2]))
    return least, states


def test_two_robots_driving_at_each_other_in_a_room_pass_apart():
    # Without teammate avoidance their paths run through each other (distance 0).
    least, states = drive(two_robots(), 40)
    assert least > 2 * RADIUS + 0.05
    assert "gaze" in states["r1"] or "gaze" in states["r2"]  # one of them got there


def test_in_a_corridor_the_later_robot_yields_and_sets_its_target_aside_for_a_while():
    # A corridor 0.7 m wide: no way around. Both stop; r2 (later in the robot list) gives its
    # target up first, set aside for a while (not failed for ever), while r1 still waits.
    robots = two_robots(free_band=(0.7, 1.4))
    least, states = drive(robots, 4 + YIELD_FRAMES + 4)
    assert least > 2 * RADIUS + 0.05
    assert robots["r2"].give_ups == {"teammate": 1}
    assert not any(np.allclose(xy, [1.05, 1.05]) for xy in robots["r2"].memory.failed)
    deferred = robots["r2"].giving_way.deferred
    assert len(deferred) == 1 and np.allclose(deferred[0][0], [1.05, 1.05])
    assert not robots["r1"].give_ups and "choose" not in states["r1"]


def test_a_robot_starting_near_a_teammate_does_not_come_nearer_passing_it():
    # As at the office's start (robots 0.5 m apart): r2 stands 0.5 m from r1 (which stays
    # put) inside its keep-out disc, and its path passes r1 0.4 m away. It must wait (r1
    # comes first), not creep nearer: before the fix the way ahead was checked against the
    # disc shrunk for planning (0.15 m inside the distance), and r2 passed at 0.40 m.
    robots = two_robots()
    robots["r1"].state = "done"
    r2 = robots["r2"]
    r2.target = ExplorationTarget(np.array([0.3, 1.45]), 0.0, 1.0, None, "entropy")
    r2.follower.set_path(np.array([[1.35, 1.45], [0.3, 1.45]]))
    pose = {"r1": [1.05, 1.05, 0.0], "r2": [1.35, 1.45, math.pi]}
    least, states = drive(robots, 8, pose)
    assert least >= 0.5 - 1e-6
    assert "wait" in states["r2"]


def test_a_path_replanned_for_the_map_is_checked_for_teammates_before_it_is_driven():
    # r2's path first leads up and away from r1 (clear of it) but leaves the map, so this
    # frame's periodic replan (every REPLAN_EVERY frames) takes the straight way to the
    # target, which passes r1 0.3 m away. The way ahead must be checked after the replan:
    # before the fix it was checked before, and r2 drove one frame on the new path (0.34 m).
    robots = two_robots()
    robots["r1"].state = "done"
    r2 = robots["r2"]
    r2.target = ExplorationTarget(np.array([0.3, 1.45]), 0.0, 1.0, None, "entropy")
    r2.follower.set_path(np.array([[1.35, 1.45], [1.35, 2.5], [0.3, 2.5], [0.3, 1.45]]))
    r2.frames = REPLAN_EVERY - 1  # the next frame replans
    pose = {"r1": [0.95, 1.15, 0.0], "r2": [1.35, 1.45, math.pi]}
    least, states = drive(robots, 3, pose)
    assert least >= 0.5 - 1e-6
    assert states["r2"][0] == "wait"


def test_a_robot_whose_heading_points_nearer_a_teammate_turns_before_it_drives():
    # r2 stands 0.5 m south of r1 (which stays put), its path runs east (away from r1), but
    # it faces north-east: the follower's arc would first take it nearer r1 (0.45 m in the
    # office's run 6, at 18 s). It turns on the spot first.
    robots = two_robots()
    robots["r1"].state = "done"
    r2 = robots["r2"]
    r2.target = ExplorationTarget(np.array([3.05, 1.05]), 0.0, 1.0, None, "entropy")
    r2.follower.set_path(np.array([[1.05, 1.05], [3.05, 1.05]]))
    pose = {"r1": [1.05, 1.55, 0.0], "r2": [1.05, 1.05, math.radians(50)]}
    least, states = drive(robots, 6, pose)
    assert least >= 0.5 - 1e-6
    assert states["r2"] == ["drive"] * 6 and math.dist(*(p[:2] for p in pose.values())) > 0.5


def test_a_teammate_beyond_the_missions_list_ranks_after_it_and_crashes_nothing():
    """A status with an id nobody configured (anyone on an open bus can send one) ranks after the
    listed robots; meeting such a teammate made the explorer raise ValueError (a robot-list
    index), which ended the agent."""
    ids = ["r1", "r2"]
    assert robot_rank(ids, "r1") < robot_rank(ids, "r2") < robot_rank(ids, "a0") < robot_rank(ids, "r9")
    robots = two_robots()
    assert robots["r1"].giving_way.priority < robots["r2"].giving_way.priority
    r1 = robots["r1"]
    r1.teammates.update("x7", 0.0, 1.6, 1.05)  # on r1's path, 0.55 m ahead
    decision = r1.decide(1.05, 1.05, 0.0, 0.0)
    assert decision.state in ("wait", "drive") and r1.giving_way.waited == 1
