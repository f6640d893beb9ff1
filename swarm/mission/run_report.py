"""The run folder of docs/design.md section 6: ``metrics.json``, ``map.npz``, ``config.yaml`` and plots.

A finished mission is described by a :class:`RunRecord`; :func:`compute_metrics` turns it
into the ``metrics.json`` dictionary (measures of :mod:`swarm.mission.evaluation`) and
:func:`write_run_folder` writes the folder::

    record = RunRecord(config="configs/lab.yaml", robots=["r1"], ...)
    metrics = compute_metrics(record, cmap, true_coverage, observed_by)
    write_run_folder("runs/lab-0", metrics, cmap, mission.to_yaml(), record)

``entropy.png`` is drawn by :mod:`swarm.mission.run_plots`; ``top_view.png``, ``map_3d.png``
and ``slices/``, the picture set of every kind of run, by :mod:`swarm.mission.map_pictures`.
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
from swarm.mission.run_plots import plot_entropy

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
    ``map_3d.png`` and the slice stack ``slices/`` (:func:`swarm.mission.map_pictures.write_map_pictures`)."""
    from swarm.mission.map_pictures import write_map_pictures
    from swarm.mission.picture_style import paths_from_trajectories

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    (out / "metrics.json").write_text(json.dumps(_jsonable(metrics), indent=2) + "\n", encoding="utf-8")
    save_map(out / "map.npz", cmap)
    (out / "config.yaml").write_text(mission_yaml_text, encoding="utf-8")
    trajectories = json.dumps(_jsonable(record.trajectories))
    (out / "trajectories.json").write_text(trajectories + "\n", encoding="utf-8")
    plot_entropy(out / "entropy.png", metrics)
    paths = paths_from_trajectories(record.trajectories)
    write_map_pictures(out, cmap, paths, record.floor_plan, record.height_band)


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
