"""PLY files with list properties, written here from the format's description (Paul Bourke's
"PLY - Polygon File Format"): a list is its count in the count type, then that many items; ASCII
bodies are numbers separated by white space, binary bodies packed in the file's byte order.
CloudCompare writes vertex elements with list properties (``property list uchar float
scalar_...``) and meshes put faces (``property list uchar int vertex_indices``) after them."""

from __future__ import annotations

import struct

import numpy as np
import pytest

from swarm.formats.point_cloud_file import PointCloudError, read_ply_vertices, read_point_cloud

STRUCT = {"char": "b", "uchar": "B", "short": "h", "ushort": "H", "int": "i", "uint": "I", "float": "f",
          "double": "d", "int8": "b", "uint8": "B", "int32": "i", "float32": "f", "float64": "d"}  # fmt: skip


def write_ply(fmt: str, elements: list[tuple[str, list[tuple], list[list]]]) -> bytes:
    """A PLY file: ``elements`` are (name, properties, instances), a property ("TYPE", name) or
    ("list", COUNT_TYPE, ITEM_TYPE, name), an instance its values in order (a list: a list).
    Written value by value with ``struct``, independently of the reader."""
    header = ["ply", f"format {fmt} 1.0", "comment written by the test from the PLY format"]
    for name, props, instances in elements:
        header.append(f"element {name} {len(instances)}")
        header += [f"property {' '.join(p)}" for p in props]
    out = ("\n".join([*header, "end_header"]) + "\n").encode()
    order = {"binary_little_endian": "<", "binary_big_endian": ">"}.get(fmt)
    for _name, props, instances in elements:
        for values in instances:
            if order is None:
                words = []
                for p, v in zip(props, values, strict=True):
                    words += [str(len(v)), *map(repr, v)] if p[0] == "list" else [repr(v)]
                out += (" ".join(words) + "\n").encode()
                continue
            for p, v in zip(props, values, strict=True):
                if p[0] == "list":
                    out += struct.pack(order + STRUCT[p[1]], len(v))
                    out += struct.pack(order + STRUCT[p[2]] * len(v), *v)
                else:
                    out += struct.pack(order + STRUCT[p[0]], v)
    return out


VERTEX = [("float", "x"), ("float", "y"), ("float", "z"), ("list", "uchar", "float", "scalar_feature"),
          ("float", "intensity")]  # fmt: skip
FACE = [("list", "uchar", "int", "vertex_indices")]
FORMATS = ("ascii", "binary_little_endian", "binary_big_endian")


def _cloud(n: int, lengths) -> list[list]:
    rng = np.random.default_rng(n)
    xyz = rng.uniform(-5, 5, (n, 3)).astype(np.float32)
    lists = [[float(np.float32(0.5 * k)) for k in range(lengths(i))] for i in range(n)]
    return [[*map(float, xyz[i]), lists[i], float(np.float32(i))] for i in range(n)]


@pytest.mark.parametrize("fmt", FORMATS)
@pytest.mark.parametrize("lengths", [lambda i: 3, lambda i: i % 4], ids=["same-length", "varying"])
def test_a_vertex_with_a_list_property_and_faces_after_it(tmp_path, fmt, lengths) -> None:
    vertices = _cloud(25, lengths)
    faces = [[[0, 1, 2]], [[2, 3, 4, 5]]]
    path = tmp_path / "cloudcompare.ply"
    path.write_bytes(write_ply(fmt, [("vertex", VERTEX, vertices), ("face", FACE, faces)]))
    got = read_ply_vertices(path)
    assert list(got) == ["x", "y", "z", "intensity"]  # the scalars, in file order; the list skipped
    expected = np.array([[v[0], v[1], v[2], v[4]] for v in vertices])
    np.testing.assert_array_equal(np.stack([got[k] for k in got], axis=1).astype(np.float64), expected)
    np.testing.assert_array_equal(read_point_cloud(path), expected[:, :3])


@pytest.mark.parametrize("fmt", FORMATS)
def test_an_element_with_lists_before_the_vertices(tmp_path, fmt) -> None:
    camera = [("list", "ushort", "double", "view"), ("int", "id")]
    cams = [[[1.0, 2.0], 7], [[], 8], [[3.0, 4.0, 5.0], 9]]
    vertices = [[1.5, 2.5, 3.5], [-1.0, 0.0, 1.0]]
    xyz = [("float", "x"), ("float", "y"), ("float", "z")]
    path = tmp_path / "cams.ply"
    path.write_bytes(write_ply(fmt, [("camera", camera, cams), ("vertex", xyz, vertices)]))
    np.testing.assert_array_equal(read_point_cloud(path), np.array(vertices))


def test_ascii_instances_are_a_stream_of_numbers_not_lines(tmp_path) -> None:
    header = write_ply("ascii", [("vertex", VERTEX, [])]).replace(b"element vertex 0", b"element vertex 3")
    body = b"0 1 2 2 0.5 0.25\n 9   3 4 5 0 8 6 7\n8 1 0.5 7\n"  # one vertex over two lines, two on one
    (tmp_path / "s.ply").write_bytes(header + body)
    got = read_ply_vertices(tmp_path / "s.ply")
    np.testing.assert_array_equal(got["x"], [0, 3, 6]) and np.testing.assert_array_equal(
        got["intensity"], [9, 8, 7]
    )
    np.testing.assert_array_equal(got["z"], [2, 5, 8])


@pytest.mark.parametrize(
    "fmt, cut, words",
    [
        ("binary_little_endian", 7, ["25 vertices", "truncated"]),
        ("binary_big_endian", 30, ["25 vertices", "truncated"]),
        ("ascii", 12, ["25 vertices", "truncated"]),
    ],
)
def test_a_cut_file_with_lists_is_refused_as_truncated(tmp_path, fmt, cut, words) -> None:
    data = write_ply(fmt, [("vertex", VERTEX, _cloud(25, lambda i: i % 4))])
    (tmp_path / "cut.ply").write_bytes(data[:-cut])
    with pytest.raises(PointCloudError) as refused:
        read_ply_vertices(tmp_path / "cut.ply")
    assert all(w in str(refused.value) for w in ["cut.ply", *words]), refused.value


def test_bad_list_counts_and_types_are_refused_naming_the_place(tmp_path) -> None:
    header = write_ply("ascii", [("vertex", VERTEX, [])]).replace(b"element vertex 0", b"element vertex 1")
    (tmp_path / "neg.ply").write_bytes(header + b"1 2 3 -2 5\n")
    with pytest.raises(
        PointCloudError, match=r"neg.ply: body: vertex 0: a list's count must be a whole number"
    ):
        read_ply_vertices(tmp_path / "neg.ply")
    (tmp_path / "ft.ply").write_bytes(
        header.replace(b"list uchar float", b"list float float") + b"1 2 3 0 5\n"
    )
    with pytest.raises(
        PointCloudError, match=r"ft.ply: header line 8: a list's count type must be an integer"
    ):
        read_ply_vertices(tmp_path / "ft.ply")
