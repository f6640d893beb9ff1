"""OctoMap .bt files: written by our code and read by OctoMap itself (octomap-python), and back."""

from pathlib import Path

import numpy as np
import pytest

from swarm.formats.octomap_file import OctomapFileError, read_bt, write_bt
from swarm.formats.octomap_map import coverage_to_leaves, leaves_to_states, states_to_prior
from swarm.map.coverage_map import CoverageMap
from swarm.map.grid import Grid
from tests.support.paths import ROOT

octomap = pytest.importorskip("octomap", reason="octomap-python (pip install '.[bench]') reads the files")

_ROOT = ROOT
#: the real OctoMap file bundled with the project (the OctoMap project's sample data, BSD)
SHARED_BT = _ROOT / "data" / "octomap" / "geb079.bt"


def known_states(shape: tuple[int, int, int], seed: int = 3) -> np.ndarray:
    """0 unknown, 1 free, 2 occupied: random voxels plus uniform blocks OctoMap prunes."""
    rng = np.random.default_rng(seed)
    states = rng.choice(np.array([0, 1, 2], np.uint8), size=shape, p=[0.3, 0.5, 0.2])
    states[0:4, 0:4, 0:4] = 2  # an aligned 4^3 block of occupied voxels
    states[4:6, 4:6, 0:2] = 1  # an aligned 2^3 block of free voxels
    states[8:10, 0:2, 2:4] = 0  # and one of unknown
    return states


def coverage_with(states: np.ndarray, grid: Grid) -> CoverageMap:
    """A coverage map whose known voxels are sure enough: sigma 0.1, mu 1 or 0; unknown at the prior."""
    return states_to_prior(grid, states, known_sigma=0.1)


def octomap_states(tree, grid: Grid) -> np.ndarray:
    """The state OctoMap gives each voxel centre of ``grid`` (0 unknown, 1 free, 2 occupied)."""
    out = np.zeros(grid.size, np.uint8)
    for n, centre in enumerate(grid.centres().reshape(-1, 3)):
        node = tree.search(centre)
        try:
            out[n] = 2 if tree.isNodeOccupied(node) else 1
        except octomap.NullPointerException:
            out[n] = 0
    return out.reshape(grid.shape)


@pytest.mark.parametrize("origin", [(0.0, 0.0, 0.0), (-1.6, -0.8, -0.4)])
def test_octomap_reads_our_file_voxel_by_voxel(tmp_path: Path, origin):
    grid = Grid(origin, 0.2, (16, 12, 6))
    states = known_states(grid.shape)
    leaves = coverage_to_leaves(coverage_with(states, grid))
    nodes = write_bt(tmp_path / "map.bt", leaves.resolution, leaves.key, leaves.occupied)
    tree = octomap.OcTree(str(tmp_path / "map.bt").encode())
    assert tree.size() == nodes
    assert tree.getResolution() == pytest.approx(0.2)
    np.testing.assert_array_equal(octomap_states(tree, grid), states)


def test_our_tree_is_byte_for_byte_octomaps_own(tmp_path: Path):
    """OctoMap, given the same voxels, writes (after its max-likelihood pruning) the same tree data."""
    grid = Grid((-0.8, 0.4, 0.0), 0.1, (12, 10, 8))
    states = known_states(grid.shape, seed=7)
    tree = octomap.OcTree(0.1)
    centres = grid.centres()
    for ijk in np.argwhere(states > 0):
        tree.updateNode(centres[tuple(ijk)], bool(states[tuple(ijk)] == 2))
    tree.writeBinary(str(tmp_path / "theirs.bt").encode())
    leaves = coverage_to_leaves(coverage_with(states, grid))
    write_bt(tmp_path / "ours.bt", leaves.resolution, leaves.key, leaves.occupied)

    def data(path: Path) -> bytes:
        raw = path.read_bytes()
        return raw[raw.index(b"\ndata\n") + 6 :]

    assert data(tmp_path / "ours.bt") == data(tmp_path / "theirs.bt")


def test_our_reader_round_trip(tmp_path: Path):
    grid = Grid((0.4, -0.2, 0.0), 0.2, (10, 8, 5))
    states = known_states(grid.shape, seed=11)
    leaves = coverage_to_leaves(coverage_with(states, grid))
    write_bt(tmp_path / "m.bt", leaves.resolution, leaves.key, leaves.occupied)
    back_grid, back = leaves_to_states(read_bt(tmp_path / "m.bt"))
    # the bounding box of the known voxels, placed back into the original grid
    at = np.round((back_grid.lo - grid.lo) / grid.voxel).astype(int)
    full = np.zeros(grid.shape, np.uint8)
    full[at[0] : at[0] + back.shape[0], at[1] : at[1] + back.shape[1], at[2] : at[2] + back.shape[2]] = back
    np.testing.assert_array_equal(full, states)


