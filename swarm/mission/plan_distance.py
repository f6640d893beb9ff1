"""Exact distance from points to the surface of a floor plan's solid.

A floor plan's obstacles are convex quads extruded from the floor z = 0 up to their heights,
so the solid is a height field: the point (x, y, z), 0 <= z, is inside when z < H(x, y), the
top of the tallest obstacle over (x, y). Its surface is the obstacles' exposed sides and
tops; the floor z = 0 (the ground, solid below it) is surface too.

- A point outside the solid is as far from the surface as from the solid: the least, over
  obstacles, of sqrt(d_xy^2 + max(0, z - h)^2) (d_xy: 2-D distance to the quad, 0 over it),
  and z from the floor.
- A point inside leaves the solid through the nearest free point. Free points at height
  z' >= z are those over {H <= z'}, so the distance is the least, over the levels v = z and
  every obstacle height h in (z, H(x, y)], of sqrt(dist_xy(p, {H <= v})^2 + (v - z)^2);
  for v = H(x, y) that is straight up, (H - z). dist_xy(p, {H <= v}) is the distance to the
  exposed outline of the obstacles taller than v: their edges less the parts inside
  another such obstacle (touching cells of a ROS map share a side that is not exposed).

Distances are exact up to rounding (``EPS``), and capped at ``cap``: farther is reported as
``cap``. Surface accuracy (:mod:`swarm.mission.surface_quality`) needs only whether a mapped
voxel centre lies within 1.5 voxel edges, so a cap of a metre is plenty. Sampling the surface
with points instead overstates every distance by up to the half-diagonal of the sampling
step, and on a grid-aligned plan (a ROS map's cells on the voxel grid's half edges) that
turned every voxel centre exactly 1.5 edges from a wall from accurate to inaccurate.
"""

from __future__ import annotations

import numpy as np

from swarm.formats.floor_plan import FloorPlan

#: An edge is exposed where the air just outside it, EPS (m) off along its outward normal,
#: is not inside another obstacle: touching cells of a ROS map share a side that is not.
EPS = 1e-6
#: The 2-D tiles the points are taken in (m): each tile looks only at obstacles near it.
TILE = 1.0


def surface_distance(plan: FloorPlan, points: np.ndarray, cap: float = 1.0) -> np.ndarray:
    """Distance (m, (P,)) from each point (P, 3) to the plan's surface (sides, tops and the
    floor z = 0), capped at ``cap`` (m, > 0). Points below the floor are |z| from it.
    Raises ValueError for a cap that is not > 0."""
    if not cap > 0:
        raise ValueError(f"cap must be > 0, got {cap}")
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    out = np.minimum(np.abs(pts[:, 2]), cap)
    if not len(pts) or not plan.count:
        return out
    qlo, qhi = plan.quad_bounds()
    tile = np.floor(pts[:, :2] / TILE).astype(np.int64)
    order = np.lexsort((tile[:, 1], tile[:, 0]))
    keys = tile[order]
    starts = np.flatnonzero(np.r_[True, np.any(keys[1:] != keys[:-1], axis=1)])
    for s, e in zip(starts, np.r_[starts[1:], len(order)], strict=True):
        idx = order[s:e]
        t_lo = keys[s] * TILE - cap
        t_hi = (keys[s] + 1) * TILE + cap
        near = np.flatnonzero(np.all((qhi >= t_lo) & (qlo <= t_hi), axis=1))
        if near.size:
            out[idx] = np.minimum(out[idx], _tile_distance(plan, near, pts[idx], cap))
    return out


def _tile_distance(plan: FloorPlan, near: np.ndarray, p: np.ndarray, cap: float) -> np.ndarray:
    """Capped distance of the points ``p`` to the sides and tops of the obstacles ``near``."""
    quads, heights = plan.quads[near], plan.heights[near]
    d_xy = _quad_distance(p[:, :2], quads)  # (P, Q), 0 over the quad
    z = p[:, 2:3]
    over = d_xy <= 0.0
    top = np.max(np.where(over, heights[None, :], 0.0), axis=1)  # H(x, y)
    inside = p[:, 2] < top
    # outside the solid: the distance to the nearest prism
    d = np.sqrt(np.min(d_xy**2 + np.maximum(0.0, z - heights[None, :]) ** 2, axis=1))
    if np.any(inside):
        d[inside] = _inside_distance(quads, heights, p[inside], top[inside], cap)
    return np.minimum(d, cap)


