"""The coordinator's state without I/O (coordinator.state): the team spread, its own ground,
wandering, nothing left, a replica started from a snapshot, targets given back."""

from __future__ import annotations

import dataclasses
import math

import msgpack
import numpy as np
import pytest
from scipy import ndimage

from coordinator.replica import CoordinatorReplica
from coordinator.state import CoordinatorState, params_from_mission
from map_server.team_map import MergedMap
from swarm.map.coverage_map import CoverageMap
from swarm.navigation.exploration import SearchContext, wander_target
from swarm.navigation.planner import GridPlanner
from swarm.navigation.traversability import build_traversability
from swarm.protocol.wire import AssignReply, AssignRequest, Pose, Snapshot, Status
from tests.support.coordinator_scene import (
    FOOTPRINT,
    corridor_map,
    deltas_of,
    far_apart,
    known_everywhere,
    mission,
    pose,
)


def test_state_spreads_three_robots_and_gives_a_released_target_back():
    m = mission()
    assert params_from_mission(m).footprint_radius == FOOTPRINT
    # Burgard's rule alone: the map comes from "r9", so all of it is teammates' ground
    state = CoordinatorState(m, dataclasses.replace(params_from_mission(m), overlap_weight=0.0))
    for msg in deltas_of(m, corridor_map(m), "r9", 1, 3):
        assert state.team.apply_payload(msg.encode()) == "applied"
    answers = {r: state.answer(AssignRequest(r, pose(r)), now=0.0) for r in ("r1", "r2", "r3")}
    targets = [a.reply.target for a in answers.values()]
    assert all(t is not None for t in targets)
    assert far_apart(targets, FOOTPRINT)
    for a in answers.values():
        assert a.reply.utility == pytest.approx(a.candidate.utility) and a.reply.utility > 0
        assert np.linalg.norm(a.reply.gaze) == pytest.approx(1.0)
        assert 0.3 <= a.reply.target[0] <= 7.7 and 1.5 <= a.reply.target[1] <= 2.5  # in the corridor
    # r1 goes silent: after the timeout r4, standing where r1 stood, gets r1's target
    # before that, r4 gets the spot least crowded by the three: no place of the corridor is
    # a footprint from all of them, so the discount decides (3.5 m between r2 and r3)
    before = state.answer(AssignRequest("r4", pose("r1")), now=5.0).reply.target
    assert min(math.dist(before[:2], t[:2]) for t in targets) > 1.4
    state.on_status(Status("r2", 0.0, pose("r2"), answers["r2"].reply.target, "drive", 0).encode(), 9.0)
    state.on_status(Status("r3", 0.0, pose("r3"), answers["r3"].reply.target, "drive", 0).encode(), 9.0)
    r4 = state.answer(AssignRequest("r4", pose("r1")), now=10.5)
    assert r4.reply.target == pytest.approx(answers["r1"].reply.target)
    assert state.counts["released"] == 2  # r1 (silent) and r4's first target (asked again)


@pytest.mark.parametrize(("weight", "glance"), [(1.0, False), (1.0, True), (0.0, False)])
def test_a_robot_is_sent_to_extend_its_own_ground(weight, glance):
    # r1 mapped the corridor's west part, r2 its east part; r1 stands just inside r2's part.
    # Frontiers line the whole corridor. With the overlap weight r1 is sent back west, to
    # the edge of its own ground; with Burgard's rule alone it takes one near where it stands.
    m = mission()
    state = CoordinatorState(m, dataclasses.replace(params_from_mission(m), overlap_weight=weight))
    for rid, (x_lo, x_hi) in {"r1": (0.3, 4.0), "r2": (4.0, 7.7)}.items():
        for msg in deltas_of(m, corridor_map(m, x_lo, x_hi), rid, 1, 2):
            assert state.team.apply_payload(msg.encode()) == "applied"
    if glance:
        # r1 also saw all of r2's part, faintly (a hundredth of r2's information): the part
        # stays r2's ground, so r1 is still sent west
        (faint,) = deltas_of(m, corridor_map(m, 4.0, 7.7), "r1", 2, 1)
        faint = dataclasses.replace(faint, dlam=faint.dlam / 100, deta=faint.deta / 100)
        assert state.team.apply_payload(faint.encode()) == "applied"
    here = Pose((4.8, 2.0, 0.4), (0.0, 0.0, 0.0))
    x = state.answer(AssignRequest("r1", here), now=0.0).reply.target[0]
    if weight:
        assert x < 4.0 - FOOTPRINT / 2
    else:
        assert x > 4.0