def test_origin_off_the_octomap_lattice(tmp_path: Path):
    grid = Grid((0.05, 0.0, 0.0), 0.1, (6, 6, 4))
    cmap = coverage_with(known_states(grid.shape), grid)
    with pytest.raises(ValueError, match=r"not a multiple of the voxel size.*--align shift") as refused:
        coverage_to_leaves(cmap)
    assert str(refused.value).endswith("by [-0.05, 0.0, 0.0] m"), refused.value  # no "-0.0"
    leaves = coverage_to_leaves(cmap, align="shift")
    assert max(abs(s) for s in leaves.shift) <= 0.05 + 1e-12
    shifted = Grid(tuple(np.add(grid.origin, leaves.shift)), 0.1, grid.shape)
    write_bt(tmp_path / "s.bt", leaves.resolution, leaves.key, leaves.occupied)
    tree = octomap.OcTree(str(tmp_path / "s.bt").encode())
    np.testing.assert_array_equal(octomap_states(tree, shifted), known_states(grid.shape))


def test_uncertain_voxels_are_unknown():
    grid = Grid((0.0, 0.0, 0.0), 0.1, (4, 4, 4))
    cmap = CoverageMap(grid)
    cmap.lam[:3] = 1 / 0.3**2  # sigma 0.3: known
    cmap.eta[:3] = cmap.lam[:3] * np.array([0.9, 0.2, 0.5])
    cmap.lam[3] = 1 / 0.8**2  # sigma 0.8: unknown at the default max_sigma 0.5
    cmap.eta[3] = cmap.lam[3]
    leaves = coverage_to_leaves(cmap)
    assert leaves.key.tolist() == (np.array([[0, 0, 0], [0, 0, 1], [0, 0, 2]]) + 32768).tolist()
    assert leaves.occupied.tolist() == [True, False, False]  # E[C] = 0.5 is not above 0.5


@pytest.mark.skipif(not SHARED_BT.exists(), reason="data/octomap/geb079.bt is missing")
def test_import_real_octomap_counts_match_octomaps_own():
    leaves = read_bt(SHARED_BT)
    tree = octomap.OcTree(str(SHARED_BT).encode())
    res = tree.getResolution()
    occupied = free = 0
    for leaf in tree.begin_leafs():
        n = int(round(leaf.getSize() / res)) ** 3
        if tree.isNodeOccupied(leaf):
            occupied += n
        else:
            free += n
    assert leaves.resolution == pytest.approx(0.08)
    assert np.any(leaves.depth < 16), "the sample has pruned nodes"
    assert leaves.voxel_counts() == (occupied, free)
    grid, states = leaves_to_states(leaves)
    assert np.count_nonzero(states == 2) == occupied
    assert np.count_nonzero(states == 1) == free
    np.testing.assert_allclose(grid.lo, tree.getMetricMin(), atol=1e-6)
    np.testing.assert_allclose(grid.hi, tree.getMetricMax(), atol=1e-6)
    # spot checks voxel by voxel against OctoMap's own search
    rng = np.random.default_rng(0)
    for flat in rng.choice(grid.size, 400, replace=False):
        ijk = np.unravel_index(flat, grid.shape)
        node = tree.search(grid.centre(np.array(ijk)))
        try:
            want = 2 if tree.isNodeOccupied(node) else 1
        except octomap.NullPointerException:
            want = 0
        assert states[ijk] == want


def test_bad_files_name_the_file_and_field(tmp_path: Path):
    grid = Grid((0.0, 0.0, 0.0), 0.1, (8, 8, 4))
    leaves = coverage_to_leaves(coverage_with(known_states(grid.shape), grid))
    write_bt(tmp_path / "good.bt", 0.1, leaves.key, leaves.occupied)
    raw = (tmp_path / "good.bt").read_bytes()
    (tmp_path / "short.bt").write_bytes(raw[:-3])
    (tmp_path / "size.bt").write_bytes(raw.replace(b"\nsize ", b"\nsize 1"))
    (tmp_path / "text.bt").write_bytes(b"# Octomap OcTree file\nid OcTree\n")
    (tmp_path / "color.bt").write_bytes(raw.replace(b"id OcTree", b"id CountingOcTree"))
    for name, field in [("short", "truncated"), ("size", "size"), ("text", "not an OctoMap binary"),
                        ("color", "id")]:  # fmt: skip
        with pytest.raises(OctomapFileError, match=field) as err:
            read_bt(tmp_path / f"{name}.bt")
        assert f"{name}.bt" in str(err.value)


@pytest.mark.slow
def test_cli_import_then_export_gives_the_same_tree(tmp_path: Path):
    import subprocess
    import sys

    grid = Grid((-0.8, 0.0, 0.0), 0.2, (12, 10, 6))
    leaves = coverage_to_leaves(coverage_with(known_states(grid.shape, seed=5), grid))
    write_bt(tmp_path / "in.bt", leaves.resolution, leaves.key, leaves.occupied)

    def swarm(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run([sys.executable, "-m", "swarm.cli", *args], capture_output=True, text=True)

    done = swarm("map", "import", str(tmp_path / "in.bt"), "--out", str(tmp_path / "prior.npz"))
    assert done.returncode == 0, done.stderr
    done = swarm("map", "export", "--from", str(tmp_path / "prior.npz"), "--out", str(tmp_path / "out.bt"))
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "out.bt").read_bytes().split(b"\ndata\n")[1] == (
        tmp_path / "in.bt"
    ).read_bytes().split(b"\ndata\n")[1]
    from swarm.formats.map_export import export_coverage_map

    with pytest.raises(ValueError, match=r"x\.obj: the output must end in .npz .* or .bt"):
        export_coverage_map(tmp_path / "x.obj", coverage_with(known_states(grid.shape), grid))
