"""``swarm bench sparse``: the block-sparse map beside the dense one: the same map, fusion time, memory.

Per stream of ray batches (``swarm.bench.ray_streams``: the office mission's rig over its
floor, the real EuRoC stereo frames, the real OctoMap scan):

- *same map*: the block map bounded by the stream's grid against ``CoverageMap`` on it, and
  the unbounded block map against a dense grid holding every ray (its lattice from that
  grid's corner): the largest relative difference of lam and eta over every voxel;
- *fusion time*: the whole stream fused into fresh maps (each batch's delta computed and
  applied), dense, block map bounded, block map unbounded, alternating within each of
  ``repeat`` rounds (best wall and CPU time); then the same with the per-voxel entropy cache
  a role keeps (``EntropyCache`` beside the dense map, the block map's own);
- *memory*: the dense arrays (lam, eta, entropy: 12 bytes a voxel) against the block map's.

Then the campus site (200 m x 100 m x 5 m at 0.1 m, 1e8 voxels): 16 robots driving its
streets, the block map's memory as it grows with the volume explored.
"""

from __future__ import annotations

import os
import resource
import time
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from swarm.bench import ray_streams
from swarm.map.block_fusion import block_batch_information
from swarm.map.block_map import BlockMap
from swarm.map.coverage_map import CoverageMap
from swarm.map.entropy_cache import EntropyCache
from swarm.map.fusion import batch_information, warm_up
from swarm.map.grid import Grid
from swarm.map.lattice import Lattice
from swarm.map.sensor_model import SensorModel

#: Bytes per voxel a role holds for a dense map: lam, eta and the entropy cache (float32 each).
DENSE_BYTES_PER_VOXEL = 12
MB = 1e6


@dataclass
class StreamFigures:
    name: str
    model: str
    frames: int
    rays: int
    voxels: int  # of the stream's grid
    seconds: dict[str, float]  # best wall time per map ("dense", "bounded", "unbounded", + " +H")
    cpu_seconds: dict[str, float]
    bounded_difference: float  # largest relative difference, bounded block map vs dense
    unbounded_difference: float  # unbounded block map vs a dense grid holding every ray
    blocks: int  # unbounded block map
    sparse_bytes: int
    bounded_blocks: int
    bounded_bytes: int


def holding_grid(frames: list, sensor: SensorModel, voxel: float) -> Grid:
    """A grid holding every ray of ``frames`` (ends cut at the sensor's reach) and the voxels behind."""
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    for origin, points in frames:
        v = points[np.all(np.isfinite(points), axis=1)] - origin
        dist = np.linalg.norm(v, axis=1, keepdims=True)
        ends = origin + v * np.minimum(1.0, sensor.reach / np.maximum(dist, 1e-12))
        lo = np.minimum(lo, np.minimum(ends.min(axis=0), origin))
        hi = np.maximum(hi, np.maximum(ends.max(axis=0), origin))
    return Grid.from_bounds(lo - 2 * voxel, hi + 3 * voxel, voxel)


def relative_difference(a: CoverageMap, b: CoverageMap) -> float:
    """max |a - b| / |b| over the lam and eta of every voxel (0 where both are 0)."""
    worst = 0.0
    for x, y in ((a.lam, b.lam), (a.eta, b.eta)):
        diff = np.abs(x.astype(np.float64) - y)
        scale = np.abs(y.astype(np.float64))
        worst = max(worst, float(np.max(np.where(diff > 0, diff / np.maximum(scale, 1e-300), 0.0))))
    return worst


def _fuse_dense(grid, sensor, frames, cache: bool) -> CoverageMap:
    t0 = time.perf_counter()
    cmap = CoverageMap(grid, sensor)
    entropy = EntropyCache.from_information(cmap.lam, cmap.eta) if cache else None
    allocation = time.perf_counter() - t0
    t0, c0 = time.perf_counter(), time.process_time()
    for origin, points in frames:
        delta = batch_information(grid, sensor, origin, points).delta
        cmap.apply(delta)
        if entropy is not None:
            idx = delta.idx.astype(np.int64)
            entropy.update_information(idx, cmap.lam[idx], cmap.eta[idx])
    return cmap, time.perf_counter() - t0, time.process_time() - c0, allocation


def _fuse_sparse(lattice, sensor, bounds, frames, cache: bool) -> BlockMap:
    bmap = BlockMap(lattice, sensor, bounds, entropy=cache)
    t0, c0 = time.perf_counter(), time.process_time()
    for origin, points in frames:
        bmap.apply(block_batch_information(lattice, sensor, origin, points, bounds).delta)
    return bmap, time.perf_counter() - t0, time.process_time() - c0


