"""Run folder: metrics of a run record and the files of docs/design.md section 6."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from swarm.formats.floor_plan import FloorPlan, rectangle
from swarm.formats.map_file import REQUIRED_KEYS
from swarm.map.coverage_map import CoverageMap
from swarm.map.grid import Grid
from swarm.mission.map_pictures import top_view_image
from swarm.mission.run_report import METRIC_KEYS, RunRecord, compute_metrics, write_run_folder

GRID = Grid((0.0, 0.0, 0.0), 0.1, (20, 10, 8))  # 2 m x 1 m x 0.8 m


def _truth() -> np.ndarray:
    """A block x in [1.5, 2.0], full width, 0.6 m high."""
    cov = np.zeros(GRID.shape, np.float32)
    cov[15:, :, :6] = 1.0
    return cov


def _plan() -> FloorPlan:
    return FloorPlan([rectangle((1.75, 0.5), (0.5, 1.0))], [0.6], (0, 0), (2, 1))


def _fused_map() -> tuple[CoverageMap, dict[str, np.ndarray]]:
    """Two robots look at the block's face x = 1.5 from the left half of the room."""
    cmap = CoverageMap(GRID)
    y, z = np.meshgrid(np.linspace(0.02, 0.98, 25), np.linspace(0.02, 0.58, 15))
    face = np.stack([np.full(y.size, 1.5), y.ravel(), z.ravel()], axis=1)
    observed = {}
    for rid, origin in (("r1", (0.3, 0.3, 0.3)), ("r2", (0.4, 0.7, 0.3))):
        observed[rid] = np.zeros(GRID.size, bool)
        for _ in range(3):
            observed[rid][cmap.integrate(np.array(origin), face).delta.idx] = True
    return cmap, observed


def _record(**kw) -> RunRecord:
    args = dict(
        config="configs/box.yaml",
        robots=["r1", "r2"],
        strategy="entropy_gradient",
        coordination="coordinator",
        seed=3,
        threshold_bits=8000.0,
        initial_entropy_bits=1120.0 * 7.0,
        entropy_curve=[[0.0, 7840.0], [0.5, 7000.0], [1.0, 6000.0], [1.5, 5000.0]],
        trajectories={"r1": [[0.0, 0.3, 0.3], [0.5, 0.6, 0.7], [1.0, 0.6, 0.2]], "r2": [[0.0, 0.4, 0.7]]},
        bytes_shared={"r1": 1234, "r2": 56},
        sim_time_s=1.5,
        wall_time_s=0.25,
        floor_plan=_plan(),
        height_band=(0.1, 0.5),
    )
    args.update(kw)
    return RunRecord(**args)


def test_distance_is_the_sum_of_segment_lengths():
    cmap, _ = _fused_map()
    m = compute_metrics(_record(), cmap, _truth())
    assert m["distance_m"]["r1"] == pytest.approx(0.5 + 0.5)  # (0.3, 0.4) then (0, -0.5)
    assert m["distance_m"]["r2"] == 0.0


