"""Point cloud files: PLY, text and NumPy read right, or refused naming the cause and the counts."""

import bz2

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from swarm.cli import main
from swarm.formats.point_cloud_file import PointCloudError, read_point_cloud, write_ply_points


def ply_header(fmt: str, count: int, extra: str = "") -> bytes:
    return (
        f"ply\nformat {fmt} 1.0\ncomment made by a test\n{extra}element vertex {count}\n"
        "property float x\nproperty float y\nproperty float z\nproperty uchar red\nend_header\n"
    ).encode()


def binary_vertices(points: np.ndarray, order: str) -> bytes:
    dtype = np.dtype([("x", order + "f4"), ("y", order + "f4"), ("z", order + "f4"), ("red", "u1")])
    data = np.zeros(len(points), dtype)
    data["x"], data["y"], data["z"] = points.T
    return data.tobytes()


finite32 = st.floats(-1e6, 1e6, width=32)


@given(points=arrays(np.float32, st.tuples(st.integers(1, 30), st.just(3)), elements=finite32))
@settings(max_examples=40, deadline=None)
def test_every_ply_form_reads_the_same_points(tmp_path_factory, points):
    folder = tmp_path_factory.mktemp("ply")
    n = len(points)
    (folder / "le.ply").write_bytes(ply_header("binary_little_endian", n) + binary_vertices(points, "<"))
    (folder / "be.ply").write_bytes(ply_header("binary_big_endian", n) + binary_vertices(points, ">"))
    text = "".join(f"{x!r} {y!r} {z!r} 7\n" for x, y, z in points.astype(float).tolist())
    (folder / "a.ply").write_bytes(ply_header("ascii", n) + text.encode())
    (folder / "p.xyz").write_text("# x y z\n" + text)
    write_ply_points(folder / "w.ply", points)
    for name in ("le.ply", "be.ply", "a.ply", "p.xyz", "w.ply"):
        np.testing.assert_array_equal(
            read_point_cloud(folder / name), points.astype(np.float64), err_msg=name
        )


def test_vertex_after_another_element(tmp_path):
    points = np.arange(6, dtype=np.float32).reshape(2, 3)
    extra = "element camera 1\nproperty float view_x\nproperty double view_y\n"
    camera = np.zeros(1, [("view_x", "<f4"), ("view_y", "<f8")]).tobytes()
    (tmp_path / "b.ply").write_bytes(
        ply_header("binary_little_endian", 2, extra) + camera + binary_vertices(points, "<")
    )
    np.testing.assert_array_equal(read_point_cloud(tmp_path / "b.ply"), points)
    (tmp_path / "a.ply").write_bytes(ply_header("ascii", 2, extra) + b"1 2\n0 1 2 0\n3 4 5 0\n")
    np.testing.assert_array_equal(read_point_cloud(tmp_path / "a.ply"), points)


def test_nan_points_are_kept_as_no_return(tmp_path):
    (tmp_path / "c.xyz").write_text("1 2 3\nnan nan nan\nNODE 0 0 0 0 0 0\n4 5 6\n")
    points = read_point_cloud(tmp_path / "c.xyz")
    assert (
        points.shape == (4, 3) and np.isnan(points[1:3]).any(axis=1).all() and points[3].tolist() == [4, 5, 6]
    )


GOOD = ply_header("binary_little_endian", 100) + binary_vertices(np.ones((100, 3), np.float32), "<")


@pytest.mark.parametrize(
    "name, content, words",
    [
        ("cut.ply", GOOD[:40], ["no end_header", "header line(s)", "cut short"]),
        ("noend.ply", GOOD.replace(b"end_header\n", b""), ["no end_header"]),
        (
            "short.ply",
            GOOD[: len(GOOD) - 13 * 40],
            ["100 vertices", "13 bytes", "1,300", "60 whole", "truncated"],
        ),
        ("ascii.ply", ply_header("ascii", 5) + b"1 2 3 0\n4 5 6 0\n", ["5 vertices", "holds 2", "truncated"]),
        (
            "fmt.ply",
            GOOD.replace(b"binary_little_endian", b"binary_middle_endian"),
            ["header line 2", "format"],
        ),
        ("type.ply", GOOD.replace(b"property uchar red", b"property colour red"), ["header line 8", "TYPE"]),
        ("count.ply", GOOD.replace(b"vertex 100", b"vertex many"), ["header line 4", "element NAME COUNT"]),
        ("noxyz.ply", GOOD.replace(b"property float z\n", b"property float w\n"), ["lacks property z"]),
        ("nov.ply", GOOD.replace(b"element vertex", b"element face"), ["no 'element vertex'", "face"]),
        ("magic.ply", b"PLY?\n" + GOOD[4:], ["not a PLY file"]),
        ("empty.ply", b"", ["no end_header", "0 header line(s)"]),
        ("empty.xyz", b"", ["holds no points"]),
        ("comments.xyz", b"# only a comment\n\n", ["holds no points"]),
        ("two.xyz", b"1 2 3\n4 5\n", ["line 2", "expected x y z", "2 value(s)"]),
        ("bad.npy", b"not numpy", ["cannot read point cloud"]),
    ],
)
def test_broken_clouds_name_the_cause_and_counts(tmp_path, name, content, words):
    path = tmp_path / name
    path.write_bytes(content)
    with pytest.raises(PointCloudError) as info:
        read_point_cloud(path)
    message = str(info.value)
    assert message.startswith(str(path)) and "\n" not in message, message
    for word in words:
        assert word in message, message


def test_empty_bz2_and_wrong_shape_npy(tmp_path):
    (tmp_path / "e.xyz.bz2").write_bytes(bz2.compress(b""))
    with pytest.raises(PointCloudError, match="holds no points"):
        read_point_cloud(tmp_path / "e.xyz.bz2")
    np.save(tmp_path / "p.npy", np.zeros((4, 2)))
    with pytest.raises(PointCloudError, match=r"expected N x 3 points, got shape \(4, 2\)"):
        read_point_cloud(tmp_path / "p.npy")
    assert read_point_cloud(tmp_path / "e.xyz.bz2", allow_empty=True).shape == (0, 3)


@pytest.mark.filterwarnings("error")
@pytest.mark.parametrize("name, content", [("cut.ply", GOOD[:40]), ("empty.xyz", b"")])
def test_ingest_of_a_broken_cloud_is_one_line_and_exit_2(tmp_path, capsys, name, content):
    (tmp_path / name).write_bytes(content)
    code = main(["ingest", str(tmp_path / name), "--out", str(tmp_path / "m.npz")])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and f"{tmp_path / name}: " in err, err
