"""The picture set of a coverage map, one for every kind of run (``swarm sim``, ``swarm replay``,
``swarm map picture``), in the look of :mod:`swarm.mission.picture_style`.

``top_view.png``: per (x, y) column, the largest E[C] among the *known* voxels of a height band
(``height_band``, z from, z to in metres; the robots' band in a simulated mission), light blue
where none is known, with the floor plan's obstacles outlined and the paths on top.

``map_3d.png``: the occupied voxels (known, E[C] > 0.5) as squares at their centres, grey by
E[C] as in the top view, seen from above at an angle, with the paths drawn over them. A flat
map (height under 30% of its length) is drawn with z stretched to 30%, and the z label says
so. Past ``max_voxels`` voxels an even subsample is drawn (the title says how many of how many).

``slices/band_NN_zA_to_Bm.png``: one picture per height band (``band_m`` metres of voxel layers,
at most ``max_bands`` bands), two panels: the largest E[C] among the band's known voxels per
column (unknown light blue, paths on top), and the mean entropy of the band's voxels per
column in bits (0 = certain, 7 = the uninformative prior).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from swarm.formats.floor_plan import FloorPlan
from swarm.formats.shown_numbers import shown
from swarm.map.coverage_map import CoverageMap
from swarm.map.entropy import expected_coverage
from swarm.map.entropy_table import default_table
from swarm.mission.picture_style import (
    COVERAGE_LABEL,
    ENTROPY_COLOURS,
    ENTROPY_LABEL,
    FLOOR_PLAN_COLOUR,
    PRIOR_BITS,
    UNKNOWN_COLOUR,
    Paths,
    coverage_colours,
    draw_paths_2d,
    draw_paths_3d,
    pyplot,
)

#: The files of the set, as :func:`write_map_pictures` writes them into a folder.
PICTURES = ("top_view.png", "map_3d.png", "slices/")


def write_map_pictures(
    out_dir: str | Path,
    cmap: CoverageMap,
    paths: Paths | None = None,
    floor_plan: FloorPlan | None = None,
    height_band: tuple[float, float] | None = None,
) -> list[Path]:
    """Write ``top_view.png``, ``map_3d.png`` and ``slices/`` into ``out_dir`` (module doc);
    ``height_band`` of the top view defaults to the whole height. Returns the files written."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    band = height_band or (cmap.grid.lo[2], cmap.grid.hi[2])
    paths = dict(paths or {})
    beliefs = map_beliefs(cmap)
    plot_top_view(out / "top_view.png", cmap, band, paths, floor_plan)
    plot_map_3d(out / "map_3d.png", cmap, paths, beliefs=beliefs)
    slices = plot_slices(out / "slices", cmap, paths=paths, beliefs=beliefs)
    return [out / "top_view.png", out / "map_3d.png", *slices]


def map_beliefs(cmap: CoverageMap) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """E[C], entropy (bits) and the known mask, each shaped like the grid."""
    mu = cmap.mean().astype(np.float64)
    sigma = cmap.sigma().astype(np.float64)
    shape = cmap.grid.shape
    coverage = expected_coverage(mu, sigma).reshape(shape)
    entropy = default_table()(mu.astype(np.float32), sigma.astype(np.float32)).reshape(shape)
    return coverage, entropy, cmap.known_mask().reshape(shape)


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


def plot_top_view(
    path: str | Path,
    cmap: CoverageMap,
    height_band: tuple[float, float],
    paths: Paths | None = None,
    floor_plan: FloorPlan | None = None,
) -> None:
    """Write the top view (module doc) over ``height_band`` (z from, z to, m)."""
    plt = pyplot()
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
    picture = ax.imshow(np.ma.masked_invalid(image.T), origin="lower", extent=(x0, x1, y0, y1),
                      cmap=coverage_colours(), vmin=0.0, vmax=1.0, interpolation="nearest")  # fmt: skip
    fig.colorbar(picture, ax=ax, fraction=0.04, shrink=0.85, label=f"{COVERAGE_LABEL}, max in band")
    handles = [Patch(facecolor=UNKNOWN_COLOUR, edgecolor="grey", label="unknown")]
    if floor_plan is not None and floor_plan.count:
        outlines = PolyCollection(floor_plan.quads, facecolors="none", edgecolors=FLOOR_PLAN_COLOUR,
                                  linewidths=0.7, alpha=0.85, zorder=4)  # fmt: skip
        ax.add_collection(outlines)
        handles.append(Line2D([], [], color=FLOOR_PLAN_COLOUR, lw=0.7, label="floor plan"))
    handles += draw_paths_2d(ax, paths or {})
    pad = 0.02 * max(x1 - x0, y1 - y0)
    ax.set(xlim=(x0 - pad, x1 + pad), ylim=(y0 - pad, y1 + pad), aspect="equal")
    band = f"[{shown(z_lo, 2):.2f}, {shown(z_hi, 2):.2f}]"
    ax.set(xlabel="x (m)", ylabel="y (m)", title=f"Top view, z in {band} m")
    fig.legend(handles=handles, loc="outside lower center", ncol=min(len(handles), 5), fontsize="small")
    fig.savefig(path)
    plt.close(fig)


