"""3-D frontier targets: unknown voxels at any height that the camera can still be pointed at.

Eq. 30 looks for targets in the sensor's slab only, and the 2-D frontier of Yamauchi's
method in the floor's columns only. Once the slab and the floor are known, a robot
using either stops, though unknown voxels may be left above the slab (the upper part of a
room, the top of furniture seen only edge-on) or below it (floor close to walls and boxes,
which a level camera misses near the robot). This module finds those voxels and where to
stand to see them:

- *3-D frontier*: unknown voxels face-adjacent to a known free voxel (E[C] below the
  opaque level), so a ray can reach them through known free space (Yamauchi's frontier,
  "known free next to unknown", in three dimensions).
- *Standing point*: a reachable cell whose horizontal distance d to the voxel's column lets
  the camera, at ``sensor_height``, see the voxel within its elevation band (the vertical
  field of view, widened upwards by a tilt head) and within range, with a straight line of
  sight in the slab (no opaque slab voxel in between). The nearest such cell by path cost
  is chosen; the gaze points at the column.

*Last looks* (``uncertain_voxels``): where a robot would stop, the voxels still holding at
least ``min_bits`` of entropy, known or not, on a face of known free space; looked at the
same way, each column once, so a robot stops only when none of them is left in view of a
reachable cell.

Targets whose columns were already looked at (``tried``) are skipped, so a voxel that stays
unknown when looked at (hidden in ways the slab test cannot tell) is given up after one try.
With ``max_looks`` > 1 and the standing points of those looks (``stands``), a column is
looked at again, up to ``max_looks`` times, each time from a reachable cell away from the
ones it was already looked at from (another side, another distance): one look often leaves
part of a column unknown (its slab voxel seen, the voxels near the band's edge not; the
floor at the camera's near limit), and Yamauchi's robot goes on while a frontier it can
still observe remains. The bound keeps the search finite.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from swarm.map.entropy import expected_coverage
from swarm.navigation.search_context import OPAQUE_COVERAGE, SearchContext
from swarm.navigation.targets import ExplorationTarget
from swarm.navigation.view_kernels import stand_for

#: Frontier columns examined per call, nearest first (straight-line distance to the robot).
MAX_COLUMNS = 400
#: A column is looked at again only from cells farther than this (m) from where it was looked at.
RESTAND_RADIUS = 0.3
#: voxels per slab of the free-voxel pass (1 MB of float32 per temporary)
FREE_CHUNK = 1 << 18


@dataclass(frozen=True)
class CameraReach:
    """The elevation band (radians, positive up) and range (m) the camera can look along."""

    elevation_lo: float
    elevation_hi: float
    max_range: float
    min_range: float = 0.3

    @classmethod
    def of_rig(cls, rig, max_range: float, looks_up: bool = True) -> CameraReach:
        """The band of a ``swarm.config.RigConfig``: mounting pitch +- half the vertical field
        of view, raised by the tilt head's range when the agent looks up (``looks_up``)."""
        half_v = math.atan(0.5 * rig.height / rig.fx)
        centre = -math.radians(rig.pitch_deg)
        up = math.radians(rig.tilt_range_deg) if looks_up else 0.0
        reach = max_range if rig.max_range is None else min(max_range, rig.max_range)
        return cls(centre - half_v, centre + half_v + up, reach)


def frontier_voxels_3d(ctx: SearchContext) -> np.ndarray:
    """Unknown voxels face-adjacent to a known free voxel, bool of shape ``grid.shape``."""
    known, near_free = _known_and_near_free(ctx)
    return ~known & near_free


def uncertain_voxels(ctx: SearchContext, entropy: np.ndarray, min_bits: float) -> np.ndarray:
    """Voxels with at least ``min_bits`` of entropy (``entropy``: per voxel, flat, bits), known
    or unknown, face-adjacent to a known free voxel: bool of shape ``grid.shape``."""
    _known, near_free = _known_and_near_free(ctx)
    return near_free & (np.asarray(entropy).reshape(near_free.shape) >= min_bits)


