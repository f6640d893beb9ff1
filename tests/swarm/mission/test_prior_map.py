"""A mission that starts from a previous map: resampling onto the mission grid, and a short run."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from swarm.config import load_mission
from swarm.config.models import ConfigError
from swarm.formats.map_file import load_map, save_map
from swarm.formats.octomap_file import write_bt
from swarm.formats.octomap_map import coverage_to_leaves, states_to_prior
from swarm.map.coverage_map import CoverageMap
from swarm.map.grid import Grid
from swarm.map.sensor_model import SensorModel
from swarm.mission.prior_map import PriorMapError, chunks, load_previous_map, prior_delta
from tests.support.prior_mission import MISSION


def test_prior_delta_gives_each_voxel_the_belief_at_its_centre():
    sensor = SensorModel()
    fine = Grid((-0.4, -0.4, 0.0), 0.1, (20, 20, 6))
    rng = np.random.default_rng(5)
    states = rng.choice(np.array([0, 1, 2], np.uint8), size=fine.shape)
    previous = states_to_prior(fine, states, sensor, known_sigma=0.1)
    mission = Grid((0.0, 0.0, 0.0), 0.2, (12, 8, 3))  # coarser, and reaching beyond the map
    cmap = CoverageMap(mission, sensor)
    cmap.apply(prior_delta(mission, sensor, previous))
    # an independent lookup: the fine voxel that holds each mission voxel centre
    centres = mission.centres().reshape(-1, 3)
    ijk = np.floor((centres - np.array(fine.origin)) / 0.1).astype(int)
    inside = np.all((ijk >= 0) & (ijk < np.array(fine.shape)), axis=1)
    want_state = np.zeros(len(centres), np.uint8)
    want_state[inside] = states[tuple(ijk[inside].T)]
    mu, sigma = cmap.mean(), cmap.sigma()
    known = want_state > 0
    np.testing.assert_allclose(sigma[known], 0.1, rtol=1e-4)
    np.testing.assert_allclose(mu[known], (want_state[known] == 2).astype(float), atol=1e-4)
    np.testing.assert_allclose(sigma[~known], sensor.prior_sigma(), rtol=1e-5)
    np.testing.assert_allclose(mu[~known], 0.5, atol=1e-5)
    assert np.count_nonzero(cmap.known_mask()) == np.count_nonzero(known)


def test_chunks_cover_the_delta_once():
    sensor = SensorModel()
    grid = Grid((0.0, 0.0, 0.0), 0.1, (10, 10, 10))
    previous = states_to_prior(grid, np.ones(grid.shape, np.uint8), sensor)
    delta = prior_delta(grid, sensor, previous)
    pieces = chunks(delta, 300)
    assert [len(p) for p in pieces] == [300, 300, 300, 100]
    np.testing.assert_array_equal(np.concatenate([p.idx for p in pieces]), delta.idx)


def test_previous_map_from_npz_or_bt(tmp_path: Path):
    grid = Grid((0.0, 0.0, 0.0), 0.1, (6, 5, 4))
    states = np.random.default_rng(2).choice(np.array([0, 1, 2], np.uint8), size=grid.shape)
    states[0, 0, 0] = 2  # the bounding box of the known voxels is the whole grid
    states[-1, -1, -1] = 1
    cmap = states_to_prior(grid, states)
    save_map(tmp_path / "m.npz", cmap)
    leaves = coverage_to_leaves(cmap)
    write_bt(tmp_path / "m.bt", leaves.resolution, leaves.key, leaves.occupied)
    from_npz = load_previous_map(tmp_path / "m.npz")
    from_bt = load_previous_map(tmp_path / "m.bt")
    assert from_bt.grid.matches(grid)
    np.testing.assert_allclose(from_bt.mean(), from_npz.mean(), atol=1e-5)
    np.testing.assert_allclose(load_map(tmp_path / "m.npz").sigma(), from_bt.sigma(), rtol=1e-5)
    (tmp_path / "bad.bt").write_bytes(b"nonsense")
    with pytest.raises(PriorMapError, match="bad.bt"):
        load_previous_map(tmp_path / "bad.bt")


def test_config_names_a_prior_map(tmp_path: Path):
    (tmp_path / "m.yaml").write_text(MISSION)
    with pytest.raises(ConfigError, match="prior_map: file not found"):
        load_mission(tmp_path / "m.yaml")
    (tmp_path / "previous.bt").write_bytes(b"")
    mission = load_mission(tmp_path / "m.yaml")
    assert mission.prior_map_path() == (tmp_path / "previous.bt").resolve()
    assert str((tmp_path / "previous.bt").resolve()) in mission.to_yaml()


@pytest.mark.slow
def test_simulated_mission_starts_from_the_previous_map(tmp_path: Path):
    """A previous map of the far half of the room: the server's final map still holds it there."""
    grid = Grid((0.0, 0.0, 0.0), 0.1, (24, 24, 8))
    states = np.zeros(grid.shape, np.uint8)
    states[14:, :, :] = 1  # free, far from the robot's start
    states[20:22, 4:8, 0:6] = 2  # a box
    previous = states_to_prior(grid, states, known_sigma=0.1)
    leaves = coverage_to_leaves(previous)
    write_bt(tmp_path / "previous.bt", leaves.resolution, leaves.key, leaves.occupied)
    (tmp_path / "m.yaml").write_text(MISSION)
    out = tmp_path / "run"
    proc = subprocess.run(
        [sys.executable, "-m", "swarm.cli", "sim", str(tmp_path / "m.yaml"), "--out", str(out), "--quiet"],
        capture_output=True,
        text=True,
        timeout=180,
    )
    logs = "\n".join(f"--- {p.name}\n{p.read_text()[-2000:]}" for p in sorted(out.glob("*.log")))
    assert proc.returncode == 0, proc.stdout + proc.stderr + logs
    assert "started from the previous map" in proc.stdout
    metrics = json.loads((out / "metrics.json").read_text())
    prior_bits = 7.0 * grid.size
    assert metrics["initial_entropy_bits"] < prior_bits - 2 * np.count_nonzero(states)  # 7 -> 4.7 bits each
    assert "prior" not in metrics["bytes_shared"]
    final = load_map(out / "server_map.npz")
    box = np.zeros(grid.shape, bool)
    box[20:22, 4:8, 0:6] = True
    assert np.all(final.mean().reshape(grid.shape)[box] > 0.5)
    far = np.zeros(grid.shape, bool)
    far[14:, :, :] = True
    assert np.all(final.sigma().reshape(grid.shape)[far] <= 0.1 + 1e-4)  # nothing was forgotten
