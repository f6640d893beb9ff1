"""Reading point clouds: .npy/.npz (N x 3), ASCII ``x y z`` lines (plain or .bz2/.gz), PLY and
PCL's PCD (``swarm.formats.pcd_file``).

Every problem raises :class:`PointCloudError` with one line naming the file, where in it
(the header line, the data line, the element) and the counts involved, e.g.
``scan.ply: body: the header announces 1,000 vertices of 12 bytes (12,000 bytes), the file
holds 6,000 after the header (500 whole vertices); the file is truncated``.

NaN and infinite coordinates are read as they are: they mean "no return" and the fusion
skips and counts them. In text files a value that is not a number (e.g. the ``NODE`` lines
of OctoMap's scan graphs) reads as NaN too, and is counted the same way.

PLY: the format of the Stanford PLY files (``ply``, ``format``, ``element``, ``property``,
``comment``/``obj_info``, ``end_header``), ASCII or binary of either byte order; the
``vertex`` element may come after other elements, and only its x, y, z are kept.
"""

from __future__ import annotations

import bz2
import gzip
import io
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from swarm.formats.errors import InputError
from swarm.formats.pcd_file import is_pcd, read_pcd


class PointCloudError(InputError):
    """A point cloud file that cannot be read: the file, the place and the counts named."""


def read_point_cloud(path: str | Path, *, allow_empty: bool = False) -> np.ndarray:
    """Points (N, 3) float64 from a file; the format follows the file name.

    A file with no points raises PointCloudError unless ``allow_empty``.
    """
    path = Path(path)
    if not path.exists():
        raise PointCloudError(f"{path}: no such file")
    if path.is_dir():
        raise PointCloudError(f"{path}: is a folder, not a point cloud file")
    name = path.name.lower()
    try:
        if name.endswith(".npy"):
            points = _check_array(np.load(path, allow_pickle=False), path, "array")
        elif name.endswith(".npz"):
            with np.load(path, allow_pickle=False) as data:
                if not data.files:
                    raise PointCloudError(f"{path}: the .npz holds no arrays")
                key = "points" if "points" in data.files else data.files[0]
                points = _check_array(data[key], path, key)
        elif name.endswith(".ply"):
            points = _read_ply(path)
        elif name.endswith(".pcd") or _starts_as_pcd(path):
            points = read_pcd(path, PointCloudError)
        else:
            points = _read_xyz(path)
    except PointCloudError:
        raise
    except (OSError, EOFError, ValueError) as exc:
        raise PointCloudError(f"{path}: cannot read point cloud: {' '.join(str(exc).split())}") from exc
    if len(points) == 0 and not allow_empty:
        raise PointCloudError(f"{path}: the file holds no points")
    return np.ascontiguousarray(points[:, :3], dtype=np.float64)


def _starts_as_pcd(path: Path) -> bool:
    if path.name.lower().endswith((".gz", ".bz2")):
        return False
    with open(path, "rb") as f:
        return is_pcd(f.read(256))


def _check_array(array: np.ndarray, path: Path, key: str) -> np.ndarray:
    if array.dtype.kind not in "fiu":
        raise PointCloudError(f"{path}: {key}: expected numbers, got an array of {array.dtype}")
    if array.ndim != 2 or array.shape[1] < 3:
        raise PointCloudError(f"{path}: {key}: expected N x 3 points, got shape {array.shape}")
    return array.astype(np.float64)


# -- ASCII x y z -----------------------------------------------------------------------------


def _open_text(path: Path):
    name = path.name.lower()
    if name.endswith(".bz2"):
        return bz2.open(path, "rt", encoding="utf-8", errors="replace")
    if name.endswith(".gz"):
        return gzip.open(path, "rt", encoding="utf-8", errors="replace")
    return open(path, encoding="utf-8", errors="replace")


def _read_xyz(path: Path) -> np.ndarray:
    """ASCII lines 'x y z [...]'; '#' starts a comment; values that are not numbers become NaN."""
    with _open_text(path) as f:
        text = f.read()
    try:  # the fast path: every data line holds numbers only, at least three
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return np.loadtxt(io.StringIO(text), comments="#", usecols=(0, 1, 2), ndmin=2, dtype=np.float64)
    except ValueError:
        pass
    rows = []
    for number, line in enumerate(text.splitlines(), 1):
        words = line.split("#", 1)[0].split()
        if not words:
            continue
        if len(words) < 3:
            raise PointCloudError(
                f"{path}: line {number}: expected x y z, got {len(words)} value(s): {line[:60]!r}"
            )
        rows.append([_number(w) for w in words[:3]])
    return np.asarray(rows, dtype=np.float64).reshape(-1, 3)


