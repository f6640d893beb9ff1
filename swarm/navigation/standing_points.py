"""Where a robot stands to look at a slab voxel: the view geometry (distance band, angle to
the gaze) and the reachable cell that fits it with a straight line of sight.

The entropy strategy (:mod:`swarm.navigation.exploration`) checks each eq. 35 candidate's
standing point here; candidates without one are skipped.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from swarm.navigation.search_context import SearchContext


@dataclass(frozen=True)
class ViewGeometry:
    """Where a robot may stand to look at an entropy target voxel: between ``near`` and
    ``far`` metres from it, with it within ``half_angle`` (radians) of the gaze (half the
    camera's horizontal field of view)."""

    near: float = 0.3
    far: float = 1.0
    half_angle: float = math.radians(30.0)


def standing_cell(
    ctx: SearchContext, i: int, j: int, g: np.ndarray, view: ViewGeometry
) -> tuple[int, int] | None:
    """Where to stand to view voxel column (i, j) looking along the unit gradient ``g``.

    Among reachable cells at distance view.near .. view.far from the voxel, within
    view.half_angle of the gaze g as seen from the cell (so the voxel and the higher
    entropy beyond it are in the field of view) and with a straight line of sight to it
    (no opaque slab voxel in between), the one nearest the point (near + far) / 2 behind
    the voxel along -g. None if no cell fits.
    """
    lo, hi = view.near, view.far
    e = ctx.voxel
    n = int(math.ceil(hi / e))
    nx, ny = ctx.reach.shape
    i0, i1, j0, j1 = max(i - n, 0), min(i + n + 1, nx), max(j - n, 0), min(j + n + 1, ny)
    ii, jj = np.nonzero(ctx.reach[i0:i1, j0:j1])
    ii += i0
    jj += j0
    target = ctx.centre(i, j)
    pts = np.stack([ctx.cx[ii], ctx.cy[jj]], axis=-1)
    ahead = target - pts
    d = np.linalg.norm(ahead, axis=1)
    ok = (d >= lo - 1e-9) & (d <= hi + 1e-9) & (ahead @ g >= math.cos(view.half_angle) * d - 1e-9)
    ii, jj, pts = ii[ok], jj[ok], pts[ok]
    if ii.size == 0:
        return None
    # line of sight: samples every quarter voxel, ignoring the target's own column
    t = np.arange(1, 4 * n + 1) / (4 * n + 1)
    samples = pts[:, None, :] + t[None, :, None] * (target - pts)[:, None, :]
    si = np.clip(np.floor((samples[..., 0] - ctx.cmap.grid.lo[0]) / e).astype(np.int64), 0, nx - 1)
    sj = np.clip(np.floor((samples[..., 1] - ctx.cmap.grid.lo[1]) / e).astype(np.int64), 0, ny - 1)
    blocked = ctx.opaque[si, sj] & ~((si == i) & (sj == j))
    clear = ~blocked.any(axis=1)
    if not clear.any():
        return None
    ii, jj, pts = ii[clear], jj[clear], pts[clear]
    ideal = target - 0.5 * (lo + hi) * g
    k = int(np.argmin(np.linalg.norm(pts - ideal, axis=1)))
    return int(ii[k]), int(jj[k])