def compare(
    name: str, model: str, grid: Grid, sensor: SensorModel, frames: list, repeat: int
) -> StreamFigures:
    """The figures of one stream on ``grid`` (see the module's docstring)."""
    lattice = Lattice.of_grid(grid)
    holding = holding_grid(frames, sensor, grid.voxel)
    free = Lattice.of_grid(holding)  # the unbounded map's lattice: comparable with the holding grid
    wall: dict[str, float] = {}
    cpu: dict[str, float] = {}

    def keep(key, seconds, cpu_s):
        wall[key] = min(wall.get(key, np.inf), seconds)
        cpu[key] = min(cpu.get(key, np.inf), cpu_s)

    for round_ in range(repeat + 1):  # round 0 is not timed: it sizes and faults in the kept scratch memory
        for cache in (False, True):
            tag = " +H" if cache else ""
            dense, *t, allocation = _fuse_dense(grid, sensor, frames, cache)
            bounded, *u = _fuse_sparse(lattice, sensor, grid, frames, cache)
            unbounded, *v = _fuse_sparse(free, sensor, None, frames, cache)
            if round_:
                keep("dense" + tag, *t)
                keep("dense grid" + tag, allocation, allocation)
                keep("bounded" + tag, *u)
                keep("unbounded" + tag, *v)
    reference = _fuse_dense(holding, sensor, frames, False)[0]
    return StreamFigures(
        name,
        model,
        len(frames),
        sum(len(p) for _, p in frames),
        grid.size,
        wall,
        cpu,
        relative_difference(bounded.to_dense(grid), dense),
        relative_difference(unbounded.to_dense(holding), reference),
        unbounded.n_blocks,
        unbounded.nbytes(),
        bounded.n_blocks,
        bounded.nbytes(),
    )


def streams(config: Path, scan: Path | None, euroc: Path | None, voxel: float = 0.1):
    """(name, model, grid, sensor, frames) of each stream that can be built."""
    from swarm.bench.fusion import UNLIMITED, clouds  # noqa: PLC0415
    from swarm.config import load_mission  # noqa: PLC0415

    mission = load_mission(config)
    rig = mission.rig_for(mission.robot_ids[0])
    model = mission.sensor_model_of(rig)
    frames = ray_streams.office_frames(mission)
    name = f"{mission.mission} ({len(frames)} range frames {rig.width}x{rig.height})"
    grid = mission.workspace.grid()
    yield name, "weighted", grid, model, frames
    yield name, "one per ray", grid, replace(model, discretize=False, weighted=False), frames
    if euroc is not None and (euroc / "mav0").exists():
        frames = ray_streams.euroc_frames(euroc)
        for discretize, label in ((False, "one per ray"), (True, "discretize")):
            sensor = SensorModel(max_range=5.0, discretize=discretize)
            yield f"EuRoC V1_01 ({len(frames)} stereo frames, 5 m)", label, None, sensor, frames
    for cloud, points, max_range in clouds(scan, None):
        sensor = SensorModel(max_range=max_range)
        reach = "whole beam" if max_range >= UNLIMITED else f"{max_range:g} m"
        yield f"OctoMap scan {cloud} ({reach})", "one per ray", None, sensor, [(np.zeros(3), points)]


def run_streams(config: Path, scan: Path | None, euroc: Path | None, repeat: int, progress=None):
    warm_up()
    out = []
    for name, model, grid, sensor, frames in streams(config, scan, euroc):
        if progress is not None:
            progress(f"{name}, {model}")
        grid = grid or holding_grid(frames, sensor, 0.1)
        out.append(compare(name, model, grid, sensor, frames, repeat))
    return out


# -- the site ------------------------------------------------------------------------------
def site_growth(config: Path, robots: int = 16, points: int = 5, block_bits=(4, 3), progress=None):
    """(site grid, rows) as ``robots`` robots drive the campus streets, fused into a block map of
    each of ``block_bits``, bounded by the site. ``points`` rows spread over the drive, each
    (frames, explored m^3, {bits: (blocks, MB, fusion ms per frame)})."""
    from swarm.config import load_mission  # noqa: PLC0415

    mission = load_mission(config)
    rig = mission.rig_for(mission.robot_ids[0])
    sensor = mission.sensor_model_of(rig)
    site = Grid((0.0, 0.0, 0.0), 0.1, tuple(int(round(s / 0.1)) for s in ray_streams.SITE))
    steps = ray_streams.street_frames(rig, robots)
    maps = {bits: BlockMap.for_grid(site, sensor, block_bits=bits) for bits in block_bits}
    seconds = dict.fromkeys(block_bits, 0.0)
    marks = set(np.linspace(0, len(steps), points + 1).astype(int)[1:])
    rows, frames = [], 0
    for s, batch in enumerate(steps, 1):
        for bits, bmap in maps.items():
            t0 = time.perf_counter()
            for origin, pts in batch:
                bmap.integrate(origin, pts)
            seconds[bits] += time.perf_counter() - t0
        frames += len(batch)
        if s in marks:
            known = maps[block_bits[0]].known_voxels()
            sizes = {
                bits: (m.n_blocks, m.nbytes() / MB, 1e3 * seconds[bits] / frames) for bits, m in maps.items()
            }
            rows.append((frames, known * site.voxel**3, sizes))
            if progress is not None:
                progress(f"site: {frames} frames")
    return site, rows


