"""The explorer's state machine (the tilt head's look-up after a gaze) and its fusion of far returns."""

from __future__ import annotations

import math

import numpy as np
import pytest

from robot_agent.choosers import TEAM_SPREAD_RADIUS
from robot_agent.decision import ExplorerState, TeamAdvice
from robot_agent.explorer import Explorer
from swarm.config import load_mission, mission_from_dict
from swarm.navigation.exploration import ExplorationTarget
from swarm.navigation.path_follower import NO_PROGRESS_FRAMES
from swarm.protocol.wire import Frame, Pose
from tests.support.paths import CONFIGS


def known_below_1m(explorer: Explorer) -> Explorer:
    """Every voxel below 1 m known free (a sure, empty belief: mu = 0, sigma = 0.05), the air
    above unknown: only 3-D frontier views are left to choose."""
    cmap = explorer.map
    low = explorer.grid.centres().reshape(-1, 3)[:, 2] < 1.0
    cmap.lam[low] = 400.0
    cmap.eta[low] = 0.0
    explorer.local.recompute_entropy()
    return explorer


def gazing_explorer(tilt_range_deg: float) -> Explorer:
    mission = load_mission(CONFIGS / "lab.yaml")
    mission.rig.tilt_range_deg = tilt_range_deg
    explorer = Explorer(mission, "r1")
    explorer.state = ExplorerState.GAZE
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
    explorer.local.recompute_entropy()
    explorer.state = ExplorerState.CHOOSE
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
    advice = TeamAdvice(ExplorationTarget(here + 0.05, 0.3, 1.0, None, "entropy"))
    explorer.state = ExplorerState.CHOOSE
    states = []
    for _ in range(3):
        assert explorer.wants_target  # the agent would ask the coordinator now
        decision = explorer.decide(here[0], here[1], 0.3, advice=advice)  # facing the gaze already
        states.append(decision.state)
    assert states == ["gaze", "gaze", "choose"]
    assert len(explorer.memory.failed) == 1 and np.allclose(explorer.memory.failed[0], here + 0.05)


def test_a_coordinator_target_the_robot_gave_up_is_declined_and_the_robot_chooses_alone():
    # The coordinator does not know which spots a robot gave up: holding one best candidate,
    # it offers the same spot again and again (seen on the AWS hospital map: one spot 177 times
    # in 110 s of wall clock, the robot gazing from where it stood). After giving the spot up, the robot
    # declines it and takes its own target (here a 3-D view of the unknown air above 1 m).
    explorer = known_below_1m(gazing_explorer(0.0))
    here = np.array([1.0, 1.0])
    advice = TeamAdvice(ExplorationTarget(here + 0.05, 0.3, 1.0, None, "assigned"))
    explorer.state = ExplorerState.CHOOSE
    states = [explorer.decide(here[0], here[1], 0.3, advice=advice).state for _ in range(3)]
    assert states == ["gaze", "gaze", "choose"]  # looked twice, then gave the spot up
    decision = explorer.decide(here[0], here[1], 0.3, advice=advice)
    assert explorer.target is not None and explorer.target.kind != "assigned"
    assert decision.state == "drive" and np.hypot(*(explorer.target.xy - here)) >= 0.15
    assert explorer.declined_assignments == 1


def test_a_wall_beyond_the_rigs_hit_range_is_free_space_up_to_it_and_no_hit():
    """A depth frame of a wall 4 m ahead: a hit with no hit range; with a 3 m one, free space
    up to 3 m only. The default stereo rig's hit range is auto: 3.53 m at 0.1 m voxels."""

    def explorer(rig: dict) -> Explorer:
        mission = mission_from_dict(
            {
                "mission": "wall",
                "workspace": {"lo": [0.0, 0.0, 0.0], "hi": [8.0, 4.0, 2.0], "voxel": 0.1},
                "robots": [{"id": "r1", "start": {"x": 1.0, "y": 2.0}}],
                "rig": rig,
                "stop": {"entropy_threshold_bits": 1.0},
            }
        )
        return Explorer(mission, "r1")

    def fused(explorer: Explorer) -> tuple[np.ndarray, np.ndarray]:
        cam = explorer.rig.camera()
        depth = np.full((cam.height, cam.width), 4.0, np.float32)
        frame = Frame("r1", 0, 0.0, Pose((1.0, 2.0, 0.4), (0.0, 0.0, 0.0)), cam, "f32", depth=depth)
        delta = explorer.fuse(frame)
        centres = explorer.grid.centre(explorer.grid.unflat(delta.idx.astype(np.int64)))
        occupied = delta.deta > 0.5 * delta.dlam
        return np.linalg.norm(centres - [1.0, 2.0, 0.4], axis=1), occupied

    depth_rig = {"mode": "range", "width": 32, "height": 24, "range_noise": 0.0}
    dist, occupied = fused(explorer({**depth_rig, "hit_range": None}))
    assert occupied.any() and dist[occupied].min() > 3.9
    dist, occupied = fused(explorer({**depth_rig, "hit_range": 3.0}))
    assert not occupied.any() and 2.9 < dist.max() <= 3.0 + 0.5 * math.sqrt(3) * 0.1
    stereo = explorer({"hit_range": "auto"})
    assert stereo.sensor.hit_range == pytest.approx(3.53, abs=0.01)
    assert stereo.camera.max_range == pytest.approx(stereo.sensor.hit_range)  # view targets within it


