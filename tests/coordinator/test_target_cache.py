"""The coordinator's per-tile eq. 35 cache: the same candidates as the whole-map pass."""

from __future__ import annotations

import math

import numpy as np
import pytest

from coordinator.state import CoordinatorState
from swarm.bench.coordinator import CAMERA_HEIGHT, floor_plan, frame_points
from swarm.config import mission_from_dict
from swarm.map.fusion import batch_information
from swarm.navigation.target_cache import TILE, ChangedTiles, tiles_any
from swarm.protocol.wire import AssignRequest, DeltaMessage, Pose, Snapshot

MISSION = {
    "mission": "cachetest",
    "workspace": {"lo": [0.0, 0.0, 0.0], "hi": [19.2, 12.8, 1.2], "voxel": 0.1},
    "robots": [{"id": "r1"}, {"id": "r2"}, {"id": "r3"}],
    "rig": {"camera_height": 0.4},
    "sensor": {"max_range": 3.0},
    "exploration": {"radius": 1.0},
}


WALLS = floor_plan((19.2, 12.8), 0.1)
FREE = np.argwhere(~WALLS[3:-3, 3:-3]) + 3


def frame(state: CoordinatorState, rng: np.random.Generator, robot: str, seq: int) -> DeltaMessage:
    """A camera frame (swarm bench coordinator's) from a random free cell of the office floor,
    facing a random way: a change local to a few tiles."""
    grid = state.team.grid
    xy = (FREE[rng.integers(len(FREE))] + 0.5) * grid.voxel
    pts = frame_points(WALLS, grid.voxel, float(grid.hi[2]), xy, rng.uniform(-math.pi, math.pi), 3.0)
    origin = np.array([xy[0], xy[1], CAMERA_HEIGHT])
    delta = batch_information(grid, state.team.map.sensor, origin, pts).delta
    return DeltaMessage(robot, 1, seq, 0.0, grid, delta.idx, delta.dlam, delta.deta)


def same_candidates(a, b) -> None:
    assert len(a) == len(b)
    for x, y in zip(a, b, strict=True):
        assert x.voxel == y.voxel
        assert np.array_equal(x.xy, y.xy) and np.array_equal(x.point, y.point)
        assert x.gaze_yaw == y.gaze_yaw and x.utility == y.utility and x.path_cost == y.path_cost


def same_floor(state: CoordinatorState, robot: str, pose: Pose) -> None:
    """The kept traversability and cost map are build_traversability's and the planner's."""
    _, full, full_cost = state._reach_full(robot, pose, state.team.copy()[0])
    with state.team.lock:
        _, kept = state._floor(robot, pose)
    kept_cost = state._cost_map(kept, pose)
    for name in ("free", "occupied", "unknown"):
        assert np.array_equal(getattr(full, name), getattr(kept, name)), name
    assert np.array_equal(full_cost, kept_cost)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_cached_candidates_equal_the_whole_map_pass_after_random_deltas(seed):
    rng = np.random.default_rng(seed)
    state = CoordinatorState(mission_from_dict(MISSION))
    seq = {"r1": 0, "r2": 0, "r3": 0}
    checked = 0
    for k in range(1, 41):  # a partly explored floor first
        state.team.apply_message(frame(state, rng, "r1", k))
    seq["r1"] = 40
    places = {r: (FREE[rng.integers(len(FREE))] + 0.5) * 0.1 for r in seq}
    for step in range(16):
        for _ in range(int(rng.integers(0, 3))):  # 0-2 deltas between two answers
            robot = f"r{int(rng.integers(1, 4))}"
            seq[robot] += 1
            msg = frame(state, rng, robot, seq[robot])
            if len(msg.idx):
                state.team.apply_message(msg)
        robot = f"r{int(rng.integers(1, 4))}"
        if rng.random() < 0.3:  # the robot moved
            places[robot] = (FREE[rng.integers(len(FREE))] + 0.5) * 0.1
        xy = places[robot]
        pose = Pose((xy[0], xy[1], 0.4), (float(rng.uniform(-math.pi, math.pi)), 0.0, 0.0))
        state._moved(robot, pose.xyz)
        full = state.candidates_for(robot, pose, *state.team.copy())
        cached = state.cached_candidates(robot, pose)
        same_candidates(full, cached)
        same_floor(state, robot, pose)
        checked += len(full)
        if step % 4 == 3:  # answers use the cache too, and leave it as the oracle finds it
            state.answer(AssignRequest(robot, pose), now=float(step))
    assert checked > 0
    slab = next(iter(state.targets._slabs.values()))
    assert slab.counts["memo"] > 0  # standing cells came from the memo


