"""Exact voxel traversal in rational arithmetic, by brute force: the reference the traversal and
fusion tests compare with."""

from __future__ import annotations

from fractions import Fraction
from math import floor

from swarm.map.grid import Grid


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
