"""map.npz and a map server's snapshot.npz read by ``swarm map info``; broken ones named by key."""

from __future__ import annotations

import json

import numpy as np
import pytest

from map_server.store import Store, StoreIdentity
from swarm.cli import main
from swarm.formats.map_file import MapFileError, load_map, save_map
from swarm.map.coverage_map import CoverageMap
from swarm.map.grid import Grid
from swarm.map.sensor_model import SensorModel


def some_map() -> CoverageMap:
    grid = Grid((0.0, -1.0, 0.0), 0.2, (5, 4, 3))
    sensor = SensorModel(0.05, 0.03, 2.5, 4.0)
    cmap = CoverageMap(grid, sensor)
    rng = np.random.default_rng(3)
    cmap.lam = (cmap.lam * rng.uniform(1, 50, grid.size)).astype(np.float32)
    cmap.eta = (cmap.lam * rng.uniform(0, 1, grid.size)).astype(np.float32)
    return cmap


def test_map_info_reads_a_store_snapshot(tmp_path, capsys):
    cmap = some_map()
    store, _ = Store.open(tmp_path / "store", StoreIdentity("site", cmap.grid, cmap.sensor), fsync=False)
    store.compact(cmap.grid, cmap.lam, cmap.eta, "[]", {})
    store.close()
    loaded = load_map(tmp_path / "store" / "snapshot.npz")
    assert loaded.grid == cmap.grid and loaded.sensor == cmap.sensor
    np.testing.assert_allclose(loaded.mean(), cmap.mean(), rtol=1e-6)
    save_map(tmp_path / "map.npz", cmap)
    assert main(["map", "info", "--json", str(tmp_path / "map.npz")]) == 0
    from_map = json.loads(capsys.readouterr().out)
    assert main(["map", "info", "--json", str(tmp_path / "store" / "snapshot.npz")]) == 0
    from_snapshot = json.loads(capsys.readouterr().out)
    assert "snapshot" in from_snapshot.pop("note")
    assert (
        from_snapshot["shape"] == from_map["shape"]
        and from_snapshot["known_fraction"] == from_map["known_fraction"]
    )
    assert from_snapshot["entropy_bits"] == pytest.approx(from_map["entropy_bits"], rel=1e-4)


@pytest.mark.parametrize(
    "change, field",
    [
        ({"origin": np.array([0.0, np.nan, 0.0])}, "origin"),
        ({"voxel_size": np.float64(np.inf)}, "voxel_size"),
        ({"sensor": np.array([0.05, 0.03, np.nan, 4.0])}, "sensor"),
        ({"mu": None}, "mu"),
    ],
)
def test_broken_map_files_name_the_key(tmp_path, capsys, change, field):
    save_map(tmp_path / "good.npz", some_map())
    with np.load(tmp_path / "good.npz") as data:
        arrays = {k: data[k] for k in data.files}
    for key, value in change.items():
        if value is None:
            del arrays[key]
        else:
            arrays[key] = value
    np.savez(tmp_path / "bad.npz", **arrays)
    with pytest.raises(MapFileError) as info:
        load_map(tmp_path / "bad.npz")
    assert str(info.value).startswith(f"{tmp_path / 'bad.npz'}: {field}: "), str(info.value)
    assert main(["map", "info", str(tmp_path / "bad.npz")]) == 2
    assert capsys.readouterr().err.count("\n") == 1