# -- tables --------------------------------------------------------------------------------
def _load() -> str:
    one, five, fifteen = os.getloadavg()
    return f"load average {one:.2f} {five:.2f} {fifteen:.2f}"


def format_streams(figures: list[StreamFigures], repeat: int) -> str:
    rows = [
        "| stream | model | rays | grid voxels | max rel. diff bounded / unbounded | dense s | "
        "its grid's allocation s | bounded s | unbounded s | bounded / dense | dense +H s | bounded +H s "
        "| bounded / dense +H | dense MB | block map MB bounded / unbounded (blocks) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for f in figures:
        w, c = f.seconds, f.cpu_seconds
        rows.append(
            f"| {f.name} | {f.model} | {f.rays:,} | {f.voxels:,} | {f.bounded_difference:.1e} / "
            f"{f.unbounded_difference:.1e} | {w['dense']:.3f} ({c['dense']:.3f}) | {w['dense grid']:.4f} "
            f"| {w['bounded']:.3f} "
            f"({c['bounded']:.3f}) | {w['unbounded']:.3f} ({c['unbounded']:.3f}) | "
            f"{w['bounded'] / w['dense']:.3f} ({c['bounded'] / c['dense']:.3f}) | {w['dense +H']:.3f} | "
            f"{w['bounded +H']:.3f} | {w['bounded +H'] / w['dense +H']:.3f} "
            f"({c['bounded +H'] / c['dense +H']:.3f}) | "
            f"{f.voxels * DENSE_BYTES_PER_VOXEL / MB:.1f} | {f.bounded_bytes / MB:.1f} / "
            f"{f.sparse_bytes / MB:.1f} ({f.bounded_blocks:,} / {f.blocks:,}) |"
        )
    rows.append(
        f"\nTimes: the whole stream, best of {repeat} rounds after an untimed one, wall s (CPU s); "
        "the maps alternate within a round; the dense map's grid is allocated before its clock "
        "starts (its allocation time is printed beside it), the block map allocates its blocks as "
        "the stream reaches them, within its time. bounded: the block map bounded by the stream's grid "
        "(the mission's workspace; for EuRoC and the scan a grid holding every ray); unbounded: no "
        "bounds. +H: with the per-voxel entropy cache kept up to date. Max rel. diff: over lam and "
        "eta of every voxel, bounded against the dense map on the grid, unbounded against a dense "
        "grid holding every ray. Memory: 12 bytes a voxel (lam, eta, entropy) for the dense grid; "
        "the block maps' allocated blocks (16^3 voxels) with their entropy cache; unbounded, the "
        "blocks beyond the grid that rays reach (below the floor: the voxels behind its hits) count too."
    )
    return "\n".join(rows)


def format_site(site: Grid, rows, robots: int) -> str:
    dense = site.size * DENSE_BYTES_PER_VOXEL / MB
    volume = site.size * site.voxel**3
    sizes = list(rows[0][2])
    head = " | ".join(
        f"{1 << b}^3: blocks, MB, MB per 1,000 m^3, share of dense, ms per frame" for b in sizes
    )
    out = [
        f"Site {site.shape[0] * site.voxel:g} m x {site.shape[1] * site.voxel:g} m x "
        f"{site.shape[2] * site.voxel:g} m at {site.voxel:g} m: {site.size:,} voxels; dense "
        f"{dense:,.0f} MB (lam, eta, entropy), {site.size * 8 / MB:,.0f} MB without the entropy cache.",
        f"{robots} robots on the campus streets, one range frame per metre each, the site as bounds:",
        "",
        f"| frames | explored m^3 (known voxels) | share of the site | {head} |",
        "|---|---|---|" + "---|" * len(sizes),
    ]
    for frames, explored, by_bits in rows:
        cells = " | ".join(
            f"{n:,}, {mb:,.1f}, {1000 * mb / max(explored, 1e-9):.1f}, {mb / dense:.1%}, {ms:.2f}"
            for n, mb, ms in by_bits.values()
        )
        out.append(f"| {frames:,} | {explored:,.0f} | {explored / volume:.1%} | {cells} |")
    out.append(
        "\nBlock map MB: allocated blocks with their entropy cache (12 bytes a voxel) and index. A block "
        "is allocated whole when a ray reaches one of its voxels: explored m^3 counts the voxels "
        "with information beyond the prior."
    )
    return "\n".join(out)


def run(
    config: Path, scan: Path | None, euroc: Path | None, repeat: int = 3, site: bool = True, robots: int = 16,
    block_bits=(4, 3), progress=None,
) -> str:  # fmt: skip
    """Every table of the benchmark, as text."""
    parts = [f"before: {_load()}"]
    figures = run_streams(config, scan, euroc, repeat, progress)
    parts += [format_streams(figures, repeat), f"after the streams: {_load()}"]
    if site:
        grid, rows = site_growth(config, robots, block_bits=tuple(block_bits), progress=progress)
        parts += [format_site(grid, rows, robots), f"after the site: {_load()}"]
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e3
    parts.append(f"peak resident memory of this process: {peak:,.0f} MB")
    return "\n\n".join(parts)
