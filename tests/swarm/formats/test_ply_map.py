"""PLY of occupied voxels with their belief: written, then read back by our own reader."""

from pathlib import Path

import numpy as np
import pytest

from swarm.formats.ply_map import BELIEF_PROPERTIES, write_belief_ply
from swarm.formats.point_cloud_file import PointCloudError, read_ply_vertices, read_point_cloud
from swarm.map.coverage_map import CoverageMap
from swarm.map.entropy import entropy_exact, expected_coverage
from swarm.map.grid import Grid


def sample_map() -> CoverageMap:
    grid = Grid((-0.5, 0.0, 0.2), 0.1, (6, 5, 4))
    cmap = CoverageMap(grid)
    rng = np.random.default_rng(4)
    picked = rng.choice(grid.size, 40, replace=False)
    sigma = rng.uniform(0.05, 0.4, 40)
    mu = rng.uniform(-0.2, 1.2, 40)
    cmap.lam[picked] = 1 / sigma**2
    cmap.eta[picked] = mu / sigma**2
    return cmap


@pytest.mark.parametrize("cubes", [False, True])
def test_belief_ply_round_trip(tmp_path: Path, cubes: bool):
    cmap = sample_map()
    n = write_belief_ply(tmp_path / "m.ply", cmap, cubes=cubes)
    mu, sigma = cmap.mean().astype(np.float64), cmap.sigma().astype(np.float64)
    coverage = expected_coverage(mu, sigma)
    want = np.flatnonzero(coverage > 0.5)  # the prior voxels sit at E[C] = 0.5 exactly: not written
    assert n == len(want) > 5
    v = read_ply_vertices(tmp_path / "m.ply")
    per = 8 if cubes else 1
    assert set(BELIEF_PROPERTIES) | {"x", "y", "z", "red", "green", "blue"} == set(v)
    np.testing.assert_allclose(v["mu"][::per], mu[want], rtol=1e-6)
    np.testing.assert_allclose(v["sigma"][::per], sigma[want], rtol=1e-6)
    np.testing.assert_allclose(v["expected_coverage"][::per], coverage[want], rtol=1e-6)
    np.testing.assert_allclose(v["entropy"][::per], entropy_exact(mu[want], sigma[want]), atol=0.02)
    points = read_point_cloud(tmp_path / "m.ply")
    centres = cmap.grid.centre(cmap.grid.unflat(want))
    if cubes:
        points = points.reshape(-1, 8, 3).mean(axis=1)  # the corners' mean is the centre
    np.testing.assert_allclose(points, centres, atol=1e-6)
    if cubes:  # faces: 6 quads per voxel, after the vertices
        raw = (tmp_path / "m.ply").read_bytes()
        assert f"element face {6 * n}".encode() in raw
        body = raw[raw.index(b"end_header\n") + 11 :]
        vertex_bytes = 8 * n * (7 * 4 + 3)
        faces = np.frombuffer(body[vertex_bytes:], dtype=[("n", "u1"), ("v", "<i4", (4,))])
        assert len(faces) == 6 * n and np.all(faces["n"] == 4)
        assert faces["v"].min() == 0 and faces["v"].max() == 8 * n - 1


def test_truncated_ply_names_the_file(tmp_path: Path):
    write_belief_ply(tmp_path / "m.ply", sample_map())
    raw = (tmp_path / "m.ply").read_bytes()
    (tmp_path / "cut.ply").write_bytes(raw[:-10])
    with pytest.raises(PointCloudError, match="cut.ply.*truncated"):
        read_ply_vertices(tmp_path / "cut.ply")


def test_open3d_reads_the_cubes(tmp_path: Path):
    o3d = pytest.importorskip("open3d", reason="Open3D is not installed (optional)")
    n = write_belief_ply(tmp_path / "m.ply", sample_map(), cubes=True)
    mesh = o3d.io.read_triangle_mesh(str(tmp_path / "m.ply"))
    assert len(mesh.vertices) == 8 * n and len(mesh.triangles) == 12 * n
