"""Exact traversal against a brute-force reference in rational arithmetic."""

from fractions import Fraction
from math import floor

import numpy as np
import pytest

from swarm.map.grid import Grid
from swarm.map.traversal import traverse

GRID = Grid((0.0, 0.0, 0.0), 0.25, (12, 12, 12))


def reference(grid: Grid, start, end, hit=True):
    """Voxels of the design's traversal semantics, by exact enumeration of every plane crossing.

    The segment occupies floor(p(t)) (half-open voxels). Collect every t at which any
    coordinate crosses an integer plane on the extended line, sort them, and take the
    voxel in the middle of each gap: the voxels over [0, 1) plus the end voxel form the
    traversal; the first different voxel after the end is the one behind.
    """
    e = Fraction(grid.voxel)
    lo = [Fraction(v) for v in grid.origin]
    s = [(Fraction(float(start[a])) - lo[a]) / e for a in range(3)]
    f = [(Fraction(float(end[a])) - lo[a]) / e for a in range(3)]
    d = [f[a] - s[a] for a in range(3)]
    # Extend the line two voxels past the end along its dominant axis: far enough to leave
    # the hit voxel, whose exit comes within one voxel on that axis.
    t_max = 1 + Fraction(2) / max(abs(c) for c in d)
    times = {t_max}
    for a in range(3):
        if d[a] == 0:
            continue
        lo_p = floor(min(s[a], s[a] + t_max * d[a])) - 1
        hi_p = floor(max(s[a], s[a] + t_max * d[a])) + 2
        for plane in range(lo_p, hi_p):
            t = (plane - s[a]) / d[a]
            if 0 <= t <= t_max:
                times.add(t)
    times = sorted(times)

    def voxel(t):
        return tuple(floor(s[a] + t * d[a]) for a in range(3))

    hit_voxel = voxel(Fraction(1))
    visited = {voxel(Fraction(0)), hit_voxel}
    behind = None
    for t, t_next in zip(times, times[1:], strict=False):
        v = voxel((t + t_next) / 2)
        if t < 1:
            visited.add(v)
        elif behind is None and v != hit_voxel:
            behind = v
    if hit and behind is not None:
        visited.add(behind)
    return visited, hit_voxel, (behind if hit else None)


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
