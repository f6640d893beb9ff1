"""Exact traversal against a brute-force reference in rational arithmetic."""

import numpy as np
import pytest

from swarm.map.grid import Grid
from swarm.map.traversal import traverse
from tests.support.traversal_oracle import reference

GRID = Grid((0.0, 0.0, 0.0), 0.25, (12, 12, 12))


def ours(grid, start, end, hit=True):
    rv = traverse(grid, np.asarray(start)[None], np.asarray(end)[None], hit=np.array([hit]))
    voxels = [tuple(v) for v in rv.ijk.tolist()]
    assert len(voxels) == len(set(voxels)), f"a voxel counted twice: {voxels}"
    behind = [tuple(v) for v in rv.ijk[rv.behind].tolist()]
    return set(voxels), behind


def check(start, end, hit=True):
    expected, _, behind = reference(GRID, start, end, hit)
    got, got_behind = ours(GRID, start, end, hit)
    assert got == expected, f"{start} -> {end}: missing {expected - got}, extra {got - expected}"
    assert got_behind == ([behind] if behind is not None else [])


def test_random_rays_match_reference():
    rng = np.random.default_rng(1)
    for _ in range(300):
        start = rng.uniform(0.3, 2.7, 3)
        end = rng.uniform(0.3, 2.7, 3)
        check(start, end)


@pytest.mark.parametrize(
    "start,end",
    [
        # along each axis, inside voxels and exactly on planes, both directions
        ((0.1, 0.6, 0.6), (2.6, 0.6, 0.6)),
        ((2.6, 0.6, 0.6), (0.1, 0.6, 0.6)),
        ((0.6, 0.1, 0.5), (0.6, 2.6, 0.5)),
        ((0.5, 0.5, 2.6), (0.5, 0.5, 0.1)),
        ((0.5, 0.75, 0.1), (0.5, 0.75, 2.0)),
        # ending and starting exactly on planes
        ((0.1, 0.6, 0.6), (1.0, 0.6, 0.6)),
        ((2.0, 0.6, 0.6), (1.0, 0.6, 0.6)),
        ((1.0, 1.0, 1.0), (2.0, 1.25, 1.5)),
        # through edges and corners: 2-D and 3-D diagonals, mixed signs
        ((0.125, 0.125, 0.6), (1.875, 1.875, 0.6)),
        ((1.875, 0.125, 0.6), (0.125, 1.875, 0.6)),
        ((0.125, 0.125, 0.125), (1.875, 1.875, 1.875)),
        ((1.875, 0.125, 1.875), (0.125, 1.875, 0.125)),
        ((0.125, 0.375, 0.6), (1.625, 1.125, 0.6)),  # slope 1/2 through every other edge
        ((0.0, 0.0, 0.0), (2.0, 1.0, 0.5)),
        ((2.0, 2.0, 2.0), (0.0, 1.0, 1.5)),
        ((0.25, 0.5, 0.75), (1.25, 0.5, 0.75)),  # along an edge line
    ],
)
def test_axis_edge_and_corner_rays_match_reference(start, end):
    check(np.array(start), np.array(end))


def test_grid_aligned_diagonal_rays_match_reference():
    """Rays between voxel corners in every octant hit edges and corners at every step."""
    rng = np.random.default_rng(7)
    for _ in range(200):
        start = rng.integers(1, 11, 3) * 0.25
        end = rng.integers(1, 11, 3) * 0.25
        if np.all(start == end):
            continue
        check(start, end)


def test_rays_without_return_have_no_behind_voxel():
    check(np.array([0.3, 0.3, 0.3]), np.array([2.2, 1.7, 0.9]), hit=False)


def test_each_voxel_once_and_contiguous_for_many_rays():
    rng = np.random.default_rng(3)
    start = np.full(3, 1.5)
    end = rng.uniform(0.05, 2.95, (2000, 3))
    rv = traverse(GRID, start, end)
    counts = np.bincount(rv.ray, minlength=len(end))
    pairs = np.unique(np.column_stack([rv.ray, GRID.flat(rv.ijk)]), axis=0)
    assert len(pairs) == len(rv), "a voxel appears twice for one ray"
    # voxels of a ray (without the one behind) number 1 + the planes crossed minus ties
    crossings = np.abs(GRID.index_of(end) - GRID.index_of(start)).sum(axis=1)
    assert np.all(counts - 1 <= crossings + 1)
    assert np.all(counts >= crossings.clip(min=0) // 3 + 2)
