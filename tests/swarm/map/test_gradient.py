"""Exploration geometry: gradient (eq. 32), axes and projection (eq. 27-29, 33),
neighbourhood (eq. 30) and target selection (eq. 34-35)."""

import itertools

import numpy as np
import pytest

from swarm.map.gradient import (
    candidate_voxels,
    entropy_gradient,
    project_on_plane,
    projected_gradient,
    robot_axes,
    select_target,
    target_scores,
)
from swarm.map.grid import Grid


def test_gradient_of_a_linear_field_is_its_slope():
    e = 0.1
    i, j, k = np.meshgrid(np.arange(6), np.arange(5), np.arange(4), indexing="ij")
    slope = np.array([0.7, -1.3, 2.1])  # bits per metre
    H = (slope[0] * i + slope[1] * j + slope[2] * k) * e + 3.0
    G = entropy_gradient(H, e)
    assert G.shape == (6, 5, 4, 3)
    for a in range(3):
        interior = [slice(None)] * 3
        interior[a] = slice(1, None)
        assert np.allclose(G[tuple(interior) + (a,)], slope[a], atol=1e-12)
        boundary = [slice(None)] * 3
        boundary[a] = 0
        assert np.all(G[tuple(boundary) + (a,)] == 0.0)  # no lower neighbour: 0


def test_gradient_is_a_backward_difference():
    rng = np.random.default_rng(0)
    H = rng.uniform(0, 7, (4, 3, 5)).astype(np.float32)
    G = entropy_gradient(H, 0.25)
    assert G.dtype == np.float32
    assert G[2, 1, 3, 0] == pytest.approx((H[2, 1, 3] - H[1, 1, 3]) / 0.25)
    assert G[2, 1, 3, 1] == pytest.approx((H[2, 1, 3] - H[2, 0, 3]) / 0.25)
    assert G[2, 1, 3, 2] == pytest.approx((H[2, 1, 3] - H[2, 1, 2]) / 0.25)
    with pytest.raises(ValueError):
        entropy_gradient(H[0], 0.25)


def test_robot_axes():
    p, q, n = robot_axes(0.0)
    assert np.allclose(p, [1, 0, 0]) and np.allclose(q, [0, 1, 0]) and np.allclose(n, [0, 0, 1])
    p, q, n = robot_axes(np.pi / 2)  # yaw left: gaze along +y, lateral along -x
    assert np.allclose(p, [0, 1, 0]) and np.allclose(q, [-1, 0, 0]) and np.allclose(n, [0, 0, 1])
    p, _, _ = robot_axes(0.0, np.pi / 6)  # positive pitch: gaze below the horizon
    assert np.allclose(p, [np.cos(np.pi / 6), 0, -0.5])
    rng = np.random.default_rng(1)
    ypr = rng.uniform(-np.pi, np.pi, (50, 3))
    p, q, n = robot_axes(ypr[:, 0], ypr[:, 1], ypr[:, 2])
    R = np.stack([p, q, n], axis=-1)
    assert np.allclose(np.einsum("nij,nik->njk", R, R), np.eye(3), atol=1e-12)
    assert np.allclose(np.cross(p, q), n, atol=1e-12)
    # ZYX: R = Rz(yaw) Ry(pitch) Rx(roll), built here from matrices
    y, pt, r = ypr[0]
    Rz = np.array([[np.cos(y), -np.sin(y), 0], [np.sin(y), np.cos(y), 0], [0, 0, 1]])
    Ry = np.array([[np.cos(pt), 0, np.sin(pt)], [0, 1, 0], [-np.sin(pt), 0, np.cos(pt)]])
    Rx = np.array([[1, 0, 0], [0, np.cos(r), -np.sin(r)], [0, np.sin(r), np.cos(r)]])
    assert np.allclose(R[0], Rz @ Ry @ Rx, atol=1e-12)


def test_projection_removes_the_normal_component():
    rng = np.random.default_rng(2)
    v = rng.normal(size=(100, 3))
    p, q, n = robot_axes(*rng.uniform(-1, 1, 3))
    out = project_on_plane(v, 3.0 * n)  # any length of normal
    assert np.allclose(out @ n, 0.0, atol=1e-12)
    # eq. 29: (u.p) p + (u.q) q
    assert np.allclose(out, (v @ p)[:, None] * p + (v @ q)[:, None] * q, atol=1e-12)
    # the removed part is along n
    assert np.allclose(np.cross(v - out, n), 0.0, atol=1e-12)
    # idempotent, and in-plane vectors are untouched
    assert np.allclose(project_on_plane(out, n), out, atol=1e-12)
    with pytest.raises(ValueError):
        project_on_plane(v, [0.0, 0.0, 0.0])