def _known_and_near_free(ctx: SearchContext) -> tuple[np.ndarray, np.ndarray]:
    """(known voxels, voxels with a face on a known free voxel), bool of shape ``grid.shape``."""
    cmap = ctx.cmap
    shape = cmap.grid.shape
    known = cmap.known_mask().reshape(shape)
    # E[C] a slab of x at a time: elementwise, so the same values without the whole map's
    # float temporaries (about 140 MB on the 8.4 M-voxel campus floor, at every view choice)
    free = np.zeros(shape, dtype=bool)
    rows = max(1, FREE_CHUNK // (shape[1] * shape[2]))
    flat_free, flat_known = free.reshape(-1), known.reshape(-1)
    for i in range(0, shape[0], rows):
        part = slice(i * shape[1] * shape[2], min(i + rows, shape[0]) * shape[1] * shape[2])
        cov = expected_coverage(cmap.mean(part), cmap.sigma(part))
        flat_free[part] = flat_known[part] & (cov < OPAQUE_COVERAGE)
    near_free = np.zeros(shape, dtype=bool)
    near_free[1:] |= free[:-1]
    near_free[:-1] |= free[1:]
    near_free[:, 1:] |= free[:, :-1]
    near_free[:, :-1] |= free[:, 1:]
    near_free[:, :, 1:] |= free[:, :, :-1]
    near_free[:, :, :-1] |= free[:, :, 1:]
    return known, near_free


def view_target(
    ctx: SearchContext,
    camera: CameraReach,
    tried: Sequence[np.ndarray] = (),
    tried_radius: float = 0.25,
    kind: str = "view",
    *,
    stands: Sequence[np.ndarray] | None = None,
    max_looks: int = 1,
    voxels: np.ndarray | None = None,
) -> ExplorationTarget | None:
    """Where to stand to see the nearest 3-D frontier voxel (see the module doc); None if no
    frontier voxel has a reachable standing point. ``voxels`` (bool, ``grid.shape``): look at
    these instead of the 3-D frontier (``uncertain_voxels`` for the last looks). ``tried``:
    x-y of columns already looked at; a column with ``max_looks`` of them within
    ``tried_radius`` is skipped. ``stands``: where the robot stood for each of ``tried``
    (same length); a column is then looked at again only from cells farther than
    RESTAND_RADIUS from the stands of its earlier looks. ``utility``: the column's frontier
    voxels (count).

    Raises ValueError when ``max_looks`` < 1, ``stands`` and ``tried`` differ in length, or
    ``voxels`` is not of the grid's shape."""
    if max_looks < 1:
        raise ValueError(f"max_looks must be >= 1, got {max_looks}")
    if stands is not None and len(stands) != len(tried):
        raise ValueError(f"stands has {len(stands)} points, tried {len(tried)}: one stand per look")
    if voxels is not None and voxels.shape != ctx.cmap.grid.shape:
        raise ValueError(f"voxels has shape {voxels.shape}, expected the grid's {ctx.cmap.grid.shape}")
    front = frontier_voxels_3d(ctx) if voxels is None else voxels
    counts = front.sum(axis=2)
    cols = np.argwhere(counts > 0)
    if cols.size == 0 or not ctx.reach.any():
        return None
    xy = np.stack([ctx.cx[cols[:, 0]], ctx.cy[cols[:, 1]]], axis=1)
    looked = np.zeros((len(cols), len(tried)), dtype=bool)  # column n was looked at by look m
    for m, p in enumerate(tried):
        looked[:, m] = np.hypot(*(xy - np.asarray(p)[:2]).T) <= tried_radius
    stood = None if stands is None else np.asarray(stands, dtype=np.float64).reshape(-1, 2)
    looks = looked.sum(axis=1)
    # never-looked columns first (the frontier proper); a column looked at n times only when
    # no column looked at fewer times has a stand left
    for n in range(max_looks):
        sel = looks == n
        if sel.any():
            found = _nearest_view(ctx, camera, front, cols[sel], xy[sel], looked[sel], stood, kind)
            if found is not None:
                return found
    return None


def _nearest_view(
    ctx: SearchContext,
    camera: CameraReach,
    front: np.ndarray,
    cols: np.ndarray,
    xy: np.ndarray,
    looked: np.ndarray,
    stood: np.ndarray | None,
    kind: str,
) -> ExplorationTarget | None:
    """The view of least path cost among frontier columns ``cols`` (M, 2) at ``xy`` (M, 2);
    ``looked`` (M, L) marks the earlier looks at each, whose stands ``stood`` (L, 2) it avoids."""
    grid = ctx.cmap.grid
    e = grid.voxel
    counts = front.sum(axis=2)
    order = np.argsort(np.hypot(*(xy - ctx.position[:2]).T), kind="stable")[:MAX_COLUMNS]
    z_centres = grid.lo[2] + (np.arange(grid.shape[2]) + 0.5) * e
    h = float(ctx.position[2])
    best: tuple[float, int, tuple[int, int]] | None = None
    dist = np.hypot(*(xy - ctx.position[:2]).T)
    usable = ctx.reach & ctx.allowed
    nowhere = np.zeros_like(usable)
    for n in order:
        # a path to a stand is at least as long as the straight line: D - d_hi
        if best is not None and dist[n] - camera.max_range > best[0]:
            break  # sorted by D: no farther column can do better
        i, j = (int(v) for v in cols[n])
        dz = z_centres[front[i, j]] - h
        # horizontal distances from which some frontier voxel of the column is in the band
        d_lo, d_hi = _distance_window(dz, camera, e)
        if d_lo > d_hi or (best is not None and dist[n] - d_hi > best[0]):
            continue
        avoid = (
            nowhere if stood is None or not looked[n].any() else _near(ctx, stood[looked[n]], RESTAND_RADIUS)
        )
        stand = _stand_for(ctx, usable, i, j, d_lo, d_hi, avoid)
        if stand is None:
            continue
        cost = 0.0 if stand == ctx.start else float(ctx.cost[stand])
        if best is None or cost < best[0]:
            best = (cost, n, stand)
    if best is None:
        return None
    _cost, n, stand = best
    at = ctx.centre(*stand)
    look = xy[n] - at
    yaw = math.atan2(look[1], look[0]) if np.linalg.norm(look) > 1e-9 else ctx.yaw
    i, j = (int(v) for v in cols[n])
    k = int(np.flatnonzero(front[i, j])[0])
    return ExplorationTarget(
        xy=at,
        gaze_yaw=yaw,
        utility=float(counts[i, j]),
        voxel=(i * grid.shape[1] + j) * grid.shape[2] + k,
        kind=kind,
    )


def _distance_window(dz: np.ndarray, camera: CameraReach, e: float) -> tuple[float, float]:
    """The widest [d_lo, d_hi] of horizontal distances that see one of the heights ``dz``
    (voxel centre minus camera, m) within the band and range (one voxel edge of slack)."""
    lo_all, hi_all = math.inf, -math.inf
    tan_hi = math.tan(min(camera.elevation_hi, math.radians(89)))
    tan_lo = math.tan(max(camera.elevation_lo, -math.radians(89)))
    for z in dz:
        d_lo = camera.min_range
        if z > 0:
            d_lo = max(d_lo, z / tan_hi if tan_hi > 0 else math.inf)
        elif z < 0:
            d_lo = max(d_lo, z / tan_lo if tan_lo < 0 else math.inf)
        d_hi = math.sqrt(max(camera.max_range**2 - z * z, 0.0)) - e
        if d_lo <= d_hi:
            lo_all, hi_all = min(lo_all, d_lo), max(hi_all, d_hi)
    return lo_all, hi_all


def _near(ctx: SearchContext, points: np.ndarray, radius: float) -> np.ndarray:
    """Cells (nx, ny) whose centre is within ``radius`` (m) of one of ``points`` (M, 2)."""
    near = np.zeros(ctx.reach.shape, dtype=bool)
    for x, y in points:
        near |= (ctx.cx[:, None] - x) ** 2 + (ctx.cy[None, :] - y) ** 2 <= radius**2
    return near


def _stand_for(
    ctx: SearchContext, usable: np.ndarray, i: int, j: int, d_lo: float, d_hi: float, avoid: np.ndarray
) -> tuple[int, int] | None:
    """The reachable allowed cell (``usable``, not in ``avoid``) of least path cost at horizontal
    distance [d_lo, d_hi] from column (i, j) with a clear slab line of sight to it; None if
    none (``view_kernels.stand_for``)."""
    half_width = int(math.ceil(d_hi / ctx.voxel)) + 1
    a, b = stand_for(
        usable,
        avoid,
        ctx.cost,
        ctx.start[0],
        ctx.start[1],
        ctx.cx,
        ctx.cy,
        ctx.opaque,
        i,
        j,
        d_lo,
        d_hi,
        half_width,
    )
    return None if a < 0 else (int(a), int(b))
