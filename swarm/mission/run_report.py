"""The run folder of docs/design.md section 6: ``metrics.json``, ``map.npz``, ``config.yaml`` and plots.

A finished mission is described by a :class:`RunRecord`; :func:`compute_metrics` turns it
into the ``metrics.json`` dictionary (measures of :mod:`swarm.mission.evaluation`) and
:func:`write_run_folder` writes the folder::

    record = RunRecord(config="configs/lab.yaml", robots=["r1"], ...)
    metrics = compute_metrics(record, cmap, true_coverage, observed_by)
    write_run_folder("runs/lab-0", metrics, cmap, mission.to_yaml(), record)

``entropy.png`` shows H(t) over sim time with H_th dashed and the mission time marked;
``top_view.png`` shows, for each (x, y) column, the largest expected coverage among the
*known* voxels of the robot's height band (grey, white = free, black = occupied); columns
with no known voxel in the band are light blue. Floor-plan obstacles are outlined in red
and each robot's trajectory is drawn in its own colour (circle = start, square = end).
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from swarm.formats.floor_plan import FloorPlan
from swarm.formats.map_file import save_map
from swarm.map.coverage_map import CoverageMap, prior_entropy_bits
from swarm.map.entropy import expected_coverage
from swarm.map.entropy_table import default_table
from swarm.mission import evaluation, surface_quality

#: Keys that ``metrics.json`` always has (docs/design.md section 6, plus our additions).
METRIC_KEYS = (
    "config",
    "robots",
    "strategy",
    "coordination",
    "seed",
    "reached_threshold",
    "mission_time_s",
    "sim_time_s",
    "wall_time_s",
    "initial_entropy_bits",
    "final_entropy_bits",
    "threshold_bits",
    "occupancy_f1",
    "occupancy_f1_observed",
    "coverage_mae",
    "coverage_mae_observed",
    "surface_accuracy",
    "surface_completeness",
    "explored_fraction",
    "distance_m",
    "bytes_shared",
    "overlap_fraction",
    "entropy_split",
    "entropy_curve",
)
#: Colour of unknown columns in the top view.
UNKNOWN_COLOUR = "#a9d6f5"
_OBSTACLE_COLOUR = "tab:red"


@dataclass
class RunRecord:
    """What a mission produced, as collected by whoever ran it.

    ``entropy_curve``: [[t, H], ...] (sim seconds, bits), one sample per batch, ending with
    the final map. ``trajectories``: robot id -> [[t, x, y], ...]. ``workspace``: the
    mission's box (lo, hi), used to leave out grid voxels outside it; ``floor_plan`` is
    outlined in the top view; ``height_band`` (z from, z to, metres) is the band of the top
    view. ``cmap``, ``true_coverage`` and ``observed_by`` (robot id -> flat bool mask of the
    voxels its own measurements touched) are used when not passed to :func:`compute_metrics`.
    """

    config: str
    robots: list[str]
    strategy: str
    coordination: str
    seed: int
    threshold_bits: float
    initial_entropy_bits: float
    entropy_curve: list[list[float]] = field(default_factory=list)
    trajectories: dict[str, list[list[float]]] = field(default_factory=dict)
    bytes_shared: dict[str, int] = field(default_factory=dict)
    sim_time_s: float = 0.0
    wall_time_s: float = 0.0
    workspace: tuple[Sequence[float], Sequence[float]] | None = None
    floor_plan: FloorPlan | None = None
    height_band: tuple[float, float] = (0.1, 0.5)
    cmap: CoverageMap | None = None
    true_coverage: np.ndarray | None = None
    observed_by: dict[str, np.ndarray] | None = None


# -- metrics ---------------------------------------------------------------------------------


def compute_metrics(
    record: RunRecord,
    cmap: CoverageMap | None = None,
    true_coverage: np.ndarray | None = None,
    observed_by: dict[str, np.ndarray] | None = None,
    sensor_observable: np.ndarray | None = None,
) -> dict[str, Any]:
    """The ``metrics.json`` dictionary of a run (keys: :data:`METRIC_KEYS`, plus ``occupancy``).

    Arguments left as None are taken from ``record``. Without ground truth every voxel at
    or above the floor counts as observable and the map-quality measures are None; without
    ``observed_by`` the overlap is None. ``reached_threshold`` is true when some sample of
    the entropy curve is at or below H_th, and ``mission_time_s`` is the first such time.

    ``sensor_observable``: the voxels some sensor of the mission could ever observe
    (:func:`swarm.mission.threshold.observable_mask_of`). When given, ``explored_fraction``,
    ``entropy_split`` and ``observable_voxels`` count those, and surface completeness
    counts only true surface whose air in front of it is among them; occupancy F1 and
    coverage MAE keep the geometric mask (:func:`evaluation.observable_mask`) either way.
    Surface accuracy and completeness (:mod:`swarm.mission.surface_quality`, tolerance 1.5
    voxel edges) need ``record.floor_plan``; None without it.
    """
    cmap = cmap if cmap is not None else record.cmap
    if cmap is None:
        raise ValueError("compute_metrics needs the final coverage map")
    true_coverage = true_coverage if true_coverage is not None else record.true_coverage
    observed_by = observed_by if observed_by is not None else record.observed_by
    grid = cmap.grid

    mu, sigma = cmap.mean(), cmap.sigma()
    exp_cov = expected_coverage(mu, sigma)
    entropy = default_table()(mu, sigma)
    known = cmap.known_mask()
    cov_for_mask = true_coverage if true_coverage is not None else np.zeros(grid.shape, np.float32)
    observable = evaluation.observable_mask(cov_for_mask, grid, record.workspace).ravel()
    prior_bits = prior_entropy_bits(grid, cmap.sensor) / grid.size  # one voxel's, as the threshold takes it

    quality: dict[str, Any] = {"observable": None, "observed": None}
    mae = mae_observed = None
    if true_coverage is not None:
        truth = np.ravel(true_coverage)
        quality = {
            "observable": evaluation.occupancy_f1(exp_cov, truth, observable),
            "observed": evaluation.occupancy_f1(exp_cov, truth, observable & known),
        }
        mae = evaluation.coverage_mae(exp_cov, truth, observable)
        mae_observed = evaluation.coverage_mae(exp_cov, truth, observable & known)

    if sensor_observable is not None:
        observable = np.ravel(sensor_observable).astype(bool)
    in_box = evaluation.observable_mask(np.zeros(grid.shape, np.float32), grid, record.workspace).ravel()
    surface = _surface_quality(record, grid, exp_cov, in_box, sensor_observable)

    curve = [[float(t), float(h)] for t, h in record.entropy_curve]
    t_mission = evaluation.mission_time(curve, record.threshold_bits)
    robots = list(record.robots) + [r for r in record.trajectories if r not in record.robots]
    metrics = {
        "config": str(record.config),
        "robots": [str(r) for r in record.robots],
        "strategy": record.strategy,
        "coordination": record.coordination,
        "seed": int(record.seed),
        "reached_threshold": t_mission is not None,
        "mission_time_s": t_mission,
        "sim_time_s": float(record.sim_time_s),
        "wall_time_s": float(record.wall_time_s),
        "initial_entropy_bits": float(record.initial_entropy_bits),
        "final_entropy_bits": float(np.sum(entropy, dtype=np.float64)),
        "threshold_bits": float(record.threshold_bits),
        "occupancy_f1": _get(quality["observable"], "f1"),
        "occupancy_f1_observed": _get(quality["observed"], "f1"),
        "occupancy": quality,
        "coverage_mae": _finite(mae),
        "coverage_mae_observed": _finite(mae_observed),
        "surface_accuracy": None if surface is None else surface["accuracy"],
        "surface_completeness": None if surface is None else surface["completeness"],
        "surface": surface,
        "explored_fraction": evaluation.explored_fraction(known, observable),
        "voxels": int(grid.size),
        "observable_voxels": int(np.count_nonzero(observable)),
        "known_voxels": int(np.count_nonzero(known)),
        "distance_m": {r: evaluation.path_length(record.trajectories.get(r, [])) for r in robots},
        "bytes_shared": {str(r): int(b) for r, b in record.bytes_shared.items()},
        "overlap_fraction": None if observed_by is None else evaluation.overlap_fraction(observed_by),
        "entropy_split": evaluation.entropy_split(entropy, observable, prior_bits),
        "entropy_left": _entropy_left(entropy, observable, known, grid),
        "entropy_curve": curve,
    }
    return metrics


def _entropy_left(entropy: np.ndarray, observable: np.ndarray, known: np.ndarray, grid) -> dict[str, Any]:
    """Where the observable entropy left at the end lies: in unknown or in known voxels, and
    per z layer (bits, index 0 = the floor layer): what a robot that stopped left behind."""
    h = np.ravel(entropy).astype(np.float64) * np.ravel(observable)
    unknown = ~np.ravel(known)
    return {
        "observable_bits": float(h.sum()),
        "unknown_bits": float(h[unknown].sum()),
        "known_bits": float(h[~unknown].sum()),
        "bits_by_layer": [float(v) for v in h.reshape(grid.shape).sum(axis=(0, 1))],
    }


def _surface_quality(
    record: RunRecord,
    grid,
    exp_cov: np.ndarray,
    in_workspace: np.ndarray,
    sensor_observable: np.ndarray | None,
) -> dict[str, Any] | None:
    """Surface accuracy and completeness of the map against the record's floor plan: accuracy
    against the whole true surface, completeness over the part some sensor can observe."""
    plan = record.floor_plan
    if plan is None:
        return None
    lo, hi = grid.lo, grid.hi
    if record.workspace is not None:
        lo, hi = np.maximum(lo, record.workspace[0]), np.minimum(hi, record.workspace[1])
    points, air = surface_quality.plan_surface_points(plan, lo, hi, 0.5 * grid.voxel)
    if sensor_observable is not None and len(points):
        flat = surface_quality.voxel_of(air, grid.lo, grid.voxel, grid.shape)
        seen = np.ravel(sensor_observable).astype(bool)
        points = points[(flat >= 0) & seen[np.maximum(flat, 0)]]
    occupied = np.flatnonzero((np.ravel(exp_cov) > 0.5) & np.ravel(in_workspace))
    centres = grid.centres().reshape(-1, 3)[occupied]
    tolerance = surface_quality.TOLERANCE_EDGES * grid.voxel
    out = surface_quality.plan_accuracy_completeness(plan, centres, points, tolerance)
    out["tolerance_m"] = tolerance
    return out


def _get(d: dict | None, key: str) -> Any:
    return None if d is None else d[key]


def _finite(x: float | None) -> float | None:
    return None if x is None or not math.isfinite(x) else float(x)


# -- the run folder ---------------------------------------------------------------------------


def write_run_folder(
    out_dir: str | Path,
    metrics: dict[str, Any],
    cmap: CoverageMap,
    mission_yaml_text: str,
    record: RunRecord,
) -> None:
    """Write ``metrics.json``, ``map.npz``, ``config.yaml``, ``trajectories.json`` (robot id ->
    [[t s, x m, y m], ...], the simulator's true poses), ``entropy.png``, ``top_view.png``,
    ``map_3d.png`` and the slice stack ``slices/`` (:mod:`swarm.mission.map_pictures`)."""
    from swarm.mission.map_pictures import plot_map_3d, plot_slices

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "metrics.json").write_text(json.dumps(_jsonable(metrics), indent=2) + "\n", encoding="utf-8")
    save_map(out / "map.npz", cmap)
    (out / "config.yaml").write_text(mission_yaml_text, encoding="utf-8")
    trajectories = json.dumps(_jsonable(record.trajectories))
    (out / "trajectories.json").write_text(trajectories + "\n", encoding="utf-8")
    plot_entropy(out / "entropy.png", metrics)
    plot_top_view(out / "top_view.png", cmap, record)
    plot_map_3d(out / "map_3d.png", cmap, record.trajectories)
    plot_slices(out / "slices", cmap)


def _jsonable(value: Any) -> Any:
    """Plain JSON types: numpy scalars and arrays converted, NaN and inf as null."""
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, list | tuple | np.ndarray):
        return [_jsonable(v) for v in value]
    if isinstance(value, bool | np.bool_):
        return bool(value)
    if isinstance(value, int | np.integer):
        return int(value)
    if isinstance(value, float | np.floating):
        return float(value) if math.isfinite(value) else None
    return value


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


def plot_top_view(path: str | Path, cmap: CoverageMap, record: RunRecord) -> None:
    """Top view of the map (see the module docstring) with obstacles and trajectories."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.collections import PolyCollection
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    grid = cmap.grid
    image, layers = top_view_image(cmap, record.height_band)
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
    plan = record.floor_plan
    if plan is not None and plan.count:
        outlines = PolyCollection(plan.quads, facecolors="none", edgecolors=_OBSTACLE_COLOUR, linewidths=0.7)
        outlines.set_alpha(0.85)
        ax.add_collection(outlines)
        handles.append(Line2D([], [], color=_OBSTACLE_COLOUR, lw=0.7, label="floor plan"))
    palette = [c for i, c in enumerate(plt.get_cmap("tab10").colors) if i != 3]  # red is the plan's
    for n, (rid, traj) in enumerate(record.trajectories.items()):
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