def test_perfect_map_scores_perfectly():
    truth = _truth()
    lam = np.full(GRID.size, 1e8, np.float32)  # sigma = 1e-4, so E[C] is within 1e-4 of mu
    cmap = CoverageMap(GRID, lam=lam, eta=lam * truth.ravel())
    m = compute_metrics(_record(), cmap, truth)
    assert m["occupancy_f1"] == 1.0 and m["occupancy_f1_observed"] == 1.0
    assert m["coverage_mae"] == pytest.approx(0.0, abs=1e-3)
    assert m["explored_fraction"] == 1.0
    core = 4 * 10 * 5  # block voxels with six covered neighbours (outside the grid counts as covered)
    assert m["observable_voxels"] == GRID.size - core
    assert m["overlap_fraction"] is None  # no per-robot masks given
    # the block's surface lies within 1.5 voxel edges of its mapped voxels, but its core is
    # too far from any face to count as surface: with the core left unknown (as no sensor
    # could see it) accuracy is perfect too
    assert m["surface_completeness"] == 1.0 and 0.5 < m["surface_accuracy"] < 1.0
    x, y, z = np.moveaxis(GRID.centres(), -1, 0)
    to_surface = np.minimum.reduce([x - 1.5, 2.0 - x, y, 1.0 - y, 0.6 - z, z])  # inside the block
    core = (truth > 0.5) & (to_surface >= 0.15 - 1e-9)  # 0.15 m or more from the faces and floor
    lam[core.ravel()] = CoverageMap(GRID).lam[0]
    eta = np.where(core.ravel(), CoverageMap(GRID).eta[0], lam * truth.ravel()).astype(np.float32)
    m = compute_metrics(_record(), CoverageMap(GRID, lam=lam, eta=eta), truth)
    assert m["surface_accuracy"] == 1.0 and m["surface_completeness"] == 1.0


def test_surface_measures_see_a_shifted_wall_and_the_sensor_observable_mask():
    truth = _truth()
    shifted = np.zeros_like(truth)
    shifted[10:15, :, :6] = 1.0  # the block mapped 0.5 m to the left: 3+ voxel edges off
    lam = np.full(GRID.size, 1e8, np.float32)
    m = compute_metrics(_record(), CoverageMap(GRID, lam=lam, eta=lam * shifted.ravel()), truth)
    # accurate: the two floor layers (centres 0.05 and 0.15 m up) of the 5 x-columns, and in
    # the 4 layers above them the 2 columns whose centres are 0.05 and 0.15 m (1.5 edges,
    # inclusive) from the true face x = 1.5: (2 * 5 + 4 * 2) / 30
    assert m["surface_accuracy"] == pytest.approx(18 / 30)
    assert m["surface_completeness"] < 0.6
    # with a sensor-observable mask: only surface whose air is observable counts, and the
    # explored fraction is over that mask
    cmap, observed = _fused_map()
    seen = np.zeros(GRID.shape, bool)
    seen[:15] = True  # everything left of the block
    m = compute_metrics(_record(), cmap, truth, observed, seen)
    assert m["observable_voxels"] == int(seen.sum())
    full = compute_metrics(_record(), cmap, truth, observed)
    assert m["surface"]["surface"] < full["surface"]["surface"]
    assert m["surface_completeness"] > full["surface_completeness"]


def test_metrics_of_a_fused_map():
    cmap, observed = _fused_map()
    m = compute_metrics(_record(), cmap, _truth(), observed)
    # The face was seen, most of the room was not: F1 over observed voxels is much better.
    assert m["occupancy_f1_observed"] > 0.8
    assert m["occupancy_f1"] < m["occupancy_f1_observed"]
    assert m["occupancy"]["observed"]["n"] < m["occupancy"]["observable"]["n"]
    assert m["coverage_mae_observed"] < m["coverage_mae"]
    assert 0.0 < m["explored_fraction"] < 1.0
    assert 0.0 < m["overlap_fraction"] < 1.0
    assert m["final_entropy_bits"] < 7.0 * GRID.size
    assert m["entropy_split"]["final_bits"] == pytest.approx(m["final_entropy_bits"])
    assert m["entropy_split"]["unobservable_share"] > 0.0  # the block's core keeps its prior
    left = m["entropy_left"]
    assert left["observable_bits"] == pytest.approx(m["entropy_split"]["final_observable_bits"])
    assert left["unknown_bits"] + left["known_bits"] == pytest.approx(left["observable_bits"])
    assert sum(left["bits_by_layer"]) == pytest.approx(left["observable_bits"])
    assert len(left["bits_by_layer"]) == GRID.shape[2] and left["known_bits"] > 0
    assert m["reached_threshold"] and m["mission_time_s"] == 0.0  # 7840 <= 8000 at once
    m = compute_metrics(_record(threshold_bits=5500.0), cmap, _truth(), observed)
    assert m["reached_threshold"] and m["mission_time_s"] == 1.5
    m = compute_metrics(_record(threshold_bits=100.0), cmap, _truth(), observed)
    assert not m["reached_threshold"] and m["mission_time_s"] is None


