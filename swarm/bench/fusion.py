"""``swarm bench fusion``: our fusion against OctoMap's insertPointCloud on the same clouds.

OctoMap (octomap-python, the ``bench`` extra) is run single-threaded (OMP_NUM_THREADS=1)
at the same resolution and max range. Note the work differs: OctoMap updates each voxel
at most once per scan, while the paper's model fuses every (ray, voxel) measurement.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from swarm.bench import best_seconds
from swarm.map.fusion import batch_information
from swarm.map.grid import Grid
from swarm.map.sensor_model import SensorModel

UNLIMITED = 1000.0  # a max range beyond any scan point: the whole beam


@dataclass
class FusionFigures:
    cloud: str
    max_range: float
    rays: int
    seconds: float
    voxel_updates: int
    octomap_seconds: float | None

    @property
    def rays_per_s(self) -> float:
        return self.rays / self.seconds

    @property
    def octomap_rays_per_s(self) -> float | None:
        return None if self.octomap_seconds is None else self.rays / self.octomap_seconds


def synthetic_frame(width: int = 160, height: int = 120, hfov_deg: float = 60.0) -> np.ndarray:
    """Hit points of a level camera at the origin looking along +x into a 4 x 6 x 2.4 m room."""
    f = (width / 2) / np.tan(np.radians(hfov_deg) / 2)
    u, v = np.meshgrid(np.arange(width) + 0.5 - width / 2, np.arange(height) + 0.5 - height / 2)
    rays = np.stack([np.full(u.shape, f), -u, -v], axis=-1).reshape(-1, 3)
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    # room walls x = 4, y = +-3, floor z = -0.4, ceiling z = 2.0; the first plane along each ray
    with np.errstate(divide="ignore"):
        t_x = np.where(rays[:, 0] > 0, 4.0 / rays[:, 0], np.inf)
        t_y = np.where(rays[:, 1] != 0, 3.0 / np.abs(rays[:, 1]), np.inf)
        t_z = np.where(rays[:, 2] < 0, -0.4 / rays[:, 2], np.where(rays[:, 2] > 0, 2.0 / rays[:, 2], np.inf))
    t = np.minimum(np.minimum(t_x, t_y), t_z)
    return rays * t[:, None]


def _octomap():
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    try:
        import octomap  # noqa: PLC0415 (optional peer, imported only for the benchmark)
    except ImportError:
        return None
    return octomap


def measure(name: str, points: np.ndarray, max_range: float, voxel: float, repeat: int) -> FusionFigures:
    """Best-of-``repeat`` time of one batch through our fusion and through OctoMap."""
    origin = np.zeros(3)
    sensor = SensorModel(max_range=max_range)
    dist = np.linalg.norm(points, axis=1, keepdims=True)
    ends = points * np.minimum(1.0, max_range / dist)
    grid = Grid.from_bounds(np.minimum(ends.min(0), 0) - voxel, np.maximum(ends.max(0), 0) + 2 * voxel, voxel)
    result = batch_information(grid, sensor, origin, points)
    seconds = best_seconds(lambda: batch_information(grid, sensor, origin, points), repeat)

    octo_seconds = None
    octomap = _octomap()
    if octomap is not None:
        octo_range = -1.0 if max_range >= UNLIMITED else max_range

        def insert():
            octomap.OcTree(voxel).insertPointCloud(points, origin, maxrange=octo_range)

        octo_seconds = best_seconds(insert, repeat)
    return FusionFigures(name, max_range, result.rays, seconds, result.voxel_updates, octo_seconds)


def run(scan: Path | None, voxel: float = 0.1, repeat: int = 3) -> list[FusionFigures]:
    """Figures for the real scan (if found) and a synthetic 160x120 frame, at 5 m and unlimited range."""
    from swarm.formats.point_cloud_file import read_point_cloud  # noqa: PLC0415

    clouds = []
    if scan is not None and scan.exists():
        clouds.append((scan.name, read_point_cloud(scan)))
    clouds.append(("synthetic 160x120 frame", synthetic_frame()))
    figures = []
    for name, points in clouds:
        points = points[np.all(np.isfinite(points), axis=1)]
        for max_range in (5.0, UNLIMITED):
            figures.append(measure(name, points, max_range, voxel, repeat))
    return figures


def format_table(figures: list[FusionFigures]) -> str:
    rows = [
        "| cloud | max range | rays | ours s | ours rays/s | ours voxel updates/s "
        "| OctoMap s | OctoMap rays/s | ours / OctoMap |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for f in figures:
        mr = "unlimited" if f.max_range >= UNLIMITED else f"{f.max_range:g} m"
        octo = f.octomap_rays_per_s
        ratio = "n/a (octomap-python not installed)" if octo is None else f"{f.rays_per_s / octo:.2f}x"
        octo_s = "n/a" if f.octomap_seconds is None else f"{f.octomap_seconds:.4f}"
        octo_r = "n/a" if octo is None else f"{octo:,.0f}"
        rows.append(
            f"| {f.cloud} | {mr} | {f.rays:,} | {f.seconds:.4f} | {f.rays_per_s:,.0f} "
            f"| {f.voxel_updates / f.seconds:,.0f} | {octo_s} | {octo_r} | {ratio} |"
        )
    return "\n".join(rows)
