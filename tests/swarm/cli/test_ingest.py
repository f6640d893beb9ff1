"""`swarm ingest` and `swarm map info` end to end, through the CLI entry point."""

import bz2
import json

import numpy as np
import pytest

from swarm.cli import main
from swarm.formats.map_file import load_map
from swarm.formats.point_cloud_file import read_point_cloud, write_ply_points
from swarm.map.ingest import default_bounds
from tests.support.paths import ROOT

BUNDLED_SCAN = ROOT / "data" / "octomap" / "scan.dat.bz2"


def wall_cloud() -> np.ndarray:
    """A wall 2 m ahead of the origin, 1.6 m wide and 1 m high."""
    y, z = np.meshgrid(np.linspace(-0.8, 0.8, 33), np.linspace(-0.5, 0.5, 21))
    return np.column_stack([np.full(y.size, 2.0), y.ravel(), z.ravel()])


def run_json(capsys, *args) -> dict:
    assert main(["ingest", *map(str, args), "--json"]) == 0
    return json.loads(capsys.readouterr().out)


@pytest.mark.slow
def test_nonfinite_and_out_of_box_points_are_reported_and_the_rest_fused(tmp_path, capsys):
    good = wall_cloud()
    bad = np.array([[np.nan, 0, 0], [1.0, np.inf, 0], [-np.inf, 0, 0], [-9.0, 0.0, 0.0], [0.5, 5.0, 0.0]])
    cloud = tmp_path / "cloud.npy"
    np.save(cloud, np.vstack([good, bad]))
    out = tmp_path / "map.npz"
    report = run_json(capsys, cloud, "--out", out, "--bounds", -1, -2, -1, 3, 2, 1, "--max-range", 20)
    assert report["skipped_nonfinite"] == 3
    assert report["skipped_outside"] == 0
    assert report["clipped_at_box"] == 2  # free space up to the box, no hit
    assert report["rays"] == len(good) + 2
    assert report["voxel_updates"] > len(good) * 20
    assert report["final_entropy_bits"] < report["initial_entropy_bits"]
    assert report["initial_entropy_bits"] == pytest.approx(7 * report["voxels"], rel=0.01)

    with np.load(out) as data:
        for key in ("mu", "sigma", "entropy", "expected_coverage"):
            assert data[key].shape == tuple(report["shape"]) and data[key].dtype == np.float32
        assert data["voxel_size"] == pytest.approx(0.1)
        np.testing.assert_allclose(data["origin"], [-1, -2, -1])
        # the wall is covered, the space in front of it free
        cov = data["expected_coverage"]
        i_wall = np.floor((np.array([2.05, 0.05, 0.05]) - [-1, -2, -1]) / 0.1).astype(int)
        i_free = np.floor((np.array([1.0, 0.05, 0.05]) - [-1, -2, -1]) / 0.1).astype(int)
        assert cov[tuple(i_wall)] > 0.5 > 0.1 > cov[tuple(i_free)]
        assert float(data["entropy"].sum()) == pytest.approx(report["final_entropy_bits"], rel=1e-4)

    cmap = load_map(out)
    assert cmap.grid.shape == tuple(report["shape"])


def test_text_bz2_and_ply_read_the_same_cloud(tmp_path, capsys):
    points = wall_cloud().astype(np.float32).astype(np.float64)  # PLY stores float32
    text = tmp_path / "cloud.txt.bz2"
    with bz2.open(text, "wt") as f:
        f.write("# x y z\n")
        np.savetxt(f, points, fmt="%.17g")
    ply = tmp_path / "cloud.ply"
    write_ply_points(ply, points)
    a = run_json(capsys, text, "--out", tmp_path / "a.npz")
    b = run_json(capsys, ply, "--out", tmp_path / "b.npz")
    assert a["rays"] == b["rays"] == len(points)
    assert a["voxel_updates"] == b["voxel_updates"]
    assert a["final_entropy_bits"] == pytest.approx(b["final_entropy_bits"], rel=1e-5)


