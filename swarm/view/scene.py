"""What the live view logs to rerun, as a function of the team map and the robots' status.

Entities (all under ``world/``, z up, metres; timeline ``sim_time``, seconds):

* ``world/map/occupied``: voxels with E[C] > 0.5 among the known ones, as boxes of the voxel
  size coloured by E[C] on viridis (0.5 dark, 1 yellow);
* ``world/map/entropy``: every known voxel's centre coloured by its entropy (magma, 0 to
  7 bits), a separate entity to toggle in the viewer;
* ``world/map/boundary``: known free voxels (E[C] <= 0.5) with an unknown face neighbour:
  the known/unknown boundary that exploration pushes;
* ``world/robots/<id>``: the robot's position, ``.../heading`` an arrow, ``.../path`` the
  positions so far, ``.../target`` its current target (the coordinator's assignment, or its
  own choice) with a line from the robot to it;
* ``plots/entropy``: the team map's entropy H (bits) after each merged delta.

Past ``max_points`` voxels per entity an even subsample is logged (the counts are logged to
``world/map/counts`` as text).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from swarm.map.coverage_map import CoverageMap
from swarm.map.entropy import expected_coverage
from swarm.map.entropy_table import default_table

PRIOR_BITS = 7.0


def require_rerun():
    """The ``rerun`` module, or an ImportError that says how to install it."""
    try:
        import rerun
    except ImportError as exc:
        raise ImportError(
            "the live view needs the rerun SDK: pip install -e '.[view]' (or 'swarm-mapping[view]')"
        ) from exc
    return rerun


def _colours(values: np.ndarray, name: str, lo: float, hi: float) -> np.ndarray:
    from matplotlib import colormaps

    scaled = np.clip((np.asarray(values, dtype=np.float64) - lo) / (hi - lo), 0.0, 1.0)
    return (colormaps[name](scaled)[:, :3] * 255).astype(np.uint8)


def _even(idx: np.ndarray, limit: int) -> np.ndarray:
    return idx if len(idx) <= limit else idx[np.linspace(0, len(idx) - 1, limit).astype(np.int64)]


def boundary_mask(known: np.ndarray, free: np.ndarray) -> np.ndarray:
    """Known free voxels with at least one unknown face neighbour; arrays shaped like the grid."""
    unknown = ~known
    near = np.zeros_like(known)
    for axis in range(3):
        for step in (1, -1):
            near |= np.roll(unknown, step, axis=axis) & _inner(known.shape, axis, step)
    return free & near


def _inner(shape: tuple[int, ...], axis: int, step: int) -> np.ndarray:
    """False on the layer that np.roll wrapped around."""
    mask = np.ones(shape, bool)
    index = [slice(None)] * 3
    index[axis] = 0 if step == 1 else -1
    mask[tuple(index)] = False
    return mask


@dataclass
class RobotTrack:
    """What the view knows of one robot from its ``robot/<id>/status``."""

    path: list[tuple[float, float, float]] = field(default_factory=list)
    yaw: float = 0.0
    target: tuple[float, float, float] | None = None
    state: str = ""


def log_map(rec, cmap: CoverageMap, max_points: int = 60_000) -> dict[str, int]:
    """Log the map entities (module doc) at the recording's current time; returns the counts."""
    rr = require_rerun()
    grid = cmap.grid
    mu = cmap.mean().astype(np.float64)
    sigma = cmap.sigma().astype(np.float64)
    known = cmap.known_mask()
    kidx = np.flatnonzero(known)
    coverage = expected_coverage(mu[kidx], sigma[kidx])
    occupied = kidx[coverage > 0.5]
    shown = _even(occupied, max_points)
    cov_shown = expected_coverage(mu[shown], sigma[shown])
    half = np.full(3, grid.voxel / 2, np.float32)
    rec.log(
        "world/map/occupied",
        rr.Boxes3D(
            centers=grid.centre(grid.unflat(shown)).astype(np.float32),
            half_sizes=np.broadcast_to(half, (len(shown), 3)),
            colors=_colours(cov_shown, "viridis", 0.5, 1.0),
            fill_mode="solid",
        ),
    )
    ent_idx = _even(kidx, max_points)
    bits = default_table()(mu[ent_idx].astype(np.float32), sigma[ent_idx].astype(np.float32))
    rec.log(
        "world/map/entropy",
        rr.Points3D(
            grid.centre(grid.unflat(ent_idx)).astype(np.float32),
            colors=_colours(bits, "magma", 0.0, PRIOR_BITS),
            radii=grid.voxel / 4,
        ),
    )
    free = np.zeros(grid.size, bool)
    free[kidx[coverage <= 0.5]] = True
    edge = np.flatnonzero(boundary_mask(known.reshape(grid.shape), free.reshape(grid.shape)).reshape(-1))
    edge_shown = _even(edge, max_points)
    rec.log(
        "world/map/boundary",
        rr.Points3D(
            grid.centre(grid.unflat(edge_shown)).astype(np.float32),
            colors=[90, 170, 240],
            radii=grid.voxel / 5,
        ),
    )
    counts = {"known": len(kidx), "occupied": len(occupied), "boundary": len(edge)}
    rec.log("world/map/counts", rr.TextDocument(", ".join(f"{k}: {v:,}" for k, v in counts.items())))
    return counts


def log_robot(rec, robot: str, track: RobotTrack) -> None:
    """Log one robot's position, heading, path and target at the current time."""
    rr = require_rerun()
    if not track.path:
        return
    here = np.asarray(track.path[-1], dtype=np.float32)
    base = f"world/robots/{robot}"
    rec.log(base, rr.Points3D([here], radii=0.12, colors=[230, 80, 40], labels=[f"{robot} {track.state}"]))
    heading = 0.4 * np.array([np.cos(track.yaw), np.sin(track.yaw), 0.0], np.float32)
    rec.log(f"{base}/heading", rr.Arrows3D(origins=[here], vectors=[heading], colors=[230, 80, 40]))
    rec.log(
        f"{base}/path",
        rr.LineStrips3D([np.asarray(track.path, np.float32)], colors=[230, 80, 40], radii=0.02),
    )
    if track.target is None:
        rec.log(f"{base}/target", rr.Clear(recursive=False))
    else:
        goal = np.asarray(track.target, dtype=np.float32)
        rec.log(f"{base}/target", rr.Points3D([goal], radii=0.1, colors=[40, 200, 90]))
        rec.log(f"{base}/target/line", rr.LineStrips3D([[here, goal]], colors=[40, 200, 90], radii=0.01))
