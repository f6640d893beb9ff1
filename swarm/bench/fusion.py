"""``swarm bench fusion``: our fusion against OctoMap's insertPointCloud on the same real clouds.

Clouds: the real OctoMap laser scan at 5 m max range and over its whole beam, and a dense
stereo cloud from one real EuRoC frame through the project's stereo pipeline
(``robot_agent.stereo``). OctoMap (octomap-python, the ``bench`` extra) runs
single-threaded (OMP_NUM_THREADS=1) at the same resolution and max range into a fresh
``OcTree`` per insert; ours fuses the batch and applies its delta to a map. The two are
timed alternately in the same loop (best of ``repeat``), so a shared machine slows both.
One ray is one measurement on both sides, then ``discretize`` is set on both sides.
Surface precision and recall (``swarm.mission.surface_quality``) judge both maps against
the cloud's own points within max range.
"""

from __future__ import annotations

import os
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from swarm.map.coverage_map import CoverageMap
from swarm.map.entropy import expected_coverage
from swarm.map.fusion import batch_information
from swarm.map.grid import Grid
from swarm.map.sensor_model import SensorModel
from swarm.mission.surface_quality import SurfaceQuality, surface_quality

UNLIMITED = 1000.0  # a max range beyond any scan point: the whole beam


@dataclass
class FusionFigures:
    cloud: str
    max_range: float
    discretize: bool
    rays: int
    seconds: float
    voxel_updates: int
    surface: SurfaceQuality
    cpu_seconds: float
    octomap_seconds: float | None = None
    octomap_cpu_seconds: float | None = None
    octomap_surface: SurfaceQuality | None = None

    @property
    def ratio(self) -> float | None:
        """OctoMap's wall time over ours: > 1 means we are faster."""
        return None if self.octomap_seconds is None else self.octomap_seconds / self.seconds

    @property
    def cpu_ratio(self) -> float | None:
        """OctoMap's CPU time over ours (steadier than wall time on a shared machine)."""
        return None if self.octomap_cpu_seconds is None else self.octomap_cpu_seconds / self.cpu_seconds


def euroc_stereo_cloud(root: Path, frame: int = 0, max_depth: float = 20.0) -> np.ndarray:
    """Points (N, 3) of one EuRoC stereo pair in the rectified left camera (x right, y down, z ahead).

    ``root`` holds ``mav0/cam0``, ``mav0/cam1`` (ASL layout: ``sensor.yaml`` with intrinsics,
    radial-tangential distortion and ``T_BS``; ``data.csv`` and ``data/*.png``). The pair is
    rectified from the two ``T_BS`` and matched with ``StereoMatcher`` (SGBM, mode ``sgbm``,
    no texture filter).
    """
    import cv2  # noqa: PLC0415

    from robot_agent.calibration import calibration_from_dict  # noqa: PLC0415
    from robot_agent.stereo import StereoMatcher  # noqa: PLC0415

    cams = []
    for name in ("cam0", "cam1"):
        text = (root / "mav0" / name / "sensor.yaml").read_text()
        cams.append(yaml.safe_load(text.split("\n", 1)[1] if text.startswith("%YAML") else text))
    k = [
        [[c["intrinsics"][0], 0, c["intrinsics"][2]], [0, c["intrinsics"][1], c["intrinsics"][3]], [0, 0, 1]]
        for c in cams
    ]
    t_bs = [np.asarray(c["T_BS"]["data"], dtype=np.float64).reshape(4, 4) for c in cams]
    t_10 = np.linalg.inv(t_bs[1]) @ t_bs[0]  # left-camera coordinates to right-camera coordinates
    calib = calibration_from_dict(
        {
            "K1": k[0],
            "D1": cams[0]["distortion_coefficients"],
            "K2": k[1],
            "D2": cams[1]["distortion_coefficients"],
            "R": t_10[:3, :3].tolist(),
            "T": t_10[:3, 3].tolist(),
            "image_size": cams[0]["resolution"],
        },
        source=str(root),
    )
    names = sorted((root / "mav0" / "cam0" / "data").glob("*.png"))
    left = cv2.imread(str(names[frame]), cv2.IMREAD_GRAYSCALE)
    right = cv2.imread(str(root / "mav0" / "cam1" / "data" / names[frame].name), cv2.IMREAD_GRAYSCALE)
    # The texture filter off: every pixel SGBM matches is a point (a dense cloud, ~300k points).
    matcher = StereoMatcher.for_rig(calib, min_depth=0.5, max_depth=max_depth, mode="sgbm", min_texture=0.0)
    depth = matcher.depth(left, right, calib)
    v, u = np.nonzero(np.isfinite(depth) & (depth > 0))
    z = depth[v, u].astype(np.float64)
    return np.column_stack([(u - calib.cx) * z / calib.fx, (v - calib.cy) * z / calib.fy, z])


def _octomap():
    os.environ["OMP_NUM_THREADS"] = "1"
    try:
        import octomap  # noqa: PLC0415 (optional peer, imported only for the benchmark)
    except ImportError:
        return None
    return octomap


def occupied_centres(cmap: CoverageMap, idx: np.ndarray) -> np.ndarray:
    """Centres (M, 3) of the voxels among ``idx`` whose expected coverage E[C] exceeds 0.5."""
    cov = expected_coverage(cmap.mean(idx), cmap.sigma(idx))
    return cmap.grid.centre(cmap.grid.unflat(idx[cov > 0.5]))


