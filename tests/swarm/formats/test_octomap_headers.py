"""``.bt`` headers OctoMap itself reads (``AbstractOccupancyOcTree::readBinary`` in OctoMap 1.x):
the deprecated ``id 1`` (read as ``OcTree``), any occupancy tree's id (its binary data is the
same), and the header-less legacy binary format (int32 3, float64 res, uint32 size), each
checked against OctoMap's own reader (octomap-python)."""

import struct
from pathlib import Path

import numpy as np
import pytest

from swarm.formats.octomap_file import OctomapFileError, read_octree, read_ot
from swarm.formats.octomap_map import leaves_to_states

octomap = pytest.importorskip("octomap", reason="octomap-python (pip install '.[bench]') writes the files")


def _scan_bt(tmp_path: Path) -> tuple[Path, int, bytes]:
    """A .bt of a small scan written by OctoMap; (path, node count, header-less tree data)."""
    tree = octomap.OcTree(0.1)
    points = np.random.default_rng(3).uniform([-0.5, -0.5, 0.0], [0.5, 0.5, 0.5], (40, 3))
    tree.insertPointCloud(points, np.array([0.0, 0.0, 0.2]))
    path = tmp_path / "scan.bt"
    tree.writeBinary(str(path).encode())
    raw = path.read_bytes()
    return path, tree.size(), raw[raw.index(b"\ndata\n") + len(b"\ndata\n") :]


@pytest.mark.parametrize("form", ["id 1", "id SemanticOcTree", "legacy"])
def test_bt_headers_octomap_reads_give_the_same_voxels(tmp_path, form):
    path, size, data = _scan_bt(tmp_path)
    other = tmp_path / "other.bt"
    if form == "legacy":
        other.write_bytes(struct.pack("<idI", 3, 0.1, size) + data)
    else:
        other.write_bytes(path.read_bytes().replace(b"id OcTree", form.encode()))
    check = octomap.OcTree(0.1)
    assert check.readBinary(str(other).encode()) and check.size() == size  # OctoMap reads it
    want_grid, want = leaves_to_states(read_octree(path))
    got_grid, got = leaves_to_states(read_octree(other))
    assert got_grid == want_grid
    assert np.array_equal(got, want)


def test_ot_with_the_deprecated_id_is_an_octree(tmp_path):
    tree = octomap.OcTree(0.1)
    tree.updateNode(np.array([0.05, 0.05, 0.05]), True)
    tree.write(str(tmp_path / "a.ot").encode())
    deprecated = tmp_path / "b.ot"
    deprecated.write_bytes((tmp_path / "a.ot").read_bytes().replace(b"id OcTree", b"id 1"))
    assert read_ot(deprecated).occupied.tolist() == read_ot(tmp_path / "a.ot").occupied.tolist()


@pytest.mark.parametrize(
    ("content", "words"),
    [
        (b"# Octomap OcTree binary file\nsize 0\nres 0.1\ndata\n", "id: only occupancy trees"),
        (struct.pack("<idI", 3, -0.1, 0), "res: must be a positive number"),
        (struct.pack("<idI", 3, 0.1, 5) + b"\x03", "data: the tree is truncated"),
        (struct.pack("<idI", 4, 0.1, 5), "not an OctoMap file"),
    ],
)
def test_headers_octomap_refuses_are_refused_naming_the_file(tmp_path, content, words):
    path = tmp_path / "bad.bt"
    path.write_bytes(content)
    with pytest.raises(OctomapFileError, match=words) as err:
        read_octree(path)
    assert str(path) in str(err.value) and "\n" not in str(err.value)