def _inside_distance(
    quads: np.ndarray, heights: np.ndarray, p: np.ndarray, top: np.ndarray, cap: float
) -> np.ndarray:
    """Distance to the free space of points inside the solid (module docstring): straight up,
    or out through the outline of the obstacles taller than a level w (the floor or an
    obstacle height below the point's top), lifted to w when w is above the point."""
    best = top - p[:, 2]
    for w in np.unique(np.r_[0.0, heights]):
        taller = heights > w
        sel = np.flatnonzero(top > w)
        if not sel.size or not np.any(taller):
            continue
        a, b = _exposed_edges(quads[taller])
        d_xy = _segments_distance(p[sel, :2], a, b)
        best[sel] = np.minimum(best[sel], np.hypot(d_xy, np.maximum(0.0, w - p[sel, 2])))
    return np.minimum(best, cap)


def _quad_distance(xy: np.ndarray, quads: np.ndarray) -> np.ndarray:
    """2-D distance (P, Q) from points (P, 2) to convex CCW quads (Q, 4, 2); 0 inside."""
    a = quads[None]  # (1, Q, 4, 2)
    d = np.roll(quads, -1, axis=1)[None] - a
    r = xy[:, None, None, :] - a  # (P, Q, 4, 2)
    t = np.clip(np.sum(r * d, axis=-1) / np.maximum(np.sum(d * d, axis=-1), 1e-18), 0.0, 1.0)
    dist = np.linalg.norm(r - t[..., None] * d, axis=-1).min(axis=2)
    cross = d[..., 0] * r[..., 1] - d[..., 1] * r[..., 0]
    dist[np.all(cross >= 0.0, axis=2)] = 0.0
    return dist


def _exposed_edges(quads: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Start and end points (S, 2) of the parts of the quads' edges whose outside (EPS off
    along the outward normal) is not inside another quad."""
    starts, ends = [], []
    qlo, qhi = quads.min(axis=1), quads.max(axis=1)
    nrm_all = _outward_normals(quads)
    for q in range(len(quads)):
        for k in range(4):
            a, b = quads[q, k], quads[q, (k + 1) % 4]
            lo, hi = np.minimum(a, b) - 2 * EPS, np.maximum(a, b) + 2 * EPS
            others = np.flatnonzero(np.all((qhi >= lo) & (qlo <= hi), axis=1) & (np.arange(len(quads)) != q))
            off = EPS * nrm_all[q, k]
            covered = [_clip(a + off, b + off, quads[o], nrm_all[o]) for o in others]
            for t0, t1 in _complement([c for c in covered if c is not None]):
                starts.append(a + t0 * (b - a))
                ends.append(a + t1 * (b - a))
    if not starts:
        return np.zeros((0, 2)), np.zeros((0, 2))
    return np.array(starts), np.array(ends)


def _outward_normals(quads: np.ndarray) -> np.ndarray:
    d = np.roll(quads, -1, axis=1) - quads
    n = np.stack([d[..., 1], -d[..., 0]], axis=-1)
    return n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-18)


def _clip(a: np.ndarray, b: np.ndarray, quad: np.ndarray, normals: np.ndarray) -> tuple[float, float] | None:
    """The parameter interval [t0, t1] of the segment a-b inside the convex quad
    (Cyrus-Beck clipping), or None."""
    t0, t1 = 0.0, 1.0
    d = b - a
    for k in range(4):
        n = normals[k]
        # inside: n . (x - corner) <= 0
        num = -float(n @ (a - quad[k]))
        den = float(n @ d)
        if abs(den) < 1e-18:
            if num < 0:
                return None
            continue
        t = num / den
        if den > 0:
            t1 = min(t1, t)
        else:
            t0 = max(t0, t)
        if t0 >= t1:
            return None
    return t0, t1


def _complement(intervals: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """The parts of [0, 1] outside the union of the intervals."""
    out, at = [], 0.0
    for t0, t1 in sorted(intervals):
        if t0 > at:
            out.append((at, t0))
        at = max(at, t1)
    if at < 1.0:
        out.append((at, 1.0))
    return out


def _segments_distance(xy: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """2-D distance (P,) from points (P, 2) to the nearest of the segments a-b (S, 2); inf
    without segments."""
    if not len(a):
        return np.full(len(xy), np.inf)
    d = b - a
    r = xy[:, None, :] - a[None]
    t = np.clip(np.sum(r * d[None], axis=-1) / np.maximum(np.sum(d * d, axis=-1), 1e-18)[None], 0.0, 1.0)
    return np.linalg.norm(r - t[..., None] * d[None], axis=-1).min(axis=1)