def test_a_frontier_robot_forgets_the_spots_it_gave_up_before_concluding_it_is_done():
    # Every voxel below 1 m known free, the air above unknown: no 2-D frontier, only 3-D
    # frontier views. Given-up spots (1 m around each) cover all the floor, as four did in
    # the lab, and the robot has made its last turn: the frontier robot forgets them and
    # looks on; the entropy robot is unchanged (done, keeping them).
    mission = load_mission(CONFIGS / "lab.yaml")
    spots = [np.array([x, y]) for x in (0.5, 1.5, 2.5, 3.5) for y in (0.5, 1.5)]
    for strategy in ("frontier", "entropy"):
        explorer = known_below_1m(Explorer(mission, "r1", strategy=strategy))
        explorer.memory.failed = list(spots)
        explorer.looked_before_done = True
        explorer.state = ExplorerState.CHOOSE
        decision = explorer.decide(1.05, 1.05, 0.0)
        if strategy == "frontier":
            assert explorer.target_kinds == {"frontier3d": 1}
            assert explorer.memory.failed == [] and decision.state in ("gaze", "drive")
        else:
            assert not explorer.target_kinds and len(explorer.memory.failed) == len(spots)
            assert decision.state == "done"


def test_an_entropy_robot_does_not_choose_a_column_its_teammates_went_to_look_at():
    # Every voxel below 1 m known free, the air above unknown: only 3-D frontier views are
    # left. A robot alone chooses a column; told (by the coordinator) that a teammate went to
    # look at that column, an identical robot chooses another one.
    mission = load_mission(CONFIGS / "lab.yaml")

    def chosen(team_views):
        explorer = known_below_1m(Explorer(mission, "r1", strategy="entropy"))
        explorer.state = ExplorerState.CHOOSE
        explorer.decide(1.05, 1.05, 0.0, advice=TeamAdvice(views=[np.asarray(v) for v in team_views]))
        assert explorer.target_kinds == {"view": 1}
        return explorer.view_point()

    alone = chosen([])
    assert alone is not None and 1.0 <= alone[2] < 1.1  # the first unknown layer above the known air
    told = chosen([alone[:2]])
    assert told is not None and math.dist(told[:2], alone[:2]) > 0.25


def test_a_robot_choosing_alone_keeps_away_from_where_its_teammates_head():
    # Only 3-D frontier views are left (as above). Told that a teammate heads to the spot a
    # robot alone would stand on, an identical robot stands TEAM_SPREAD_RADIUS away from it;
    # told that teammates head everywhere, it still chooses a view rather than stopping.
    mission = load_mission(CONFIGS / "lab.yaml")

    def stand(team_goals):
        explorer = known_below_1m(Explorer(mission, "r1", strategy="entropy"))
        explorer.state = ExplorerState.CHOOSE
        explorer.decide(
            1.05, 1.05, 0.0, advice=TeamAdvice(goals=[np.asarray(g, dtype=np.float64) for g in team_goals])
        )
        assert explorer.target_kinds == {"view": 1}
        return np.asarray(explorer.target.xy)

    alone = stand([])
    told = stand([alone])
    assert np.hypot(*(told - alone)) > TEAM_SPREAD_RADIUS
    lo, hi = mission.workspace.grid().lo, mission.workspace.grid().hi
    everywhere = [(x, y) for x in np.arange(lo[0], hi[0], 0.5) for y in np.arange(lo[1], hi[1], 0.5)]
    assert np.allclose(stand(everywhere), alone)


