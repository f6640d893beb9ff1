"""The picture set of every run (top_view.png, map_3d.png, slices/), ``swarm map picture`` from a
map file, and ``swarm map stats``'s summary of a real map server's figures."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from swarm.cli.main import main
from swarm.cli.map_stats import stats_summary
from swarm.formats.map_file import save_map
from swarm.map.coverage_map import CoverageMap
from swarm.map.delta import Delta
from swarm.map.grid import Grid
from swarm.mission.map_pictures import PICTURES, plot_map_3d, write_map_pictures
from swarm.mission.picture_style import path_colour
from tests.support.paths import ROOT


def _occupied_everywhere(grid: Grid) -> CoverageMap:
    """A map whose every voxel is known and occupied (E[C] near 1): a path at the floor lies
    behind all of them, seen from above."""
    cmap = CoverageMap(grid)
    idx = np.arange(grid.size, dtype=np.uint32)
    lam = np.full(grid.size, 400.0, np.float32)  # sigma 0.05
    cmap.apply(Delta(idx, lam, lam * 0.98))
    return cmap


def _pixels_of(png, colour, tolerance: int = 30) -> int:
    """How many pixels of the picture are within ``tolerance`` (0-255 per channel) of ``colour``."""
    image = cv2.imread(str(png))[:, :, ::-1].astype(int)  # RGB
    target = np.array([round(255 * c) for c in colour[:3]])
    return int(np.count_nonzero(np.all(np.abs(image - target) <= tolerance, axis=2)))


@pytest.mark.slow
def test_the_paths_are_drawn_over_the_voxels_in_3d(tmp_path) -> None:
    grid = Grid((0.0, 0.0, 0.0), 0.1, (40, 30, 10))
    cmap = _occupied_everywhere(grid)
    path = {"r1": np.array([[0.5, 0.5], [3.5, 0.5], [3.5, 2.5], [0.5, 2.5]])}
    plot_map_3d(tmp_path / "map_3d.png", cmap, path)
    plot_map_3d(tmp_path / "bare.png", cmap, {})
    blue = path_colour(0)
    # the voxels and their colour bar are grey, as E[C] is in the top view: no colour but the path's
    rgb = cv2.imread(str(tmp_path / "bare.png")).astype(int)
    assert np.count_nonzero(rgb.max(axis=2) - rgb.min(axis=2) > 40) < 50
    assert _pixels_of(tmp_path / "bare.png", blue) < 50
    assert _pixels_of(tmp_path / "map_3d.png", blue) > 800  # drawn over the voxels (hidden: < 50)


@pytest.mark.slow
def test_one_picture_set_for_every_run_without_negative_zeros_in_its_names(tmp_path) -> None:
    grid = Grid((-1.6, -1.0, -1e-12), 0.1, (32, 20, 9))  # z origin a hair below 0
    cmap = CoverageMap(grid)
    idx = np.arange(0, grid.size, 7, dtype=np.uint32)
    cmap.apply(Delta(idx, np.full(len(idx), 100.0, np.float32), np.full(len(idx), 10.0, np.float32)))
    written = write_map_pictures(tmp_path, cmap, {"cam": np.array([[-1.0, -0.5, 0.3], [1.0, 0.5, 0.6]])})
    names = [p.relative_to(tmp_path).as_posix() for p in written]
    assert names[:2] == ["top_view.png", "map_3d.png"] and PICTURES == (
        "top_view.png",
        "map_3d.png",
        "slices/",
    )
    bands = sorted(n for n in names if n.startswith("slices/"))
    assert bands[0] == "slices/band_00_z0.00_to_0.40m.png", bands  # not z-0.00
    assert all("-0.00" not in n for n in names)
    for p in written:
        assert cv2.imread(str(p)) is not None, p


def test_swarm_map_picture_draws_a_run_folders_map_with_its_paths(tmp_path, capsys) -> None:
    run = tmp_path / "run"
    run.mkdir()
    grid = Grid((0.0, 0.0, 0.0), 0.1, (30, 20, 6))
    save_map(run / "map.npz", _occupied_everywhere(grid))
    (run / "trajectories.json").write_text(json.dumps({"r1": [[0, 0.5, 0.5], [1, 2.5, 1.5]]}))
    out = tmp_path / "pics"
    assert main(["map", "picture", str(run / "map.npz"), "--out", str(out), "--band", "0.1,0.4"]) == 0
    printed = capsys.readouterr().out
    assert "of z in [0.1, 0.4] m" in printed and "1 path(s)" in printed, printed
    assert (out / "top_view.png").is_file() and (out / "map_3d.png").is_file()
    assert len(list((out / "slices").glob("band_*.png"))) == 2
    assert _pixels_of(out / "top_view.png", path_colour(0)) > 100


def test_swarm_map_picture_refuses_a_band_upside_down(tmp_path, capsys) -> None:
    grid = Grid((0.0, 0.0, 0.0), 0.1, (4, 4, 4))
    save_map(tmp_path / "map.npz", CoverageMap(grid))
    assert main(["map", "picture", str(tmp_path / "map.npz"), "--out", str(tmp_path), "--band", "1,0.5"]) == 2
    assert capsys.readouterr().err.strip() == "swarm: error: --band 1,0.5: Z0 must be below Z1"


def test_the_stats_summary_of_a_real_map_server_is_a_few_lines(tmp_path) -> None:
    from map_server.server import MapServer
    from swarm.config import load_mission
    from swarm.protocol.wire import DeltaMessage

    mission = load_mission(ROOT / "configs" / "lab.yaml")
    server = MapServer(mission, tmp_path / "store")
    grid = mission.workspace.grid()
    idx = np.arange(100, 400, dtype=np.uint32)
    msg = DeltaMessage(
        "r1", 1, 1, 0.5, grid, idx, np.full(300, 50.0, np.float32), np.full(300, 1.0, np.float32)
    )
    from tests.support.map_server_mission import signed

    assert server.merge(signed(server, [("r1", 1, msg.encode())])) == 1
    server.threshold_bits = mission.threshold_bits()
    stats = server.stats()
    lines = stats_summary(stats)
    server.stop()
    assert 4 <= len(lines) <= 8, lines
    assert lines[0].startswith(f"mission {mission.mission}: {grid.size:,} voxels of 0.1 m")
    assert f"known {stats['known_fraction']:.1%}" in lines[0]
    h, h0 = stats["entropy_bits"], stats["initial_entropy_bits"]
    assert f"entropy {h:,.0f} bits, {h / h0:.1%} of the initial {h0:,.0f}" in lines[1]
    assert f"H_th {mission.threshold_bits():,.0f} bits" in lines[1]
    assert lines[2].startswith("deltas applied 1 (300 voxel updates)") and "refused: none" in lines[2]
    assert lines[3].strip().startswith("r1: 1 deltas, 300 voxel updates, acked 1 of 1")