def test_wander_keeps_off_teammates_ground_and_stops_when_nothing_is_unknown():
    m = mission()
    cmap = corridor_map(m)
    trav = build_traversability(cmap, robot_height=0.5, robot_radius=m.robot.radius)
    here = (4.05, 2.05, 0.0)
    cost = GridPlanner(trav).cost_map(tuple(int(c) for c in trav.cell_of(np.array(here[:2]))))
    theirs = np.zeros(trav.shape, dtype=bool)
    theirs[:40] = True  # x < 4 m: teammates' ground
    rng = np.random.default_rng(0)
    ctx = SearchContext.build(cmap, np.zeros(cmap.grid.size), here, 0.4, trav, cost)
    xs = []
    for _ in range(40):
        t = wander_target(ctx, 3.0, rng, avoid=theirs)
        assert t.kind == "wander" and trav.is_free(trav.cell_of(t.xy))
        assert math.dist(t.xy, here[:2]) <= 3.0 + 1e-9
        xs.append(t.xy[0])
    assert min(xs) >= 4.0
    unconstrained = [wander_target(ctx, 3.0, rng).xy[0] for _ in range(40)]
    assert min(unconstrained) < 4.0  # the rule, not chance, kept it east
    # when every reachable cell is teammates' ground, it still wanders
    assert wander_target(ctx, 3.0, rng, avoid=~theirs | theirs) is not None
    # nothing unknown in view of reachable space: nothing to wander for
    known = known_everywhere(m)
    trav_k = build_traversability(known, robot_height=0.5, robot_radius=m.robot.radius)
    cost_k = GridPlanner(trav_k).cost_map(tuple(int(c) for c in trav_k.cell_of(np.array(here[:2]))))
    known_ctx = SearchContext.build(known, np.zeros(known.grid.size), here, 0.4, trav_k, cost_k)
    assert wander_target(known_ctx, 3.0, rng) is None


def test_a_robot_whose_only_targets_are_taken_wanders_and_one_with_nothing_unknown_is_told_so():
    # a pocket of known floor 0.4 m x 1 m gives three eq. 35 targets from two standing
    # points; once r1 and r2 hold them, the third is at a held target (U' = 0), so the
    # coordinator sends r3 to wander instead of telling it nothing is left
    m = mission()
    state = CoordinatorState(m, params_from_mission(m))
    for msg in deltas_of(m, corridor_map(m, 0.8, 1.2), "r9", 1, 2):
        assert state.team.apply_payload(msg.encode()) == "applied"
    here = Pose((1.0, 2.0, 0.4), (0.0, 0.0, 0.0))
    first = state.answer(AssignRequest("r1", here), now=0.0)
    second = state.answer(AssignRequest("r2", here), now=0.1)
    assert first.candidate is not None and second.candidate is not None
    third = state.answer(AssignRequest("r3", here), now=0.2)
    assert (third.candidates, third.held_by_others) == (3, 2)
    assert third.candidate is None and third.wander is not None and third.wander.kind == "wander"
    assert third.reply.utility == 0.0 and third.reply.target is not None
    x, y, _ = third.reply.target
    assert 0.8 <= x <= 1.2 and 1.5 <= y <= 2.5  # known free floor: reachable
    assert np.linalg.norm(third.reply.gaze) == pytest.approx(1.0)
    assert (state.counts["assigned"], state.counts["wander"]) == (2, 1)
    # a map with nothing unknown left: no target, no wander, and the robot is told so
    done = CoordinatorState(m, params_from_mission(m))
    for msg in deltas_of(m, known_everywhere(m), "r9", 1, 2):
        assert done.team.apply_payload(msg.encode()) == "applied"
    nothing = done.answer(AssignRequest("r1", here), now=0.0)
    assert nothing.reply.target is None and nothing.candidate is None and nothing.wander is None
    assert done.counts["nothing_left"] == 1