def test_projected_gradient_on_a_horizontal_plane_drops_z():
    rng = np.random.default_rng(3)
    H = rng.uniform(0, 7, (5, 5, 3))
    G = projected_gradient(H, 0.1, [0, 0, 1])
    assert np.allclose(G[..., :2], entropy_gradient(H, 0.1)[..., :2])
    assert np.allclose(G[..., 2], 0.0)


def _brute_candidates(grid: Grid, position, radius, z_slab):
    centres = grid.centres().reshape(-1, 3)
    k = grid.unflat(np.arange(grid.size))[:, 2]
    k0 = int(np.floor((position[2] - grid.origin[2]) / grid.voxel))
    in_slab = np.abs(k - k0) <= z_slab
    close = np.linalg.norm(centres - np.asarray(position), axis=1) <= radius
    return np.flatnonzero(in_slab & close)


def test_candidates_match_brute_force():
    grid = Grid((-1.0, 0.5, 0.0), 0.1, (23, 17, 9))
    rng = np.random.default_rng(4)
    for _ in range(300):
        position = grid.lo + rng.uniform(-0.3, 1.3, 3) * (grid.hi - grid.lo)
        radius = rng.uniform(0, 1.2)
        z_slab = int(rng.integers(0, 3))
        got = candidate_voxels(grid.shape, grid.voxel, grid.origin, position, radius, z_slab)
        want = _brute_candidates(grid, position, radius, z_slab)
        assert got.dtype == np.int64
        assert np.array_equal(got, want), (position, radius, z_slab)
    # the sensor's own layer only, by default
    pos = np.array([0.13, 1.27, 0.44])
    got = candidate_voxels(grid.shape, grid.voxel, grid.origin, pos, 0.35)
    assert got.size > 0 and np.all(grid.unflat(got)[:, 2] == 4)
    assert candidate_voxels(grid.shape, grid.voxel, grid.origin, pos, -1.0).size == 0


def test_target_selection_is_the_argmax_of_eq_35():
    # a 4 x 3 x 1 entropy field: explored (low H) on the left, unexplored on the right
    H = np.array(
        [
            [[0.5], [0.4], [0.6]],
            [[1.0], [0.5], [0.7]],
            [[6.0], [2.0], [0.9]],
            [[7.0], [7.0], [1.5]],
        ]
    )
    e = 0.5
    ec = np.array(
        [
            [[0.0], [0.0], [0.1]],
            [[0.0], [0.9], [0.0]],
            [[0.0], [0.5], [0.0]],
            [[1.0], [0.0], [0.2]],
        ]
    )
    _, _, n = robot_axes(0.3)  # horizontal plane
    G = projected_gradient(H, e, n)
    cands = np.arange(H.size)
    # by hand: the backward differences and scores of every voxel
    best, best_score, best_vec = None, -1.0, None
    for i, j in itertools.product(range(4), range(3)):
        gx = (H[i, j, 0] - H[i - 1, j, 0]) / e if i > 0 else 0.0
        gy = (H[i, j, 0] - H[i, j - 1, 0]) / e if j > 0 else 0.0
        score = np.hypot(gx, gy) * (1 - ec[i, j, 0])
        assert target_scores(np.linalg.norm(G, axis=-1), ec, [i * 3 + j])[0] == pytest.approx(score)
        if score > best_score:
            best, best_score, best_vec = i * 3 + j, score, np.array([gx, gy, 0.0])
    # (2, 0): gx = (6 - 1) / 0.5 = 10, no lower y neighbour; E[C] = 0 -> score 10
    assert best == 6 and best_score == pytest.approx(10.0)
    t = select_target(G, ec, cands)
    assert t.index == best and t.score == pytest.approx(best_score)
    # gaze towards higher entropy: +x here
    assert np.allclose(t.gaze, best_vec / np.linalg.norm(best_vec))
    # candidates restrict the choice; (3, 1) has the larger gradient but is excluded here
    t2 = select_target(G, ec, [1, 4, 7, 8])
    scores = target_scores(np.linalg.norm(G, axis=-1), ec, [1, 4, 7, 8])
    assert t2.index == [1, 4, 7, 8][int(np.argmax(scores))]
    # an almost certainly occupied voxel is not chosen however steep its gradient
    ec2 = ec.copy()
    ec2[2, 0, 0] = 1.0
    assert select_target(G, ec2, cands).index != 6


def test_no_conclusive_target():
    H = np.full((3, 3, 1), 4.0)
    G = projected_gradient(H, 0.1, [0, 0, 1])
    ec = np.zeros(H.shape)
    assert select_target(G, ec, np.arange(9)) is None  # flat entropy: wander
    assert select_target(G, ec, []) is None
    H[1, 1, 0] = 5.0
    G = projected_gradient(H, 0.1, [0, 0, 1])
    assert select_target(G, ec, np.arange(9)).index == 4
    assert select_target(G, ec, np.arange(9), min_score=100.0) is None
    ec[1, 1, 0] = np.nan
    t = select_target(G, ec, np.arange(9))  # NaN never wins
    assert t is not None and t.index != 4