def test_a_robot_that_rocks_to_and_fro_gives_its_target_up():
    # Driving to a target 2 m ahead on known free floor: a robot that advances keeps it; one
    # that moves back and forth (pushing against a teammate in a narrow corridor) moves more
    # than 5 cm every few frames, so it is never "stuck", yet never gets nearer: after
    # NO_PROGRESS_FRAMES it gives the target up.
    mission = load_mission(CONFIGS / "lab.yaml")

    def driving() -> Explorer:
        explorer = known_below_1m(Explorer(mission, "r1", strategy="entropy"))
        explorer.target = ExplorationTarget(np.array([3.05, 1.05]), 0.0, 1.0, None, "entropy")
        explorer.follower.set_path(np.array([[1.05, 1.05], [2.05, 1.05], [3.05, 1.05]]))
        explorer.state = ExplorerState.DRIVE
        return explorer

    steady = driving()
    for n in range(18):
        assert steady.decide(1.05 + 0.1 * n, 1.05, 0.0).state == "drive"
    assert not steady.give_ups
    rocking = driving()
    states = [rocking.decide(1.05 + 0.04 * (n % 4), 1.05, 0.0).state for n in range(NO_PROGRESS_FRAMES + 6)]
    assert "choose" in states and states.index("choose") <= NO_PROGRESS_FRAMES + 4
    assert rocking.give_ups == {"no progress": 1}
    assert len(rocking.memory.failed) == 1 and np.allclose(rocking.memory.failed[0], [3.05, 1.05])


def test_an_entropy_robot_looks_at_what_is_still_uncertain_before_it_stops():
    # Everything known: below 1 m surely free (sigma 0.02), above seen faintly once. No eq. 35
    # target, probe or 3-D frontier is left. Where it used to stop (after its last turn), the
    # robot first goes to look at an uncertain column in view, and stops only when nothing
    # holds more than half the prior's entropy.
    mission = load_mission(CONFIGS / "lab.yaml")

    def after_last_turn(faint: bool) -> Explorer:
        explorer = Explorer(mission, "r1", strategy="entropy")
        cmap = explorer.map
        low = explorer.grid.centres().reshape(-1, 3)[:, 2] < 1.0
        cmap.lam[:] = 1.0 / 0.02**2
        cmap.eta[:] = 0.0
        if faint:
            cmap.lam[~low] = 4.0
            cmap.eta[~low] = 2.0
        explorer.local.recompute_entropy()
        explorer.looked_before_done = True
        explorer.state = ExplorerState.CHOOSE
        explorer.decide(1.05, 1.05, 0.0)
        return explorer

    looking = after_last_turn(faint=True)
    assert looking.target_kinds == {"last look": 1} and looking.state in ("gaze", "drive")
    assert looking.view_point() is not None and looking.view_point()[2] >= 1.0
    assert looking.entropy.values[looking.target.voxel] > looking.search.last_look_bits
    settled = after_last_turn(faint=False)
    assert not settled.target_kinds and settled.state == "done"


def test_the_explorer_wants_a_target_only_when_it_is_about_to_choose_one():
    # The agent asks the coordinator only then; the answer comes in with the decision, and a
    # decision without one never asks anyone (there is no callback into the agent).
    explorer = gazing_explorer(0.0)
    assert not explorer.wants_target  # gazing
    explorer.decide(1.0, 1.0, 0.3)  # on the gaze: choose next
    assert explorer.state is ExplorerState.CHOOSE and explorer.wants_target
    explorer.failures_in_a_row = 6  # MAX_FAILURES: it turns on the spot instead of choosing
    assert not explorer.wants_target
    explorer.failures_in_a_row = 0
    explorer.threshold = explorer.map_entropy + 1.0  # below H_th: done, nothing to choose
    assert not explorer.wants_target
    assert explorer.decide(1.0, 1.0, 0.3).state == "done" and explorer.state is ExplorerState.DONE


@pytest.mark.parametrize(
    ("strategy", "rungs"),
    [
        ("entropy", ["AssignedTarget", "SpreadFromTeam", "OwnTarget", "LastLook"]),
        ("frontier", ["AssignedTarget", "SpreadFromTeam", "OwnTarget", "LookAgain"]),
        ("random", ["AssignedTarget", "SpreadFromTeam", "OwnTarget"]),
    ],
)
def test_the_fallback_ladder_is_one_ordered_list_per_strategy(strategy, rungs):
    explorer = Explorer(load_mission(CONFIGS / "lab.yaml"), "r1", strategy=strategy)
    assert [type(c).__name__ for c in explorer.choosers] == rungs


def test_an_unknown_strategy_is_refused_naming_the_strategies():
    with pytest.raises(ValueError, match=r"unknown exploration strategy 'spiral'.*entropy"):
        Explorer(load_mission(CONFIGS / "lab.yaml"), "r1", strategy="spiral")