def _number(word: str) -> float:
    try:
        return float(word)
    except ValueError:
        return float("nan")


# -- PLY -------------------------------------------------------------------------------------

_PLY_TYPES = {
    "char": "i1", "uchar": "u1", "int8": "i1", "uint8": "u1",
    "short": "i2", "ushort": "u2", "int16": "i2", "uint16": "u2",
    "int": "i4", "uint": "u4", "int32": "i4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}  # fmt: skip
_PLY_FORMATS = {"ascii": "", "binary_little_endian": "<", "binary_big_endian": ">"}
#: A header longer than this is taken for a file that is not PLY.
_MAX_HEADER_LINES = 10_000


@dataclass
class _Element:
    name: str
    count: int
    scalars: list[tuple[str, str]] = field(default_factory=list)
    lists: list[str] = field(default_factory=list)


@dataclass
class _PlyHeader:
    fmt: str
    elements: list[_Element]
    size: int  # bytes up to and including the end_header line


def _read_ply(path: Path) -> np.ndarray:
    """The x, y, z properties of the vertex element of an ASCII or binary PLY file."""
    data = path.read_bytes()
    header = _parse_ply_header(data, path)
    vertex_at = next((i for i, e in enumerate(header.elements) if e.name == "vertex"), None)
    if vertex_at is None:
        names = ", ".join(e.name for e in header.elements) or "none"
        raise PointCloudError(f"{path}: header: no 'element vertex' (elements: {names})")
    vertex = header.elements[vertex_at]
    names = [n for n, _ in vertex.scalars]
    missing = [c for c in "xyz" if c not in names]
    if missing:
        raise PointCloudError(
            f"{path}: header: element vertex lacks propert{'y' if len(missing) == 1 else 'ies'} "
            f"{', '.join(missing)} (has {', '.join(names) or 'none'})"
        )
    if header.fmt == "ascii":
        return _ply_ascii_vertices(data[header.size :], header.elements, vertex_at, path)
    table = _ply_binary_table(data[header.size :], header, vertex_at, path)
    return np.stack([table[c].astype(np.float64) for c in "xyz"], axis=1)


def read_ply_vertices(path: str | Path) -> dict[str, np.ndarray]:
    """Every scalar property of the vertex element of a PLY file, by name, in file order.

    ASCII (as float64) and binary files (in the file's types); other elements, such as the
    faces after the vertices, are skipped. Raises PointCloudError naming the file and what
    is wrong, as :func:`read_point_cloud` does.
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise PointCloudError(f"{path}: cannot read: {exc}") from exc
    header = _parse_ply_header(data, path)
    vertex_at = next((i for i, e in enumerate(header.elements) if e.name == "vertex"), None)
    if vertex_at is None:
        raise PointCloudError(f"{path}: header: no 'element vertex'")
    names = [n for n, _ in header.elements[vertex_at].scalars]
    if header.fmt == "ascii":
        rows = _ply_ascii_vertices(data[header.size :], header.elements, vertex_at, path, names)
        return {n: rows[:, i] for i, n in enumerate(names)}
    table = _ply_binary_table(data[header.size :], header, vertex_at, path)
    return {n: table[n].astype(table[n].dtype.newbyteorder("=")) for n in names}


def _parse_ply_header(data: bytes, path: Path) -> _PlyHeader:
    end = 0
    lines: list[str] = []
    while True:
        nl = data.find(b"\n", end)
        if nl < 0:
            last = data[end:].decode("ascii", "replace").strip()
            cut = f" (the last, cut short: {last[:40]!r})" if last else ""
            raise PointCloudError(
                f"{path}: header: no end_header line; the file ends after {len(lines)} header line(s){cut}"
            )
        lines.append(data[end:nl].decode("ascii", "replace").strip())
        end = nl + 1
        if lines[-1] == "end_header" or len(lines) > _MAX_HEADER_LINES:
            break
    if lines[0] != "ply":
        raise PointCloudError(f"{path}: not a PLY file (the first line is not 'ply')")
    if lines[-1] != "end_header":
        raise PointCloudError(f"{path}: header: no end_header line in the first {_MAX_HEADER_LINES:,} lines")
    fmt = None
    elements: list[_Element] = []
    for number, line in enumerate(lines[1:-1], 2):
        words = line.split()
        where = f"{path}: header line {number}"
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "format":
            if len(words) != 3 or words[1] not in _PLY_FORMATS:
                raise PointCloudError(
                    f"{where}: format must be one of {', '.join(_PLY_FORMATS)}, got {line!r}"
                )
            fmt = words[1]
        elif words[0] == "element":
            if len(words) != 3 or not words[2].isdigit():
                raise PointCloudError(f"{where}: expected 'element NAME COUNT', got {line!r}")
            elements.append(_Element(words[1], int(words[2])))
        elif words[0] == "property":
            if not elements:
                raise PointCloudError(f"{where}: a property before any element")
            if len(words) == 5 and words[1] == "list":
                if words[2] not in _PLY_TYPES or words[3] not in _PLY_TYPES:
                    raise PointCloudError(f"{where}: unknown list types in {line!r}")
                elements[-1].lists.append(words[4])
                elements[-1].scalars.append((words[4], f"list {words[2]} {words[3]}"))
            elif len(words) == 3 and words[1] in _PLY_TYPES:
                elements[-1].scalars.append((words[2], _PLY_TYPES[words[1]]))
            else:
                raise PointCloudError(
                    f"{where}: expected 'property TYPE NAME' with TYPE one of "
                    f"{', '.join(sorted(set(_PLY_TYPES)))}, got {line!r}"
                )
        else:
            raise PointCloudError(f"{where}: unknown keyword {words[0]!r}")
    if fmt is None:
        raise PointCloudError(f"{path}: header: no format line")
    return _PlyHeader(fmt, elements, end)


def _ply_ascii_vertices(
    body: bytes, elements: list[_Element], vertex_at: int, path: Path, wanted: list[str] | None = None
) -> np.ndarray:
    """The ``wanted`` columns (default x, y, z) of the vertices of an ASCII PLY, (count, len(wanted))."""
    lines = [line for line in body.decode("ascii", "replace").splitlines() if line.strip()]
    skip = sum(e.count for e in elements[:vertex_at])
    vertex = elements[vertex_at]
    got = max(len(lines) - skip, 0)
    if got < vertex.count:
        raise PointCloudError(
            f"{path}: body: the header announces {vertex.count:,} vertices, the file holds {got:,} "
            f"vertex line(s); the file is truncated"
        )
    names = [n for n, _ in vertex.scalars]
    wanted = list(wanted or "xyz")
    columns = [names.index(c) for c in wanted]
    if vertex.lists and max(columns) > names.index(vertex.lists[0]):
        raise PointCloudError(
            f"{path}: header: properties after the list property {vertex.lists[0]!r} are not supported"
        )
    points = np.empty((vertex.count, len(columns)))
    for i, line in enumerate(lines[skip : skip + vertex.count]):
        words = line.split()
        if len(words) <= max(columns):
            raise PointCloudError(
                f"{path}: body: vertex {i} has {len(words)} value(s), the header announces {len(names)}"
            )
        try:
            points[i] = [float(words[c]) for c in columns]
        except ValueError:
            raise PointCloudError(f"{path}: body: vertex {i}: not a number in {line[:60]!r}") from None
    return points


def _ply_binary_table(body: bytes, header: _PlyHeader, vertex_at: int, path: Path) -> np.ndarray:
    """The vertex element of a binary PLY as a structured array in the file's byte order."""
    order = _PLY_FORMATS[header.fmt]
    offset = 0
    for element in header.elements[:vertex_at]:
        if element.lists:
            raise PointCloudError(
                f"{path}: header: element {element.name!r} before vertex has list properties; "
                "only fixed-size elements may come before vertex in a binary PLY"
            )
        offset += _dtype(element, order).itemsize * element.count
    vertex = header.elements[vertex_at]
    if vertex.lists:
        raise PointCloudError(
            f"{path}: header: list property {vertex.lists[0]!r} in element vertex is not supported"
        )
    dtype = _dtype(vertex, order)
    need = dtype.itemsize * vertex.count
    got = max(len(body) - offset, 0)
    if got < need:
        raise PointCloudError(
            f"{path}: body: the header announces {vertex.count:,} vertices of {dtype.itemsize} bytes "
            f"({need:,} bytes), the file holds {got:,} ({got // dtype.itemsize:,} whole vertices); "
            "the file is truncated"
        )
    return np.frombuffer(body, dtype=dtype, count=vertex.count, offset=offset)


def _dtype(element: _Element, order: str) -> np.dtype:
    return np.dtype([(name, order + kind) for name, kind in element.scalars])


def write_ply_points(path: str | Path, points: np.ndarray, values: np.ndarray | None = None) -> None:
    """A binary little-endian PLY of points, with an optional float property ``value``."""
    points = np.asarray(points, dtype=np.float32).reshape(-1, 3)
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    if values is not None:
        fields.append(("value", "<f4"))
    data = np.empty(len(points), dtype=fields)
    data["x"], data["y"], data["z"] = points.T
    if values is not None:
        data["value"] = values
    header = ["ply", "format binary_little_endian 1.0", f"element vertex {len(points)}"]
    header += [f"property float {n}" for n, _ in fields] + ["end_header"]
    with open(path, "wb") as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        f.write(data.tobytes())