@pytest.mark.parametrize("seed", range(4))
def test_random_maps_never_crowd_robots_while_room_is_left(seed):
    rng = np.random.default_rng(seed)
    m = mission()
    for trial in range(3):
        state = CoordinatorState(m)
        cmap = CoverageMap(m.workspace.grid(), m.sensor.model())
        nx, ny, nz = cmap.grid.shape
        known = ndimage.binary_dilation(rng.random((nx, ny)) < 0.01, iterations=int(rng.integers(4, 10)))
        occupied = known & ndimage.binary_dilation(rng.random((nx, ny)) < 0.01, iterations=1)
        lam, eta = cmap.lam.reshape(nx, ny, nz), cmap.eta.reshape(nx, ny, nz)
        lam[known] = 1.0 / 0.03**2
        eta[known] = np.where(occupied[known], 1.0, 0.0)[:, None] * lam[known]
        for msg in deltas_of(m, cmap, "r9", trial + 1, 2):
            state.team.apply_payload(msg.encode())
        trav = build_traversability(cmap, robot_height=0.5, robot_radius=m.robot.radius)
        free = np.argwhere(trav.free)
        if len(free) < 3:
            continue
        held: list[np.ndarray] = []
        for k, cell in enumerate(free[rng.choice(len(free), 3, replace=False)]):
            x, y = trav.centre(cell)
            robot_pose = Pose((float(x), float(y), 0.4), (float(rng.uniform(-3, 3)), 0.0, 0.0))
            answer = state.answer(AssignRequest(f"r{k}", robot_pose), now=float(k))
            found = state.candidates_for(f"r{k}", robot_pose, *state.team.copy())  # what it chose from
            if answer.reply.target is None:
                assert not found
                continue
            target = np.array(answer.reply.target[:2])
            assert any(np.allclose(c.xy, target) for c in found)
            room = [c for c in found if all(np.hypot(*(c.xy - h)) >= FOOTPRINT for h in held)]
            if room:
                assert all(np.hypot(*(target - h)) >= FOOTPRINT for h in held), (seed, trial, k)
            assert all(np.hypot(*(target - h)) > 0 for h in held)
            held.append(target)


def test_a_replica_started_from_a_snapshot_adds_no_delta_twice_even_beyond_the_acks():
    """Seq 1 is late at the server, 2 and 3 are in its map: the snapshot's acks cover nothing,
    its ``above`` covers 2 and 3, so the replica takes only seq 1 from the merged stream."""
    m = mission()
    grid, sensor = m.workspace.grid(), m.sensor.model()
    d1, d2, d3 = deltas_of(m, corridor_map(m), "r9", 1, 3)
    server = MergedMap(grid, sensor)
    for msg in (d2, d3):
        assert server.admit(msg)
        server.apply(msg)
    snap = Snapshot.decode(server.snapshot().encode())
    assert snap.acks == {"r9": {1: 0}} and snap.above == {"r9": {1: [2, 3]}}

    replica = CoordinatorReplica(grid, sensor)
    replica.load_snapshot(snap)
    assert [replica.apply_payload(msg.encode()) for msg in (d3, d1, d2, d1)] == [
        "duplicate",
        "applied",
        "duplicate",
        "duplicate",
    ]
    assert server.admit(d1)
    server.apply(d1)
    np.testing.assert_allclose(replica.map.lam, server.cmap.lam, rtol=1e-6)
    np.testing.assert_allclose(replica.map.eta, server.cmap.eta, rtol=1e-6, atol=1e-3)


