"""Pictures of a whole coverage map for the run folder: a 3-D view and a slice stack.

``map_3d.png``: the occupied voxels (E[C] > 0.5) as squares at their centres, coloured by
expected coverage (colour bar, 0-1), seen from above at an angle, with each robot's path
drawn on the floor. A flat map (height under 30% of its length) is drawn with z stretched to
30%, and the z label says so. Past ``max_voxels`` voxels an even subsample is drawn (the title says
how many of how many).

``slices/band_NN_zA-Bm.png``: one picture per height band (``band_m`` metres of voxel
layers, at most ``max_bands`` bands), two panels side by side: the largest E[C] among the
band's known voxels per (x, y) column (unknown columns light blue), and the mean entropy
of the band's voxels per column in bits (0 = certain, 7 = the uninformative prior).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from swarm.map.coverage_map import CoverageMap
from swarm.map.entropy import expected_coverage
from swarm.map.entropy_table import default_table

UNKNOWN_COLOUR = "#a9d6f5"
PRIOR_BITS = 7.0


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def beliefs(cmap: CoverageMap) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """E[C], entropy (bits) and the known mask, each shaped like the grid."""
    mu = cmap.mean().astype(np.float64)
    sigma = cmap.sigma().astype(np.float64)
    shape = cmap.grid.shape
    coverage = expected_coverage(mu, sigma).reshape(shape)
    entropy = default_table()(mu.astype(np.float32), sigma.astype(np.float32)).reshape(shape)
    return coverage, entropy, cmap.known_mask().reshape(shape)


def plot_map_3d(
    path: str | Path,
    cmap: CoverageMap,
    trajectories: dict[str, list] | None = None,
    title: str = "Occupied voxels (E[C] > 0.5)",
    max_voxels: int = 30_000,
) -> int:
    """Write the 3-D view (module doc); returns how many voxels were drawn."""
    plt = _pyplot()
    grid = cmap.grid
    coverage, _, known = beliefs(cmap)
    occupied = np.flatnonzero((coverage > 0.5).reshape(-1) & known.reshape(-1))
    total = len(occupied)
    if total > max_voxels:
        occupied = occupied[np.linspace(0, total - 1, max_voxels).astype(np.int64)]
    centres = grid.centre(grid.unflat(occupied))
    lo, hi = grid.lo, grid.hi
    fig = plt.figure(figsize=(8.5, 6.5), dpi=120, layout="constrained")
    ax = fig.add_subplot(projection="3d")
    extent = hi - lo
    aspect = extent / extent.max()
    stretched = aspect[2] < 0.3  # a flat building: z drawn taller than true scale, and said so
    aspect[2] = max(aspect[2], 0.3)
    ax.set_box_aspect(tuple(aspect))
    # marker size: about one voxel on a figure showing the longest side in ~5 inches
    size = max(1.0, (72 * 5.0 * grid.voxel / extent.max()) ** 2)
    shown = ax.scatter(
        centres[:, 0],
        centres[:, 1],
        centres[:, 2],
        c=coverage.reshape(-1)[occupied],
        cmap="viridis",
        vmin=0.5,
        vmax=1.0,
        marker="s",
        s=size,
        depthshade=True,
        linewidths=0,
    )
    for rid, traj in (trajectories or {}).items():
        pts = np.asarray(traj, dtype=np.float64).reshape(-1, 3)
        if len(pts):
            ax.plot(pts[:, 1], pts[:, 2], np.full(len(pts), lo[2]), lw=1.5, label=f"{rid} path")
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_zlim(lo[2], hi[2])
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("z (m, stretched)" if stretched else "z (m)")
    ax.view_init(elev=35, azim=-60)
    drawn = f"{len(occupied):,} of {total:,} voxels drawn" if total > len(occupied) else f"{total:,} voxels"
    ax.set_title(f"{title}: {drawn}, voxel {grid.voxel:g} m")
    fig.colorbar(shown, ax=ax, shrink=0.6, pad=0.08, label="expected coverage E[C] (0-1)")
    if trajectories:
        ax.legend(loc="upper left", fontsize="small")
    fig.savefig(path)
    plt.close(fig)
    return len(occupied)


def height_bands(cmap: CoverageMap, band_m: float = 0.4, max_bands: int = 8) -> list[tuple[int, int]]:
    """Voxel layer ranges [k0, k1) of the slice stack, bottom up."""
    nz = cmap.grid.shape[2]
    per = max(1, round(band_m / cmap.grid.voxel), -(-nz // max_bands))
    return [(k, min(k + per, nz)) for k in range(0, nz, per)]


def plot_slices(
    out_dir: str | Path, cmap: CoverageMap, band_m: float = 0.4, max_bands: int = 8
) -> list[Path]:
    """Write the slice stack (module doc) into ``out_dir``; returns the files written."""
    plt = _pyplot()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    for old in out.glob("band_*.png"):
        old.unlink()
    grid = cmap.grid
    coverage, entropy, known = beliefs(cmap)
    (x0, y0, z0), (x1, y1, _) = grid.lo, grid.hi
    extent = (x0, x1, y0, y1)
    ratio = (y1 - y0) / (x1 - x0)
    written = []
    for n, (k0, k1) in enumerate(height_bands(cmap, band_m, max_bands)):
        band_known = known[:, :, k0:k1]
        cov = np.where(band_known, coverage[:, :, k0:k1], -np.inf).max(axis=2)
        cov[~band_known.any(axis=2)] = np.nan
        bits = entropy[:, :, k0:k1].mean(axis=2)
        za, zb = z0 + k0 * grid.voxel, z0 + k1 * grid.voxel
        fig, axes = plt.subplots(1, 2, figsize=(11.0, min(max(4.2 * ratio, 2.2), 8.0) + 1.2), dpi=110)
        fig.set_layout_engine("constrained")
        greys = plt.get_cmap("gray_r").with_extremes(bad=UNKNOWN_COLOUR)
        panels = (
            (cov, greys, 0.0, 1.0, "max E[C] of known voxels"),
            (bits, plt.get_cmap("magma"), 0.0, PRIOR_BITS, "mean entropy (bits per voxel)"),
        )
        for ax, (image, colours, vmin, vmax, label) in zip(axes, panels, strict=True):
            shown = ax.imshow(
                np.ma.masked_invalid(image.T),
                origin="lower",
                extent=extent,
                cmap=colours,
                vmin=vmin,
                vmax=vmax,
                interpolation="nearest",
            )
            fig.colorbar(shown, ax=ax, fraction=0.05, shrink=0.9, label=label)
            ax.set_aspect("equal")
            ax.set_xlabel("x (m)")
            ax.set_ylabel("y (m)")
        axes[0].set_title("expected coverage (light blue: unknown)")
        axes[1].set_title("entropy (7 bits: no information)")
        fig.suptitle(f"Height band {n}: z in [{za:.2f}, {zb:.2f}] m")
        path = out / f"band_{n:02d}_z{za:.2f}-{zb:.2f}m.png"
        fig.savefig(path)
        plt.close(fig)
        written.append(path)
    return written
