"""OctoMap's other files: full ``.ot`` trees and the ColorOcTree / OcTreeStamped types, as the
public reports show them (gaoxiang12/octomap_tutor#1: a ColorOcTree saved as ``.ot``;
floatlazer/semantic_slam#16: a ColorOcTree saved with writeBinary; felixendres/rgbdslam_v2#59:
a ``.ot`` with ``size 0``), checked against OctoMap itself (octomap-python)."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from swarm.formats.octomap_file import OctomapFileError, read_bt, read_octree, read_ot
from swarm.formats.octomap_map import leaves_to_states
from tests.support.paths import ROOT

octomap = pytest.importorskip("octomap", reason="octomap-python (pip install '.[bench]') writes the files")

SHARED_BT = ROOT / "data" / "octomap" / "geb079.bt"


def _states(path: Path):
    grid, states = leaves_to_states(read_octree(path))
    return grid, states


def _octomap_states(tree, grid) -> np.ndarray:
    out = np.zeros(grid.size, np.uint8)
    for n, centre in enumerate(grid.centres().reshape(-1, 3)):
        node = tree.search(centre)
        try:
            out[n] = 2 if tree.isNodeOccupied(node) else 1
        except octomap.NullPointerException:
            out[n] = 0
    return out.reshape(grid.shape)


@pytest.mark.slow
def test_ot_of_the_sample_map_gives_the_voxels_of_its_bt(tmp_path):
    """OctoMap's own write() of its sample map: every expanded voxel as the .bt gives it."""
    tree = octomap.OcTree(str(SHARED_BT).encode())
    tree.write(str(tmp_path / "geb079.ot").encode())
    want_grid, want = leaves_to_states(read_bt(SHARED_BT))
    got_grid, got = _states(tmp_path / "geb079.ot")
    assert got_grid == want_grid
    assert np.array_equal(got, want)


@pytest.mark.parametrize("kind", ["OcTree", "ColorOcTree"])
def test_ot_and_bt_of_a_scan_match_octomap_voxel_by_voxel(tmp_path, kind):
    rng = np.random.default_rng(7)
    tree = getattr(octomap, kind)(0.1)
    points = rng.uniform([-0.6, -0.4, 0.0], [0.6, 0.4, 0.5], (60, 3))
    if kind == "OcTree":
        tree.insertPointCloud(points, np.array([0.0, 0.0, 0.25]))  # free rays, occupied ends
    else:
        for p in points:
            tree.updateNode(p, bool(p[0] > 0))  # occupied and free leaves, not pruned
    tree.write(str(tmp_path / "t.ot").encode())
    tree.writeBinary(str(tmp_path / "t.bt").encode())  # (prunes the tree: after write)
    assert (tmp_path / "t.ot").read_bytes().startswith(b"# Octomap OcTree file\n")
    for name in ("t.ot", "t.bt"):
        grid, states = _states(tmp_path / name)
        assert np.count_nonzero(states == 2) > 0 and np.count_nonzero(states == 1) > 0
        assert np.array_equal(states, _octomap_states(tree, grid)), name


def test_empty_tree_is_refused_naming_the_file(tmp_path):
    """rgbdslam's failed save: a ColorOcTree .ot with size 0 and no data."""
    path = tmp_path / "empty.ot"
    path.write_bytes(b"# Octomap OcTree file\n# (feel free)\n#\nid ColorOcTree\nsize 0\nres 0.05\ndata\n")
    assert len(read_ot(path).key) == 0
    done = subprocess.run(
        [sys.executable, "-m", "swarm.cli", "map", "import", str(path), "--out", str(tmp_path / "p.npz")],
        capture_output=True,
        text=True,
    )
    assert done.returncode != 0 and "Traceback" not in done.stderr
    assert f"{path}: the octree has no known node" in done.stderr


@pytest.mark.slow
def test_cli_imports_a_color_ot(tmp_path):
    tree = octomap.ColorOcTree(0.1)
    for p in ([0.05, 0.05, 0.05], [0.35, 0.05, 0.05]):
        tree.updateNode(np.array(p), True)
    tree.write(str(tmp_path / "c.ot").encode())
    done = subprocess.run(
        [
            sys.executable,
            "-m",
            "swarm.cli",
            "map",
            "import",
            str(tmp_path / "c.ot"),
            "--out",
            str(tmp_path / "p.npz"),
        ],
        capture_output=True,
        text=True,
    )
    assert done.returncode == 0, done.stderr
    assert "2 occupied" in done.stdout


@pytest.mark.parametrize(
    ("content", "words"),
    [
        (b"# Octomap OcTree binary file", ["header ends after its first line"]),
        (
            b"# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\n",
            ["not an OctoMap file", "(.bt)", "(.ot)"],
        ),
        (
            b"# Octomap OcTree file\nid OcTree\nsize 3\nres 0.1\ndata\n" + bytes(4) + b"\x03" + bytes(1),
            ["truncated"],
        ),
        (
            b"# Octomap OcTree file\nid OcTree\nsize 5\nres 0.1\ndata\n" + bytes(5),
            ["size", "5 nodes", "holds 1"],
        ),
        (
            b"# Octomap OcTree file\nid CountingOcTree\nsize 1\nres 0.1\ndata\n" + bytes(5),
            ["id", "CountingOcTree"],
        ),
        (
            b"# Octomap OcTree file\nid OcTree\nsize 1\nres 0.1\ndata\n\x00\x00\xc0\x7f\x00",
            ["log-odds", "nan"],
        ),
        (b"# Octomap OcTree file\nid OcTree\nsize 1\nres -1\ndata\n" + bytes(5), ["res", "positive"]),
    ],
)
def test_broken_trees_are_refused_on_one_line_naming_the_field(tmp_path, content, words):
    path = tmp_path / "bad.ot"
    path.write_bytes(content)
    with pytest.raises(OctomapFileError) as info:
        read_octree(path)
    message = str(info.value)
    assert message.startswith(f"{path}: ") and "\n" not in message
    for word in words:
        assert word in message, message