def measure(
    name: str, points: np.ndarray, max_range: float, voxel: float, repeat: int, discretize: bool
) -> FusionFigures:
    """Best-of-``repeat`` time of one batch through our fusion and through OctoMap, alternately."""
    origin = np.zeros(3)
    sensor = SensorModel(max_range=max_range, discretize=discretize)
    dist = np.linalg.norm(points, axis=1)
    ends = points * np.minimum(1.0, max_range / dist)[:, None]
    grid = Grid.from_bounds(np.minimum(ends.min(0), 0) - voxel, np.maximum(ends.max(0), 0) + 2 * voxel, voxel)
    truth = points[dist <= max_range]
    cmap = CoverageMap(grid, sensor)
    octomap = _octomap()
    octo_range = -1.0 if max_range >= UNLIMITED else max_range
    ours = octo = ours_cpu = octo_cpu = float("inf")
    tree = None
    for _ in range(repeat):
        work = CoverageMap(grid, sensor)
        t0, c0 = time.perf_counter(), time.process_time()
        result = batch_information(grid, sensor, origin, points)
        work.apply(result.delta)
        ours, ours_cpu = min(ours, time.perf_counter() - t0), min(ours_cpu, time.process_time() - c0)
        if octomap is not None:
            t0, c0 = time.perf_counter(), time.process_time()
            tree = octomap.OcTree(voxel)
            tree.insertPointCloud(points, origin, maxrange=octo_range, discretize=discretize)
            octo, octo_cpu = min(octo, time.perf_counter() - t0), min(octo_cpu, time.process_time() - c0)
    cmap.apply(result.delta)
    figures = FusionFigures(
        name,
        max_range,
        discretize,
        result.rays,
        ours,
        result.voxel_updates,
        surface_quality(occupied_centres(cmap, result.delta.idx.astype(np.int64)), truth, voxel),
        ours_cpu,
    )
    if tree is not None:
        figures.octomap_seconds = octo
        figures.octomap_cpu_seconds = octo_cpu
        figures.octomap_surface = surface_quality(
            np.asarray(tree.extractPointCloud()[0]).reshape(-1, 3), truth, voxel
        )
    return figures


def clouds(scan: Path | None, euroc: Path | None) -> list[tuple[str, np.ndarray, float]]:
    """(name, points, max range) of each benchmark cloud that is found."""
    from swarm.formats.point_cloud_file import read_point_cloud  # noqa: PLC0415

    out = []
    if scan is not None and scan.exists():
        points = read_point_cloud(scan)
        points = points[np.all(np.isfinite(points), axis=1)]
        out += [(f"{scan.name}", points, 5.0), (f"{scan.name}", points, UNLIMITED)]
    if euroc is not None and (euroc / "mav0").exists():
        out.append(("EuRoC V1_01 frame 0 stereo", euroc_stereo_cloud(euroc), UNLIMITED))
    return out


def run(
    scan: Path | None, euroc: Path | None, voxel: float = 0.1, repeat: int = 3, progress=None
) -> list[FusionFigures]:
    """Figures for each cloud, one measurement per ray and then discretized, on both sides."""
    figures = []
    for name, points, max_range in clouds(scan, euroc):
        for discretize in (False, True):
            if progress is not None:
                mr = "whole beam" if max_range >= UNLIMITED else f"{max_range:g} m"
                progress(f"{name}, {mr}, discretize {'on' if discretize else 'off'}: {len(points):,} points")
            figures.append(measure(name, points, max_range, voxel, repeat, discretize))
    return figures


def _pr(q: SurfaceQuality | None) -> str:
    return "n/a" if q is None else f"{q.precision:.2f} / {q.recall:.2f}"


def format_table(figures: list[FusionFigures]) -> str:
    rows = [
        "| cloud | max range | discretize | rays | ours s (CPU s) | ours rays/s | ours voxel updates/s "
        "| OctoMap s (CPU s) | OctoMap rays/s | ours / OctoMap speed (CPU) | ours P / R | OctoMap P / R |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for f in figures:
        mr = "whole beam" if f.max_range >= UNLIMITED else f"{f.max_range:g} m"
        none = f.octomap_seconds is None
        octo_s = (
            "n/a (octomap-python not installed)"
            if none
            else f"{f.octomap_seconds:.4f} ({f.octomap_cpu_seconds:.4f})"
        )
        octo_r = "n/a" if none else f"{f.rays / f.octomap_seconds:,.0f}"
        ratio = "n/a" if none else f"{f.ratio:.2f}x ({f.cpu_ratio:.2f}x)"
        rows.append(
            f"| {f.cloud} | {mr} | {'on' if f.discretize else 'off'} | {f.rays:,} "
            f"| {f.seconds:.4f} ({f.cpu_seconds:.4f}) "
            f"| {f.rays / f.seconds:,.0f} | {f.voxel_updates / f.seconds:,.0f} | {octo_s} | {octo_r} "
            f"| {ratio} | {_pr(f.surface)} | {_pr(f.octomap_surface)} |"
        )
    rows.append(
        "\nP / R: surface precision / recall (share of occupied voxels, E[C] > 0.5, within 1.5 voxel "
        "edges of a cloud point within max range; share of those points within 1.5 voxel edges "
        "of an occupied voxel's centre). Times: best of the repeats, ours and OctoMap alternating; "
        "CPU s is the process's CPU time, which a shared machine disturbs less than wall time."
    )
    return "\n".join(rows)
