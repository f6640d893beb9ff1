"""The one look of every map picture (``top_view.png``, ``map_3d.png``, ``slices/``): colours,
colour-bar labels with units, and how robot paths are drawn.

Expected coverage E[C] (0: free, 1: occupied; the fraction of the voxel covered) is grey,
white to black (``gray_r``), in every picture; a column or voxel with no information beyond the
prior is light blue; entropy is ``magma`` from 0 to 7 bits per voxel (7 bits: the uninformative
prior); the floor plan is outlined in red; each robot's path has its own colour of ``tab10``
(red left out: it is the floor plan's), the same robot the same colour in every picture, with a
circle at its start and a square at its end, drawn over the map.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

COVERAGE_COLOURS = "gray_r"
UNKNOWN_COLOUR = "#a9d6f5"
ENTROPY_COLOURS = "magma"
FLOOR_PLAN_COLOUR = "tab:red"
PRIOR_BITS = 7.0  # the entropy of the uninformative prior: 128 bins

COVERAGE_LABEL = "E[C], expected coverage (0 free, 1 occupied)"
ENTROPY_LABEL = "entropy (bits per voxel; 7 = no information)"

#: Paths: robot id -> (N, 2) or (N, 3) points in metres (x, y[, z]), in the order travelled.
Paths = Mapping[str, np.ndarray]


def pyplot():
    """matplotlib.pyplot on the file-only Agg backend (no display needed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def coverage_colours():
    """The E[C] colour map, light blue where the value is masked (unknown)."""
    return pyplot().get_cmap(COVERAGE_COLOURS).with_extremes(bad=UNKNOWN_COLOUR)


def path_colour(n: int) -> tuple[float, float, float]:
    """The colour of the ``n``-th robot's path (0-based), the same in every picture."""
    palette = [c for i, c in enumerate(pyplot().get_cmap("tab10").colors) if i != 3]  # red: the plan's
    return palette[n % len(palette)]


def paths_from_trajectories(trajectories: Mapping[str, Sequence[Sequence[float]]]) -> dict[str, np.ndarray]:
    """A run's ``trajectories.json`` (robot id -> ``[[t s, x m, y m], ...]``) as paths (x, y)."""
    out = {}
    for rid, rows in trajectories.items():
        pts = np.asarray(rows, dtype=np.float64)
        if pts.ndim == 2 and pts.shape[1] >= 3 and len(pts):
            out[str(rid)] = pts[:, 1:3]
    return out


def path_length(points: np.ndarray) -> float:
    """Metres along a path's points (x, y), the plane distance a ground robot covered."""
    pts = np.asarray(points, dtype=np.float64)
    if len(pts) < 2:
        return 0.0
    return float(np.sum(np.hypot(*np.diff(pts[:, :2], axis=0).T)))


def draw_paths_2d(ax, paths: Paths, lengths: bool = True) -> list:
    """Draw each path on a top-down axis, over what is there; returns legend handles."""
    from matplotlib.lines import Line2D

    handles = []
    for n, (rid, pts) in enumerate(paths.items()):
        pts = np.asarray(pts, dtype=np.float64)
        if pts.ndim != 2 or not len(pts):
            continue
        c = path_colour(n)
        ax.plot(pts[:, 0], pts[:, 1], "-", color=c, lw=1.6, zorder=5)
        ax.plot(pts[0, 0], pts[0, 1], "o", color=c, ms=7, mec="black", zorder=6)
        ax.plot(pts[-1, 0], pts[-1, 1], "s", color=c, ms=7, mec="black", zorder=6)
        label = f"{rid} ({path_length(pts):.1f} m)" if lengths else str(rid)
        handles.append(Line2D([], [], color=c, lw=1.6, label=label))
    if handles:
        handles += [
            Line2D([], [], ls="", marker="o", color="white", mec="black", label="start"),
            Line2D([], [], ls="", marker="s", color="white", mec="black", label="end"),
        ]
    return handles


def draw_paths_3d(ax, paths: Paths, floor_z: float) -> None:
    """Draw each path on a 3-D axis over the voxels (the axis draws in zorder, not by depth):
    a path of (x, y) points at ``floor_z``, a path of (x, y, z) points where it went."""
    ax.computed_zorder = False
    for n, (rid, pts) in enumerate(paths.items()):
        pts = np.asarray(pts, dtype=np.float64)
        if pts.ndim != 2 or not len(pts):
            continue
        z = pts[:, 2] if pts.shape[1] >= 3 else np.full(len(pts), floor_z)
        c = path_colour(n)
        ax.plot(pts[:, 0], pts[:, 1], z, "-", color=c, lw=2.2, zorder=10, label=f"{rid} path")
        ax.scatter([pts[0, 0]], [pts[0, 1]], [z[0]], color=c, marker="o", s=40, edgecolors="black",
                   zorder=11, depthshade=False)  # fmt: skip
        ax.scatter([pts[-1, 0]], [pts[-1, 1]], [z[-1]], color=c, marker="s", s=40, edgecolors="black",
                   zorder=11, depthshade=False)  # fmt: skip