def test_a_loaded_snapshot_counts_as_every_tile_changed():
    rng = np.random.default_rng(5)
    state = CoordinatorState(mission_from_dict(MISSION))
    state.team.apply_message(frame(state, rng, "r1", 1))
    pose = Pose((10.0, 6.0, 0.4), (0.0, 0.0, 0.0))
    state.cached_candidates("r1", pose)
    other = CoordinatorState(mission_from_dict(MISSION))
    for k in range(1, 6):
        other.team.apply_message(frame(other, rng, "r2", k))
    m = other.team.map
    state.team.load_snapshot(Snapshot(m.grid, m.lam, m.eta, {}, {}))
    same_candidates(state.candidates_for("r1", pose, *state.team.copy()), state.cached_candidates("r1", pose))


def test_changed_tiles_mark_the_tiles_whose_differences_read_a_voxel():
    nx, ny, nz = 2 * TILE, 2 * TILE, 3
    changes = ChangedTiles((nx, ny, nz))
    assert changes.take("a").all()  # the first take: everything
    changes.mark(np.array([((TILE - 1) * ny + 5) * nz + 1]))  # column (TILE - 1, 5)
    seen = changes.take("a")
    assert seen.tolist() == [[True, False], [True, False]]  # its tile and the one at i + 1
    assert not changes.take("a").any()
    mask = np.zeros((nx - 3, ny), dtype=bool)
    mask[-1, -1] = True
    assert tiles_any(mask).tolist() == [[False, False], [False, True]]


def marked_by_numpy(shape, idx, tile=TILE) -> np.ndarray:
    """The oracle of ChangedTiles.mark: each voxel's tile and those of columns (i+1, j), (i, j+1)."""
    nx, ny, nz = shape
    cols = idx // nz
    i, j = cols // ny, cols % ny
    out = np.zeros((math.ceil(nx / tile), math.ceil(ny / tile)), dtype=bool)
    for ii, jj in ((i, j), (np.minimum(i + 1, nx - 1), j), (i, np.minimum(j + 1, ny - 1))):
        out[ii // tile, jj // tile] = True
    return out


@pytest.mark.parametrize("seed", range(4))
def test_compiled_marks_equal_the_numpy_formula(seed):
    rng = np.random.default_rng(seed)
    shape = tuple(int(n) for n in rng.integers([TILE, TILE, 1], [5 * TILE, 5 * TILE, 30]))
    size = math.prod(shape)
    idx = np.concatenate([rng.integers(0, size, int(rng.integers(1, 3000))), [0, size - 1]])
    changes = ChangedTiles(shape)
    changes.take("a"), changes.take("b")
    changes.mark(idx)
    expected = marked_by_numpy(shape, idx)
    assert np.array_equal(changes.take("a"), expected) and np.array_equal(changes.take("b"), expected)


def test_a_voxel_outside_the_grid_marks_nothing_and_raises():
    changes = ChangedTiles((TILE, TILE, 2))
    changes.take("a")
    for bad in (-1, TILE * TILE * 2):
        with pytest.raises(IndexError, match="outside a grid"):
            changes.mark(np.array([3, bad]))
        assert not changes.take("a").any()


def test_the_swept_floor_follows_the_positions_kept_and_dropped(monkeypatch):
    monkeypatch.setattr("coordinator.state.MAX_SWEPT", 7)
    rng = np.random.default_rng(3)
    state = CoordinatorState(mission_from_dict(MISSION))
    for k in range(1, 6):
        state.team.apply_message(frame(state, rng, "r1", k))
    for step in range(30):
        xy = (rng.uniform(0.0, 19.2), rng.uniform(0.0, 12.8))
        state._moved("r2", (xy[0], xy[1], 0.4))
        if step % 5 == 4:
            assert len(state._swept) <= 7
            same_floor(state, "r2", Pose((xy[0], xy[1], 0.4), (0.0, 0.0, 0.0)))