@pytest.mark.slow
@pytest.mark.skipif(not BUNDLED_SCAN.exists(), reason="bundled OctoMap scan missing")
def test_real_scan_ingests_and_map_info_summarises_it(tmp_path, capsys):
    out = tmp_path / "scan.npz"
    report = run_json(capsys, BUNDLED_SCAN, "--out", out)
    assert report["points"] == 88206
    assert report["rays"] + report["skipped_nonfinite"] + report["skipped_outside"] == 88206
    assert report["truncated_at_max_range"] > 30000  # median range is 4.9 m, max range 5 m
    assert 0 < report["final_entropy_bits"] < 0.9 * report["initial_entropy_bits"]

    assert main(["map", "info", str(out), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["voxels"] == report["voxels"]
    assert info["entropy_bits"] == pytest.approx(report["final_entropy_bits"], rel=1e-3)
    assert 0.05 < info["known_fraction"] < 1
    assert info["occupied_voxels"] > 0

    # Voxels holding returned points are far more covered than the known space on average.
    # (Not all exceed 0.5: grazing rays, on the floor above all, pass through the hit voxels
    # of their neighbours and the model counts traversed voxels as free.)
    points = read_point_cloud(BUNDLED_SCAN)
    points = points[np.linalg.norm(points, axis=1) < 4.9]
    with np.load(out) as data:
        idx = np.floor((points - data["origin"]) / data["voxel_size"]).astype(int)
        coverage = data["expected_coverage"]
        known = data["sigma"] < 0.99 * data["sigma"].max()
        assert coverage[tuple(idx.T)].mean() > 4 * coverage[known].mean()


def test_errors_name_the_problem(tmp_path, capsys):
    assert main(["ingest", str(tmp_path / "missing.xyz"), "--out", str(tmp_path / "m.npz")]) == 2
    assert "missing.xyz" in capsys.readouterr().err
    cloud = tmp_path / "c.npy"
    np.save(cloud, wall_cloud())
    assert main(["ingest", str(cloud), "--out", str(tmp_path / "m.npz"), "--voxel", "-0.1"]) == 2
    assert "--voxel" in capsys.readouterr().err
    assert main(["ingest", str(cloud), "--out", str(tmp_path / "m.npz"), "--max-range", "0"]) == 2
    assert "max_range" in capsys.readouterr().err
    np.save(cloud, np.zeros((4, 2)))
    assert main(["ingest", str(cloud), "--out", str(tmp_path / "m.npz")]) == 2
    assert "N x 3" in capsys.readouterr().err


def test_repeated_ingest_returns_one_fusion_of_the_cloud_and_reports_its_times():
    """With repeat the cloud is fused several times for timing; the map is one fusion's."""
    from swarm.map.coverage_map import CoverageMap  # noqa: PLC0415
    from swarm.map.grid import Grid  # noqa: PLC0415
    from swarm.map.ingest import ingest_cloud  # noqa: PLC0415
    from swarm.map.sensor_model import SensorModel  # noqa: PLC0415

    sensor = SensorModel(max_range=20.0)
    bounds = (np.array([-1.0, -2.0, -1.0]), np.array([3.0, 2.0, 1.0]))
    cmap, report = ingest_cloud(wall_cloud(), np.zeros(3), sensor, 0.1, bounds, repeat=3)
    once = CoverageMap(Grid.from_bounds(*bounds, 0.1), sensor)
    once.integrate(np.zeros(3), wall_cloud())
    np.testing.assert_array_equal(cmap.lam, once.lam)
    np.testing.assert_array_equal(cmap.eta, once.eta)
    assert report.fusion_repeats == 3
    assert 0 < report.fusion_seconds <= report.first_fusion_seconds
    with pytest.raises(ValueError, match="repeat"):
        ingest_cloud(wall_cloud(), np.zeros(3), sensor, 0.1, bounds, repeat=0)


def test_the_default_box_lies_on_octomaps_lattice_so_the_map_exports_to_bt(tmp_path, capsys):
    # a real scan whose extent is no multiple of the voxel: the fitted box's corners are
    points = read_point_cloud(BUNDLED_SCAN) if BUNDLED_SCAN.exists() else wall_cloud() + 0.0123
    lo, hi = default_bounds(points, np.array([0.013, -0.021, 0.004]), 5.0, 0.1)
    for corner in (lo, hi):
        np.testing.assert_allclose(corner / 0.1, np.round(corner / 0.1), atol=1e-9)
    out = tmp_path / "scan.npz"
    np.save(tmp_path / "scan.npy", points)
    run_json(capsys, tmp_path / "scan.npy", "--out", out, "--origin", "0.013", "-0.021", "0.004")
    assert main(["map", "export", "--from", str(out), "--out", str(tmp_path / "scan.bt")]) == 0
    assert "moved by" not in capsys.readouterr().out