def test_a_robot_given_back_its_own_old_target_is_asked_to_flush():
    """Flush on demand: the replica has not changed since r1 was sent to the only place left,
    so what r1 saw there is still in its outbox; handing the place back says "flush"."""
    m = mission()
    state = CoordinatorState(m)
    for msg in deltas_of(m, corridor_map(m, 0.3, 1.8), "r9", 1, 2):
        state.team.apply_payload(msg.encode())
    first = state.answer(AssignRequest("r1", pose("r1")), now=0.0)
    assert first.candidate is not None and not first.reply.flush
    again = state.answer(AssignRequest("r1", pose("r1")), now=1.0)
    assert again.candidate is not None
    assert math.dist(again.reply.target[:2], first.reply.target[:2]) < 1.0
    assert again.reply.flush and state.counts["flush_asked"] == 1
    # the field travels, and a reply without it (an older coordinator) means no flush
    assert AssignReply.decode(again.reply.encode()).flush
    old = msgpack.packb({"v": 1, "target": None, "gaze": None, "utility": 0.0})
    assert not AssignReply.decode(old).flush


def test_a_nothing_left_answer_names_the_columns_teammates_went_to_look_at():
    """Status.view and AssignReply.views (additions to protocol v1): with no eq. 35 target left,
    a robot chooses its own 3-D views; the coordinator tells it which columns the others
    went to look at (in their statuses), its own excluded, so no column is looked at twice."""
    m = mission()
    state = CoordinatorState(m)
    for msg in deltas_of(m, known_everywhere(m), "r9", 1, 2):
        state.team.apply_payload(msg.encode())
    looks = {"r2": [(3.05, 1.15, 1.85), (3.05, 1.15, 1.85), (5.25, 2.95, 1.65)], "r1": [(0.55, 0.55, 1.2)]}
    for robot, views in looks.items():
        for n, view in enumerate(views):
            status = Status(robot, float(n), pose(robot), (1.0, 2.0, 0.0), "drive", 0, view)
            state.on_status(status.encode(), now=float(n))
    state.on_status(Status("r3", 0.0, pose("r3"), None, "choose", 0).encode(), now=3.0)  # no view
    answer = state.answer(AssignRequest("r1", pose("r1")), now=4.0)
    assert answer.reply.target is None
    # r2's two columns, once each and in order; not r1's own
    assert answer.reply.views == ((3.05, 1.15), (5.25, 2.95))
    assert AssignReply.decode(answer.reply.encode()).views == answer.reply.views
    assert state.answer(AssignRequest("r2", pose("r2")), now=5.0).reply.views == ((0.55, 0.55),)


def test_a_nothing_left_answer_says_where_the_others_are_heading():
    """AssignReply.goals (an addition to protocol v1): the targets the coordinator holds for
    the other live robots (their statuses' own choices included), never the asker's own, so
    a robot choosing alone can keep away from them."""
    m = mission()
    state = CoordinatorState(m)
    for msg in deltas_of(m, known_everywhere(m), "r9", 1, 2):
        state.team.apply_payload(msg.encode())
    heading = {"r1": (0.5, 0.5, 0.0), "r2": (3.0, 1.5, 0.0)}
    for robot, target in heading.items():
        state.on_status(Status(robot, 0.0, pose(robot), target, "drive", 0).encode(), now=0.0)
    state.on_status(Status("r3", 0.0, pose("r3"), None, "choose", 0).encode(), now=0.0)
    answer = state.answer(AssignRequest("r1", pose("r1")), now=1.0)
    assert answer.reply.target is None
    assert answer.reply.goals == ((3.0, 1.5),)
    assert AssignReply.decode(answer.reply.encode()).goals == answer.reply.goals
    # r1 asked, so it holds nothing now; r2 still heads to its target
    assert state.answer(AssignRequest("r3", pose("r3")), now=2.0).reply.goals == ((3.0, 1.5),)
    # a robot silent past the timeout holds nothing
    later = 2.0 + state.params.robot_timeout_s + 1.0
    assert state.answer(AssignRequest("r3", pose("r3")), now=later).reply.goals == ()