def plot_map_3d(
    path: str | Path,
    cmap: CoverageMap,
    paths: Paths | None = None,
    title: str = "Occupied voxels (E[C] > 0.5)",
    max_voxels: int = 20_000,
    beliefs: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> int:
    """Write the 3-D view (module doc); returns how many voxels were drawn."""
    plt = pyplot()
    grid = cmap.grid
    coverage, _, known = beliefs or map_beliefs(cmap)
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
    voxels = ax.scatter(*centres.T, c=coverage.reshape(-1)[occupied], cmap=coverage_colours(), vmin=0.0,
                       vmax=1.0, marker="s", s=size, depthshade=True, linewidths=0, zorder=1)  # fmt: skip
    draw_paths_3d(ax, paths or {}, float(lo[2]))
    ax.set(xlim=(lo[0], hi[0]), ylim=(lo[1], hi[1]), zlim=(lo[2], hi[2]), xlabel="x (m)", ylabel="y (m)")
    ax.set_zlabel("z (m, stretched)" if stretched else "z (m)")
    ax.view_init(elev=35, azim=-60)
    drawn = f"{len(occupied):,} of {total:,} voxels drawn" if total > len(occupied) else f"{total:,} voxels"
    ax.set_title(f"{title}: {drawn}, voxel {grid.voxel:g} m")
    fig.colorbar(voxels, ax=ax, shrink=0.6, pad=0.08, label=COVERAGE_LABEL)
    if paths:
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
    out_dir: str | Path,
    cmap: CoverageMap,
    band_m: float = 0.4,
    max_bands: int = 8,
    paths: Paths | None = None,
    beliefs: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> list[Path]:
    """Write the slice stack (module doc) into ``out_dir``; returns the files written.

    One figure serves every band: it is laid out and drawn once without its images and title,
    and each band draws only those over a copy of that background (drawing a whole figure
    per band took most of a run folder's time)."""
    from PIL import Image

    plt = pyplot()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    for old in out.glob("band_*.png"):
        old.unlink()
    grid = cmap.grid
    coverage, entropy, known = beliefs or map_beliefs(cmap)
    (x0, y0, z0), (x1, y1, _) = grid.lo, grid.hi
    ratio = (y1 - y0) / (x1 - x0)
    fig, axes = plt.subplots(1, 2, figsize=(11.0, min(max(4.2 * ratio, 2.2), 8.0) + 1.2), dpi=110)
    fig.set_layout_engine("constrained")
    blank = np.full(grid.shape[1::-1], np.nan)
    panels = (
        (coverage_colours(), 0.0, 1.0, f"{COVERAGE_LABEL}, max", "expected coverage (light blue: unknown)"),
        (plt.get_cmap(ENTROPY_COLOURS), 0.0, PRIOR_BITS, f"{ENTROPY_LABEL}, mean", "entropy"),
    )
    images = []
    for ax, (colours, vmin, vmax, label, title) in zip(axes, panels, strict=True):
        picture = ax.imshow(np.ma.masked_invalid(blank), origin="lower", extent=(x0, x1, y0, y1),
                            cmap=colours, vmin=vmin, vmax=vmax, interpolation="nearest")  # fmt: skip
        images.append(picture)
        fig.colorbar(picture, ax=ax, fraction=0.05, shrink=0.9, label=label)
        ax.set(aspect="equal", xlabel="x (m)", ylabel="y (m)", title=title)
    draw_paths_2d(axes[0], paths or {})
    axes[0].set(xlim=(x0, x1), ylim=(y0, y1))
    heading = fig.suptitle("Height band 0: z in [0.00, 0.00] m")  # lays out room for the title
    fig.canvas.draw()
    fig.set_layout_engine("none")
    over_images = [*axes[0].lines, heading]  # drawn again over each band's images
    for artist in (*images, *over_images):
        artist.set_visible(False)
    fig.canvas.draw()
    background = fig.canvas.copy_from_bbox(fig.bbox)
    for artist in (*images, *over_images):
        artist.set_visible(True)
    written = []
    for n, (k0, k1) in enumerate(height_bands(cmap, band_m, max_bands)):
        band_known = known[:, :, k0:k1]
        cov = np.where(band_known, coverage[:, :, k0:k1], -np.inf).max(axis=2)
        cov[~band_known.any(axis=2)] = np.nan
        images[0].set_data(np.ma.masked_invalid(cov.T))
        images[1].set_data(entropy[:, :, k0:k1].mean(axis=2).T)
        za, zb = shown(z0 + k0 * grid.voxel, 2), shown(z0 + k1 * grid.voxel, 2)
        heading.set_text(f"Height band {n}: z in [{za:.2f}, {zb:.2f}] m")
        fig.canvas.restore_region(background)
        for ax, picture in zip(axes, images, strict=True):
            ax.draw_artist(picture)
        for artist in over_images:
            artist.axes.draw_artist(artist) if artist.axes is not None else fig.draw_artist(artist)
        path = out / f"band_{n:02d}_z{za:.2f}_to_{zb:.2f}m.png"  # z-0.60_to_-0.20m: signs stay readable
        Image.fromarray(np.asarray(fig.canvas.buffer_rgba())).save(path)
        written.append(path)
    plt.close(fig)
    return written
