"""The run folder's two flat plots: ``entropy.png`` and ``top_view.png``.

``entropy.png`` shows H(t) over sim time with H_th dashed and the mission time marked;
``top_view.png`` shows, for each (x, y) column, the largest expected coverage among the
*known* voxels of the robot's height band (grey, white = free, black = occupied); columns
with no known voxel in the band are light blue. Floor-plan obstacles are outlined in red
and each robot's trajectory is drawn in its own colour (circle = start, square = end).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from swarm.formats.floor_plan import FloorPlan
from swarm.map.coverage_map import CoverageMap
from swarm.map.entropy import expected_coverage
from swarm.mission import evaluation
from swarm.mission.map_pictures import UNKNOWN_COLOUR

_OBSTACLE_COLOUR = "tab:red"


def top_view_image(cmap: CoverageMap, height_band: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """Top view over the layers whose voxel centre lies in ``height_band`` (all layers if none does).

    Returns (image, layers): image (nx, ny) is the largest E[C] among the known voxels of
    each column's band, NaN where none of them is known; layers are the z indices used.
    """
    grid = cmap.grid
    z = grid.lo[2] + (np.arange(grid.shape[2]) + 0.5) * grid.voxel
    layers = np.flatnonzero((z >= height_band[0] - 1e-9) & (z <= height_band[1] + 1e-9))
    if layers.size == 0:
        layers = np.arange(grid.shape[2])
    lam = cmap.lam.reshape(grid.shape)[:, :, layers]
    eta = cmap.eta.reshape(grid.shape)[:, :, layers]
    known = cmap.known_mask().reshape(grid.shape)[:, :, layers]
    lam64 = lam.astype(np.float64)
    cov = np.where(known, expected_coverage(eta / lam64, 1.0 / np.sqrt(lam64)), -np.inf)
    image = cov.max(axis=2)
    image[~known.any(axis=2)] = np.nan
    return image, layers


def plot_entropy(path: str | Path, metrics: dict[str, Any]) -> None:
    """Entropy over sim time, H_th as a dashed line, the mission time marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    curve = np.asarray(metrics.get("entropy_curve") or [], dtype=np.float64).reshape(-1, 2)
    threshold = float(metrics["threshold_bits"])
    t_mission = metrics.get("mission_time_s")
    fig, ax = plt.subplots(figsize=(7.5, 4.2), dpi=120, layout="constrained")
    ax.plot(curve[:, 0], curve[:, 1], "-", color="tab:blue", lw=1.6, label="map entropy H(t)")
    ax.axhline(threshold, ls="--", color="tab:red", lw=1.2, label=f"H_th = {_bits(threshold)}")
    if t_mission is not None:
        below = np.flatnonzero(curve[:, 1] <= threshold)
        h_at = curve[below[0], 1] if below.size else threshold
        ax.axvline(t_mission, ls=":", color="tab:green", lw=1.2)
        ax.plot([t_mission], [h_at], "o", color="tab:green", label=f"mission time {t_mission:.1f} s")
    else:
        ax.text(0.98, 0.95, "threshold not reached", transform=ax.transAxes, ha="right", va="top")
    if not len(curve):
        ax.text(0.5, 0.5, "no entropy samples", transform=ax.transAxes, ha="center")
    top = max([threshold, float(metrics.get("initial_entropy_bits") or 0.0), *curve[:, 1]])
    ax.set_ylim(0.0, 1.05 * top if top > 0 else 1.0)
    ax.set_xlim(left=0.0)
    ax.set_xlabel("sim time (s)")
    ax.set_ylabel("map entropy (bits)")
    robots = metrics.get("robots") or []
    ax.set_title(
        f"{len(robots)} robot(s), {metrics.get('strategy')}, {metrics.get('coordination')}, "
        f"seed {metrics.get('seed')}"
    )
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper right" if t_mission is not None else "center right")
    fig.savefig(path)
    plt.close(fig)


def _bits(x: float) -> str:
    return f"{x:,.0f} bits" if abs(x) >= 100 else f"{x:.3g} bits"


def plot_top_view(
    path: str | Path,
    cmap: CoverageMap,
    height_band: tuple[float, float],
    trajectories: dict[str, list[list[float]]],
    floor_plan: FloorPlan | None = None,
) -> None:
    """Top view of the map (see the module docstring) over ``height_band`` (z from, z to, m),
    with the floor plan's obstacles and each robot's trajectory ([[t, x, y], ...])."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import PolyCollection
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    grid = cmap.grid
    image, layers = top_view_image(cmap, height_band)
    (x0, y0, _), (x1, y1, _) = grid.lo, grid.hi
    z_lo = grid.lo[2] + layers[0] * grid.voxel
    z_hi = grid.lo[2] + (layers[-1] + 1) * grid.voxel
    ratio = (y1 - y0) / (x1 - x0)
    height = min(max(6.5 * ratio, 2.5), 9.0) + 1.6  # the map, then title, labels and legend
    fig, ax = plt.subplots(figsize=(8.0, height), dpi=120, layout="constrained")
    colours = plt.get_cmap("gray_r").with_extremes(bad=UNKNOWN_COLOUR)
    shown = ax.imshow(
        np.ma.masked_invalid(image.T),
        origin="lower",
        extent=(x0, x1, y0, y1),
        cmap=colours,
        vmin=0.0,
        vmax=1.0,
        interpolation="nearest",
    )
    fig.colorbar(shown, ax=ax, fraction=0.04, shrink=0.85, label="max E[C] of known voxels in band")
    handles: list[Any] = [Patch(facecolor=UNKNOWN_COLOUR, edgecolor="grey", label="unknown")]
    plan = floor_plan
    if plan is not None and plan.count:
        outlines = PolyCollection(plan.quads, facecolors="none", edgecolors=_OBSTACLE_COLOUR, linewidths=0.7)
        outlines.set_alpha(0.85)
        ax.add_collection(outlines)
        handles.append(Line2D([], [], color=_OBSTACLE_COLOUR, lw=0.7, label="floor plan"))
    palette = [c for i, c in enumerate(plt.get_cmap("tab10").colors) if i != 3]  # red is the plan's
    for n, (rid, traj) in enumerate(trajectories.items()):
        pts = np.asarray(traj, dtype=np.float64)
        if pts.ndim != 2 or not len(pts):
            continue
        c = palette[n % len(palette)]
        ax.plot(pts[:, 1], pts[:, 2], "-", color=c, lw=1.6)
        ax.plot(pts[0, 1], pts[0, 2], "o", color=c, ms=7, mec="black")
        ax.plot(pts[-1, 1], pts[-1, 2], "s", color=c, ms=7, mec="black")
        handles.append(Line2D([], [], color=c, lw=1.6, label=f"{rid} ({evaluation.path_length(pts):.1f} m)"))
    handles += [
        Line2D([], [], ls="", marker="o", color="white", mec="black", label="start"),
        Line2D([], [], ls="", marker="s", color="white", mec="black", label="end"),
    ]
    pad = 0.02 * max(x1 - x0, y1 - y0)
    ax.set_xlim(x0 - pad, x1 + pad)
    ax.set_ylim(y0 - pad, y1 + pad)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(f"Top view, z in [{z_lo:.2f}, {z_hi:.2f}] m")
    fig.legend(handles=handles, loc="outside lower center", ncol=min(len(handles), 5), fontsize="small")
    fig.savefig(path)
    plt.close(fig)
