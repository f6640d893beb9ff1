"""PCL's .pcd point clouds (ascii, binary, binary_compressed), written by other code (pypcd4,
liblzf: tests/data/pcd/README.md). A .pcd was read as 'x y z' text and refused as
'line 2: expected x y z, got 2 value(s): VERSION 0.7'."""

import json

import numpy as np
import pytest

from swarm.cli import main
from swarm.formats.pcd_file import lzf_decompress
from swarm.formats.point_cloud_file import PointCloudError, read_point_cloud
from tests.support.paths import TEST_DATA

DATA = TEST_DATA / "pcd"


@pytest.mark.parametrize("name", ["xyzir_ascii.pcd", "xyzir_binary.pcd", "xyzir_binary_compressed.pcd"])
def test_each_pcd_encoding_gives_the_points_written(name):
    want = np.load(DATA / "xyzir_xyz.npy").astype(np.float64)
    got = read_point_cloud(DATA / name)
    assert got.shape == (50, 3) and np.isnan(got[7]).all()
    np.testing.assert_allclose(got, want, atol=1e-6 if "ascii" in name else 0, equal_nan=True)


def test_an_organised_compressed_cloud_keeps_its_nan_pixels():
    got = read_point_cloud(DATA / "organised.pcd")
    grid = got.reshape(64, 32, 3)
    assert np.isnan(grid[::2]).all() and np.isfinite(grid[1::2]).all()
    np.testing.assert_allclose(grid[1, :, 0], np.linspace(0, 1, 32).astype(np.float32))


def test_a_pcd_without_the_suffix_is_told_by_its_header(tmp_path):
    path = tmp_path / "cloud.txt"
    path.write_bytes((DATA / "xyzir_binary.pcd").read_bytes())
    assert read_point_cloud(path).shape == (50, 3)


def test_lzf_overlapping_back_references():
    # literal 'ab', then copy 8 bytes from 2 back (overlapping): 'ab' * 5
    assert lzf_decompress(bytes([1]) + b"ab" + bytes([6 << 5, 1]), 10) == b"ab" * 5


def _as_two_ascii_points(head: bytes, body: bytes) -> tuple[bytes, bytes]:
    head = head.replace(b"DATA binary", b"DATA ascii").replace(b"WIDTH 50", b"WIDTH 2")
    return head.replace(b"POINTS 50", b"POINTS 2"), b"1 2 3 0.5 1\n4 5\n"


@pytest.mark.parametrize(
    ("edit", "words"),
    [
        (lambda h, b: (h.replace(b"POINTS 50", b"POINTS 60"), b), ["POINTS: 60 is not WIDTH x HEIGHT"]),
        (lambda h, b: (h, b[:-100]), ["DATA binary", "truncated"]),
        (lambda h, b: (h.replace(b"TYPE F F F F U", b"TYPE F F F F Q"), b), ["field 'ring'", "TYPE Q"]),
        (lambda h, b: (h.replace(b"FIELDS x y z", b"FIELDS a b c"), b), ["FIELDS: no x, y, z"]),
        (lambda h, b: (h.replace(b"DATA binary", b"DATA binary_lz4"), b), ["DATA: 'binary_lz4'"]),
        (_as_two_ascii_points, ["point 1 has 2 values"]),
    ],
)
def test_broken_pcds_are_refused_on_one_line(tmp_path, edit, words):
    head, body = (DATA / "xyzir_binary.pcd").read_bytes().split(b"\nDATA binary\n", 1)
    head, body = edit(head + b"\nDATA binary\n", body)
    path = tmp_path / "bad.pcd"
    path.write_bytes(head + body)
    with pytest.raises(PointCloudError) as info:
        read_point_cloud(path)
    message = str(info.value)
    assert message.startswith(f"{path}: ") and "\n" not in message
    for word in words:
        assert word in message, message


def test_damaged_compressed_data_is_refused(tmp_path):
    raw = bytearray((DATA / "xyzir_binary_compressed.pcd").read_bytes())
    raw[-40:] = bytes(40)  # zeros: literal runs that overrun the end
    path = tmp_path / "bad.pcd"
    path.write_bytes(bytes(raw))
    with pytest.raises(PointCloudError, match=r"bad.pcd: DATA binary_compressed: "):
        read_point_cloud(path)


def test_swarm_ingest_reads_a_pcd(tmp_path, capsys):
    out = tmp_path / "map.npz"
    code = main(["ingest", str(DATA / "xyzir_binary_compressed.pcd"), "--out", str(out), "--json"])
    assert code == 0 and out.is_file()
    report = json.loads(capsys.readouterr().out)
    assert report["points"] == 50 and report["skipped_nonfinite"] == 1  # point 7 is NaN


def test_binary_compressed_data_stored_uncompressed_is_read(tmp_path):
    """MapIV/pypcd4#37: a writer that found LZF no smaller stored the raw bytes in the
    binary_compressed layout (both sizes equal)."""
    head, body = (DATA / "xyzir_binary.pcd").read_bytes().split(b"DATA binary\n", 1)
    record = np.dtype([("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("intensity", "<f4"), ("ring", "<u2")])
    table = np.frombuffer(body, record, 50)
    fields = b"".join(table[n].tobytes() for n in record.names)
    sizes = np.array([len(fields), len(fields)], "<u4").tobytes()
    path = tmp_path / "stored.pcd"
    path.write_bytes(head + b"DATA binary_compressed\n" + sizes + fields)
    np.testing.assert_array_equal(read_point_cloud(path), read_point_cloud(DATA / "xyzir_binary.pcd"))


@pytest.mark.parametrize("encoding", ["ascii", "binary", "binary_compressed"])
def test_padding_fields_and_counts_are_skipped_over(tmp_path, encoding):
    """PDAL/PDAL#3255, mrdoob/three.js#24278: '_' padding and COUNT > 1 shift the x, y, z that
    follow them; a reader that assumed 4-byte single fields read the wrong bytes."""
    rng = np.random.default_rng(4)
    record = np.dtype([("_", "<u1", (3,)), ("x", "<f4"), ("normal", "<f4", (3,)), ("y", "<f8"), ("z", "<f4")])
    table = np.zeros(6, record)
    table["_"] = 7
    for name in ("x", "y", "z"):
        table[name] = rng.uniform(-3, 3, 6)
    table["normal"] = 1.0
    head = (
        "VERSION .7\nFIELDS _ x normal y z\nSIZE 1 4 4 8 4\nTYPE U F F F F\nCOUNT 3 1 3 1 1\n"
        f"WIDTH 3\nHEIGHT 2\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 6\nDATA {encoding}\n"
    ).encode()
    if encoding == "ascii":
        rows = [f"7 7 7 {float(r['x'])!r} 1 1 1 {float(r['y'])!r} {float(r['z'])!r}\n" for r in table]
        body = "".join(rows).encode()
    elif encoding == "binary":
        body = table.tobytes()
    else:  # an LZF stream of literal runs (up to 32 bytes each, a length byte before)
        fields = b"".join(table[n].tobytes() for n in record.names)
        runs = [fields[i : i + 32] for i in range(0, len(fields), 32)]
        packed = b"".join(bytes([len(run) - 1]) + run for run in runs)
        body = np.array([len(packed), len(fields)], "<u4").tobytes() + packed
    path = tmp_path / "padded.pcd"
    path.write_bytes(head + body)
    want = np.stack([table[c].astype(np.float64) for c in "xyz"], axis=1)
    np.testing.assert_allclose(read_point_cloud(path), want, rtol=1e-6)
