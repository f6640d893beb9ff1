"""What a mission's sensors can ever observe (sim2d.observability), the observable-rule H_th
(swarm.mission.threshold) and surface accuracy/completeness (swarm.mission.surface_quality)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from sim2d.observability import ObservabilityModel, observable_voxels, reachable_floor
from swarm.config import ConfigError, mission_from_dict
from swarm.formats.floor_plan import FloorPlan, rectangle
from swarm.map.coverage_map import prior_entropy_bits
from swarm.map.grid import Grid
from swarm.mission import surface_quality as sq
from swarm.mission.threshold import resolve_threshold, threshold_parts


def _plan(quads, heights, lo=(0, 0), hi=(4, 3)) -> FloorPlan:
    return FloorPlan(
        quads=np.array(quads), heights=np.array(heights, float), lo=np.array(lo), hi=np.array(hi)
    )


def _room_plan() -> FloorPlan:
    """A 4 m x 3 m room with 0.2 m walls 1.0 m high, a sealed 0.6 m closet in one corner (walls
    1.0 m high all round) and a solid 0.5 m block 0.3 m high."""
    walls = [
        rectangle(np.array([2.0, 0.1]), np.array([4.0, 0.2])),
        rectangle(np.array([2.0, 2.9]), np.array([4.0, 0.2])),
        rectangle(np.array([0.1, 1.5]), np.array([0.2, 3.0])),
        rectangle(np.array([3.9, 1.5]), np.array([0.2, 3.0])),
        # the closet: x 3.0-3.8, y 2.0-2.8 inside, closed by two walls
        rectangle(np.array([3.4, 1.9]), np.array([1.0, 0.2])),
        rectangle(np.array([2.9, 2.4]), np.array([0.2, 0.8])),
    ]
    block = rectangle(np.array([1.5, 1.5]), np.array([0.5, 0.5]))
    return _plan([*walls, block], [1.0] * 6 + [0.3])


MODEL = ObservabilityModel(
    camera_height=0.4,
    elevation_lo=-math.radians(40),
    elevation_hi=math.radians(40),
    max_range=5.0,
    spacing=0.3,
    angle_step=math.radians(2.0),
)


def _oracle(plan: FloorPlan, grid: Grid, eyes: np.ndarray, model: ObservabilityModel) -> np.ndarray:
    """Slow reference: for each eye and each voxel centre, is the straight ray to it within the
    elevation band and does it meet its first surface (sampled every 2 cm) within range and
    no nearer than the voxel centre? True when some eye passes all tests."""
    centres = grid.centres().reshape(-1, 3)
    seen = np.zeros(len(centres), dtype=bool)
    s = np.arange(0.02, model.max_range, 0.02)
    for eye in eyes:
        d = centres - eye
        dist = np.linalg.norm(d, axis=1)
        el = np.arcsin(np.clip(d[:, 2] / np.maximum(dist, 1e-12), -1, 1))
        ok = (el >= model.elevation_lo + 0.05) & (el <= model.elevation_hi - 0.05) & (dist > 0.1)
        u = d[ok] / dist[ok, None]
        p = eye + s[None, :, None] * u[:, None, :]  # (C, S, 3)
        top = plan.height_at(p[..., :2])
        solid = (p[..., 2] < 0) | (p[..., 2] < top)
        first = np.where(solid.any(axis=1), s[np.argmax(solid, axis=1)], np.inf)
        seen[np.flatnonzero(ok)[(first < model.max_range - 0.1) & (first >= dist[ok] + 0.03)]] = True
    return seen.reshape(grid.shape)


def test_reachable_floor_is_the_start_s_room_only():
    plan = _room_plan()
    reach = reachable_floor(
        plan, np.array([0.0, 0.0]), np.array([4.0, 3.0]), np.array([[1.0, 1.0]]), 0.18, 0.05
    )
    xs = (np.arange(reach.shape[0]) + 0.5) * 0.05
    ys = (np.arange(reach.shape[1]) + 0.5) * 0.05
    at = lambda x, y: reach[np.searchsorted(xs, x), np.searchsorted(ys, y)]  # noqa: E731
    assert at(1.0, 1.0) and at(3.0, 1.0)
    assert not at(3.4, 2.4)  # inside the sealed closet
    assert not at(1.5, 1.5) and not at(1.5, 1.22)  # on the block, and within a radius of it
    assert not at(0.25, 1.5)  # within a radius of the wall


@pytest.mark.slow
def test_observable_voxels_agree_with_the_slow_oracle_and_leave_out_the_hidden():
    plan = _room_plan()
    grid = Grid.from_bounds(np.array([0.0, 0.0, 0.0]), np.array([4.0, 3.0, 1.4]), 0.1)
    starts = np.array([[1.0, 1.0]])
    fast = observable_voxels(plan, grid, starts, MODEL)
    # the closet's inside, the block's core and the walls' cores are never observed
    ijk = lambda x, y, z: tuple(int(v) for v in np.floor((np.array([x, y, z]) - grid.lo) / 0.1))  # noqa: E731
    assert not fast[ijk(3.4, 2.4, 0.35)]
    assert not fast[ijk(3.4, 2.4, 0.95)]
    assert not fast[ijk(1.5, 1.5, 0.05)]  # two voxels under the top: deeper than the one behind a hit
    # above 1 m only grazing rays could pass, and nothing returns up there: unobservable
    assert not fast[:, :, 11:].any()
    assert fast[ijk(2.0, 1.0, 0.45)] and fast[ijk(2.5, 2.5, 0.05)]
    coarse = Grid.from_bounds(np.array([0.0, 0.0, 0.0]), np.array([4.0, 3.0, 1.4]), 0.2)
    fast = observable_voxels(plan, coarse, starts, MODEL)
    eyes = np.array([[x, y, 0.4] for x in (0.8, 2.6) for y in (0.8, 2.3)])
    oracle = _oracle(plan, coarse, eyes, MODEL)
    # every voxel centre the oracle sees from a few eyes, the sampled model sees from all poses
    # (but a voxel or two that only grazing rays reach)
    assert (oracle & ~fast).sum() <= max(2, 0.01 * oracle.sum())
    assert oracle.sum() > 0.5 * fast.sum()


def test_a_ray_that_returns_nothing_observes_nothing():
    grid = Grid.from_bounds(np.array([0.0, 0.0, 0.0]), np.array([2.0, 2.0, 1.0]), 0.1)
    flat = ObservabilityModel(**{**MODEL.__dict__, "elevation_lo": 0.0, "elevation_hi": math.radians(20)})
    assert not observable_voxels(None, grid, np.array([[1.0, 1.0]]), flat).any()  # open floor, looking up
    down = ObservabilityModel(**{**MODEL.__dict__, "max_range": 0.3})
    assert not observable_voxels(None, grid, np.array([[1.0, 1.0]]), down).any()  # floor out of range


def test_beyond_the_hit_range_a_ray_observes_free_space_up_to_it_only():
    """Robots kept behind a 0.1 m fence at x = 1 (the camera, 0.4 m high, sees over it) look at
    a 1 m wall at x = 3: at least 2.18 m away. With a 1.5 m hit range its face is never a hit,
    the free space 1.25 m away still is observed (rays towards the wall are cut there)."""
    fence = rectangle(np.array([1.0, 1.5]), np.array([0.05, 20.0]))
    wall = rectangle(np.array([3.1, 1.5]), np.array([0.2, 20.0]))
    plan = _plan([fence, wall], [0.1, 1.0])
    grid = Grid.from_bounds(np.array([0.0, 0.0, 0.0]), np.array([4.0, 3.0, 1.4]), 0.1)
    starts = np.array([[0.5, 1.5]])
    full = observable_voxels(plan, grid, starts, MODEL)
    cut = observable_voxels(plan, grid, starts, ObservabilityModel(**{**MODEL.__dict__, "hit_range": 1.5}))
    near = observable_voxels(plan, grid, starts, ObservabilityModel(**{**MODEL.__dict__, "max_range": 1.5}))
    ijk = lambda x, y, z: tuple(int(v) for v in np.floor((np.array([x, y, z]) - grid.lo) / 0.1))  # noqa: E731
    face, free = ijk(2.95, 1.5, 0.45), ijk(2.05, 1.5, 0.45)
    assert full[face] and not cut[face]
    assert full[free] and cut[free] and not near[free]  # near: the wall's rays return nothing
    assert not (cut & ~full).any()  # a cut ray observes a part of what the whole one does
    assert not (near & ~cut).any()  # and at least what a sensor of that range does
    # eyes stand at x <= 0.82: nothing beyond x = 0.82 + 1.5 (and a voxel) is observed
    assert not cut[ijk(2.45, 0.0, 0.0)[0] :].any() and full[ijk(2.45, 0.0, 0.0)[0] :].any()
    # the hit range of a mission: the rig's (at the workspace's voxel), at most the max range
    far = {
        "mission": "far",
        "workspace": {"lo": [0.0, 0.0, 0.0], "hi": [4.0, 3.0, 1.4], "voxel": 0.1},
        "robots": [{"id": "r1", "start": {"x": 0.5, "y": 1.5}}],
        "rig": {"hit_range": "auto"},
    }
    mission = mission_from_dict(far)
    model = ObservabilityModel.for_mission(mission)
    assert model.hit_range == pytest.approx(math.sqrt(0.1 * mission.rig.fx * 0.09 / 0.1))
    for hit_range in (7.0, None):  # beyond the max range, or none: no cut
        mission = mission_from_dict({**far, "rig": {"hit_range": hit_range}})
        assert ObservabilityModel.for_mission(mission).hit_range is None


MISSION = {
    "mission": "room",
    "workspace": {"lo": [0.0, 0.0, 0.0], "hi": [4.0, 3.0, 1.4], "voxel": 0.1},
    "robots": [{"id": "r1", "start": {"x": 1.0, "y": 1.0}}],
    "rig": {"mode": "range", "max_range": 5.0},
    "stop": {"observable_fraction": 0.16},
}


def test_the_observable_threshold_is_the_hidden_entropy_plus_a_share_of_the_rest(tmp_path):
    plan_file = tmp_path / "room.yaml"
    plan_file.write_text(
        "walls:\n  - {points: [[0.1, 0.1], [3.9, 0.1], [3.9, 2.9], [0.1, 2.9]], closed: true,"
        " thickness: 0.2, height: 1.0}\n"
    )
    mission = mission_from_dict({**MISSION, "floor_plan": "room.yaml"}, base_dir=tmp_path)
    with pytest.raises(ConfigError, match="observable_fraction"):
        mission.threshold_bits()
    resolved, parts, observable = resolve_threshold(mission)
    grid = mission.workspace.grid()
    h0 = prior_entropy_bits(grid, mission.sensor.model()) / grid.size
    n_obs = int(observable.sum())
    assert parts.observable_voxels == n_obs and parts.unobservable_voxels == grid.size - n_obs
    assert resolved.threshold_bits() == pytest.approx(h0 * (grid.size - n_obs) + 0.16 * h0 * n_obs)
    assert resolved.stop.entropy_threshold_bits == pytest.approx(parts.threshold_bits)
    assert 0 < n_obs < grid.size
    # another share, forced on a mission whose threshold is in bits
    fixed = mission_from_dict(
        {**MISSION, "floor_plan": "room.yaml", "stop": {"entropy_threshold_bits": 5}}, base_dir=tmp_path
    )
    assert resolve_threshold(fixed)[1] is None
    half = threshold_parts(fixed, 0.5, observable)
    assert half.threshold_bits == pytest.approx(h0 * (grid.size - n_obs) + 0.5 * h0 * n_obs)
    with pytest.raises(ConfigError, match="floor_plan"):
        resolve_threshold(mission_from_dict(MISSION))


def test_surface_accuracy_and_completeness_count_within_the_tolerance():
    surface = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0], [3.0, 0.0, 0.0]])
    mapped = np.array([[0.0, 0.1, 0.0], [1.0, 0.0, 0.14], [5.0, 5.0, 5.0]])
    out = sq.surface_accuracy_completeness(mapped, surface, 0.15)
    assert out["accuracy"] == pytest.approx(2 / 3)
    assert out["completeness"] == pytest.approx(2 / 4)
    # the floor plane counts for accuracy only
    low = np.array([[7.0, 7.0, 0.1]])
    assert sq.surface_accuracy_completeness(low, surface, 0.15, floor_z=0.0)["accuracy"] == 1.0
    assert sq.surface_accuracy_completeness(low, surface, 0.15)["accuracy"] == 0.0
    empty = sq.surface_accuracy_completeness(np.zeros((0, 3)), surface, 0.15)
    assert empty["accuracy"] is None and empty["completeness"] == 0.0


def test_plan_surface_points_lie_on_exposed_faces_only():
    # two boxes side by side share a face: its points are inside the solid and left out
    plan = _plan(
        [
            rectangle(np.array([1.0, 1.0]), np.array([1.0, 1.0])),
            rectangle(np.array([2.0, 1.0]), np.array([1.0, 1.0])),
        ],
        [0.5, 0.5],
    )
    pts, air = sq.plan_surface_points(plan, np.array([0, 0, 0.0]), np.array([3, 2, 1.0]), 0.05)
    on_x = np.isclose(pts[:, 0], 0.5) | np.isclose(pts[:, 0], 2.5)
    on_y = np.isclose(pts[:, 1], 0.5) | np.isclose(pts[:, 1], 1.5)
    on_top = np.isclose(pts[:, 2], 0.5)
    assert np.all(on_x | on_y | on_top)
    assert not np.any(np.isclose(pts[:, 0], 1.5) & ~on_top & ~on_y)  # the shared face
    assert np.all(plan.height_at(air[:, :2]) < air[:, 2])  # the air points are outside
    # a side is 1 m x 0.5 m: 20 x 10 points; 6 exposed sides of 1 m; a top of 2 m x 1 m
    assert np.count_nonzero(~on_top) == 6 * 20 * 10
    assert np.count_nonzero(on_top) == 40 * 20