def test_metrics_without_ground_truth():
    cmap, _ = _fused_map()
    m = compute_metrics(_record(), cmap)
    assert m["occupancy_f1"] is None and m["coverage_mae"] is None
    assert m["observable_voxels"] == GRID.size
    assert m["explored_fraction"] == pytest.approx(m["known_voxels"] / GRID.size)


def test_top_view_image_marks_unknown_columns():
    cmap = CoverageMap(GRID)
    ijk = np.array([[3, 4, 2], [3, 4, 3], [5, 5, 7]])  # z = 0.25, 0.35 (in the band), 0.75 (above)
    idx = GRID.flat(ijk)
    cmap.lam[idx] = 1e4
    cmap.eta[idx] = 1e4 * np.array([0.9, 0.1, 1.0], np.float32)
    image, layers = top_view_image(cmap, (0.1, 0.5))
    assert layers.tolist() == [1, 2, 3, 4]
    assert image[3, 4] == pytest.approx(0.9, abs=1e-3)
    assert np.isnan(image[5, 5]) and np.count_nonzero(~np.isnan(image)) == 1


@pytest.mark.slow
def test_write_run_folder(tmp_path):
    cmap, observed = _fused_map()
    record = _record()
    metrics = compute_metrics(record, cmap, _truth(), observed)
    out = tmp_path / "run"
    write_run_folder(out, metrics, cmap, "mission: box\n", record)

    data = json.loads((out / "metrics.json").read_text())
    assert set(METRIC_KEYS) <= set(data)
    assert data["config"] == "configs/box.yaml" and data["robots"] == ["r1", "r2"]
    assert data["seed"] == 3 and data["strategy"] == "entropy_gradient"
    assert data["reached_threshold"] is True and data["mission_time_s"] == 0.0
    assert data["bytes_shared"] == {"r1": 1234, "r2": 56}
    assert data["entropy_curve"] == record.entropy_curve
    assert data["distance_m"]["r1"] == pytest.approx(1.0)
    floats = ("occupancy_f1", "coverage_mae", "explored_fraction", "overlap_fraction", "final_entropy_bits")
    for key in floats:
        assert isinstance(data[key], float), key
    assert 0.0 <= data["occupancy_f1"] <= 1.0

    with np.load(out / "map.npz") as npz:
        assert set(REQUIRED_KEYS) <= set(npz.files)
        assert npz["mu"].shape == GRID.shape and npz["expected_coverage"].dtype == np.float32
    assert (out / "config.yaml").read_text() == "mission: box\n"
    slices = sorted((out / "slices").glob("band_*.png"))
    assert [p.name for p in slices] == ["band_00_z0.00_to_0.40m.png", "band_01_z0.40_to_0.80m.png"]
    for name in ("entropy.png", "top_view.png", "map_3d.png", *(f"slices/{p.name}" for p in slices)):
        image = cv2.imread(str(out / name))
        assert image is not None, name
        h, w = image.shape[:2]
        assert w >= 600 and h >= 300, (name, w, h)
        assert image.std() > 10  # not a blank canvas


@pytest.mark.slow
def test_metrics_json_has_no_nan(tmp_path):
    cmap = CoverageMap(GRID)
    truth = np.ones(GRID.shape, np.float32)  # all solid: nothing is observable
    record = _record(entropy_curve=[], trajectories={})
    metrics = compute_metrics(record, cmap, truth)
    assert metrics["coverage_mae"] is None
    metrics["extra"] = float("nan")
    write_run_folder(tmp_path, metrics, cmap, "", record)
    text = (tmp_path / "metrics.json").read_text()
    assert "NaN" not in text and json.loads(text)["extra"] is None
