"""Reading the vertices of a PLY file (Greg Turk's polygon file format, as Paul Bourke's page
describes it: http://paulbourke.net/dataformats/ply/).

A PLY file is a header of lines (``ply``; ``format ascii|binary_little_endian|binary_big_endian
1.0``; ``comment`` and ``obj_info`` lines; ``element NAME COUNT`` each followed by its
``property TYPE NAME`` and ``property list COUNT_TYPE ITEM_TYPE NAME`` lines; ``end_header``)
and then the elements' instances in header order: in ASCII a stream of numbers separated by
white space (a list property is its count, then that many items), in binary the values packed
in the file's byte order (a list: the count in its type, then the items). TYPE is one of
``char uchar short ushort int uint float double`` or ``int8 uint8 int16 uint16 int32 uint32
float32 float64``.

:func:`read_ply_vertices` returns every scalar property of the ``vertex`` element, which may
come after other elements and may hold list properties (CloudCompare writes ``property list
uchar float scalar_...``); elements after it (faces) are not read. Every problem raises
:class:`~swarm.formats.point_cloud_file.PointCloudError` naming the file, where in it and the
counts involved.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

_TYPES = {
    "char": "i1", "uchar": "u1", "int8": "i1", "uint8": "u1",
    "short": "i2", "ushort": "u2", "int16": "i2", "uint16": "u2",
    "int": "i4", "uint": "u4", "int32": "i4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}  # fmt: skip
_FORMATS = {"ascii": "", "binary_little_endian": "<", "binary_big_endian": ">"}
_STRUCT = {"i1": "b", "u1": "B", "i2": "h", "u2": "H", "i4": "i", "u4": "I", "f4": "f", "f8": "d"}
#: A header longer than this is taken for a file that is not PLY.
MAX_HEADER_LINES = 10_000


@dataclass
class PlyProperty:
    """A property: its name, the numpy type of its value (of a list's items), and for a list
    property the numpy type of its count (None for a scalar)."""

    name: str
    kind: str
    count_kind: str | None = None


@dataclass
class PlyElement:
    name: str
    count: int
    properties: list[PlyProperty] = field(default_factory=list)

    @property
    def has_lists(self) -> bool:
        return any(p.count_kind is not None for p in self.properties)

    @property
    def scalars(self) -> list[str]:
        return [p.name for p in self.properties if p.count_kind is None]


@dataclass
class PlyHeader:
    fmt: str
    elements: list[PlyElement]
    size: int  # bytes up to and including the end_header line


def read_ply_vertices(path: str | Path, error: type[Exception]) -> dict[str, np.ndarray]:
    """Every scalar property of the vertex element of a PLY file, by name, in file order: as
    float64 from ASCII, in the file's types (native byte order) from binary. Raises ``error``
    (a one-line message: the file, the place, the counts) for whatever is wrong."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise error(f"{path}: cannot read: {exc}") from exc
    header = parse_header(data, path, error)
    at = next((i for i, e in enumerate(header.elements) if e.name == "vertex"), None)
    if at is None:
        names = ", ".join(e.name for e in header.elements) or "none"
        raise error(f"{path}: header: no 'element vertex' (elements: {names})")
    body = data[header.size :]
    if header.fmt == "ascii":
        return _ascii_vertices(body, header.elements, at, path, error)
    return _binary_vertices(body, header.elements, at, _FORMATS[header.fmt], path, error)


def parse_header(data: bytes, path: Path, error: type[Exception]) -> PlyHeader:
    """The header of a PLY file's bytes; ``error`` names the header line that is wrong."""
    end = 0
    lines: list[str] = []
    while True:
        nl = data.find(b"\n", end)
        if nl < 0:
            last = data[end:].decode("ascii", "replace").strip()
            cut = f" (the last, cut short: {last[:40]!r})" if last else ""
            raise error(
                f"{path}: header: no end_header line; the file ends after {len(lines)} header line(s){cut}"
            )
        lines.append(data[end:nl].decode("ascii", "replace").strip())
        end = nl + 1
        if lines[-1] == "end_header" or len(lines) > MAX_HEADER_LINES:
            break
    if lines[0] != "ply":
        raise error(f"{path}: not a PLY file (the first line is not 'ply')")
    if lines[-1] != "end_header":
        raise error(f"{path}: header: no end_header line in the first {MAX_HEADER_LINES:,} lines")
    fmt = None
    elements: list[PlyElement] = []
    types = ", ".join(sorted(set(_TYPES)))
    for number, line in enumerate(lines[1:-1], 2):
        words = line.split()
        where = f"{path}: header line {number}"
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "format":
            if len(words) != 3 or words[1] not in _FORMATS:
                raise error(f"{where}: format must be one of {', '.join(_FORMATS)}, got {line!r}")
            fmt = words[1]
        elif words[0] == "element":
            if len(words) != 3 or not words[2].isdigit():
                raise error(f"{where}: expected 'element NAME COUNT', got {line!r}")
            elements.append(PlyElement(words[1], int(words[2])))
        elif words[0] == "property":
            if not elements:
                raise error(f"{where}: a property before any element")
            if len(words) == 5 and words[1] == "list":
                if words[2] not in _TYPES or words[3] not in _TYPES:
                    raise error(f"{where}: unknown list types in {line!r} (TYPE is one of {types})")
                if _TYPES[words[2]][0] not in "iu":
                    raise error(f"{where}: a list's count type must be an integer type, got {words[2]!r}")
                elements[-1].properties.append(PlyProperty(words[4], _TYPES[words[3]], _TYPES[words[2]]))
            elif len(words) == 3 and words[1] in _TYPES:
                elements[-1].properties.append(PlyProperty(words[2], _TYPES[words[1]]))
            else:
                raise error(
                    f"{where}: expected 'property TYPE NAME' or 'property list COUNT_TYPE TYPE NAME' with "
                    f"TYPE one of {types}, got {line!r}"
                )
        else:
            raise error(f"{where}: unknown keyword {words[0]!r}")
    if fmt is None:
        raise error(f"{path}: header: no format line")
    return PlyHeader(fmt, elements, end)


# -- ASCII: a stream of numbers --------------------------------------------------------------


def _ascii_vertices(
    body: bytes, elements: list[PlyElement], at: int, path: Path, error
) -> dict[str, np.ndarray]:
    tokens = body.split()
    pos = 0
    for element in elements[:at]:
        pos = _ascii_element(tokens, pos, element, None, path, error)
    vertex = elements[at]
    rows: list[list[bytes]] = []
    _ascii_element(tokens, pos, vertex, rows, path, error)
    names = vertex.scalars
    try:
        values = np.array(rows, dtype=np.float64).reshape(vertex.count, len(names))
    except ValueError:
        bad = next(i for i, row in enumerate(rows) if not all(_is_number(w) for w in row))
        shown = b" ".join(rows[bad]).decode("ascii", "replace")[:60]
        raise error(f"{path}: body: vertex {bad}: not a number in {shown!r}") from None
    return {name: values[:, i] for i, name in enumerate(names)}


def _ascii_element(tokens: list[bytes], pos: int, element: PlyElement, rows, path: Path, error) -> int:
    """Walk one element's instances from token ``pos``; append each instance's scalar values to
    ``rows`` (when given); return the position after the element."""
    n = len(element.properties)
    if not element.has_lists:
        end = pos + n * element.count
        if end > len(tokens):
            _ascii_truncated(element, (len(tokens) - pos) // max(n, 1), len(tokens) - pos, path, error)
        if rows is not None:
            rows.extend(tokens[i : i + n] for i in range(pos, end, n))
        return end
    scalar = [p.count_kind is None for p in element.properties]
    for instance in range(element.count):
        row = []
        start = pos
        for is_scalar in scalar:
            if pos >= len(tokens):
                _ascii_truncated(element, instance, len(tokens) - start, path, error)
            if is_scalar:
                row.append(tokens[pos])
                pos += 1
                continue
            length = _list_length(tokens[pos], element, instance, path, error)
            pos += 1 + length
        if pos > len(tokens):
            _ascii_truncated(element, instance, len(tokens) - start, path, error)
        if rows is not None:
            rows.append(row)
    return pos


def _list_length(token: bytes, element: PlyElement, instance: int, path: Path, error) -> int:
    try:
        length = int(token)
    except ValueError:
        length = -1
    if length < 0:
        raise error(
            f"{path}: body: {element.name} {instance}: a list's count must be a whole number >= 0, "
            f"got {token[:20].decode('ascii', 'replace')!r}"
        )
    return length


def _ascii_truncated(element: PlyElement, whole: int, values: int, path: Path, error):
    name = "vertices" if element.name == "vertex" else f"'{element.name}' elements"
    raise error(
        f"{path}: body: the header announces {element.count:,} {name}, the body holds {whole:,} "
        f"whole ({values:,} values after the elements before it); the file is truncated"
    )


def _is_number(word: bytes) -> bool:
    try:
        float(word)
    except ValueError:
        return False
    return True


# -- binary: packed values -------------------------------------------------------------------


def _binary_vertices(body: bytes, elements, at: int, order: str, path: Path, error) -> dict[str, np.ndarray]:
    offset = 0
    for element in elements[:at]:
        offset = _binary_element(body, offset, element, order, path, error)[1]
    table = _binary_element(body, offset, elements[at], order, path, error)[0]
    return {name: table[name].astype(table[name].dtype.newbyteorder("=")) for name in elements[at].scalars}


def _binary_element(body: bytes, offset: int, element: PlyElement, order: str, path: Path, error):
    """(the element's instances as a structured array, the offset after them). Lists of one
    length throughout (a mesh's triangles, CloudCompare's per-point lists) read as one array;
    others instance by instance."""
    lengths = _first_lengths(body, offset, element, order) if element.has_lists else []
    dtype = _fixed_dtype(element, order, lengths)
    need = dtype.itemsize * element.count
    if element.count and len(body) - offset >= need:
        table = np.frombuffer(body, dtype=dtype, count=element.count, offset=offset)
        if all(np.all(table[f"{p.name}#count"] == n) for p, n in zip(_lists(element), lengths, strict=True)):
            return table, offset + need
        return _binary_instances(body, offset, element, order, path, error)
    if element.count == 0:
        return np.zeros(0, dtype), offset
    if element.has_lists:
        return _binary_instances(body, offset, element, order, path, error)
    got = max(len(body) - offset, 0)
    name = "vertices" if element.name == "vertex" else f"'{element.name}' elements"
    raise error(
        f"{path}: body: the header announces {element.count:,} {name} of {dtype.itemsize} bytes "
        f"({need:,} bytes), the file holds {got:,} ({got // dtype.itemsize:,} whole {name}); "
        "the file is truncated"
    )


def _lists(element: PlyElement) -> list[PlyProperty]:
    return [p for p in element.properties if p.count_kind is not None]


def _first_lengths(body: bytes, offset: int, element: PlyElement, order: str) -> list[int]:
    """The lengths of the first instance's lists (0 where the file ends first)."""
    lengths = []
    for p in element.properties:
        if p.count_kind is None:
            offset += np.dtype(p.kind).itemsize
            continue
        size = np.dtype(p.count_kind).itemsize
        if offset + size > len(body):
            return lengths + [0] * (len(_lists(element)) - len(lengths))
        n = int(np.frombuffer(body, order + p.count_kind, 1, offset)[0])
        lengths.append(max(n, 0))
        offset += size + max(n, 0) * np.dtype(p.kind).itemsize
    return lengths


def _fixed_dtype(element: PlyElement, order: str, lengths: list[int]) -> np.dtype:
    fields, n = [], iter(lengths)
    for p in element.properties:
        if p.count_kind is None:
            fields.append((p.name, order + p.kind))
        else:
            fields += [(f"{p.name}#count", order + p.count_kind), (p.name, order + p.kind, (next(n),))]
    return np.dtype(fields)


def _binary_instances(body: bytes, offset: int, element: PlyElement, order: str, path: Path, error):
    """The element read instance by instance (lists of varying lengths); its scalars only."""
    view = memoryview(body)
    rows = []
    for instance in range(element.count):
        row = []
        for p in element.properties:
            code = order + _STRUCT[p.count_kind or p.kind]
            size = struct.calcsize(code)
            if offset + size > len(body):
                _binary_truncated(element, instance, path, error)
            value = struct.unpack_from(code, view, offset)[0]
            offset += size
            if p.count_kind is None:
                row.append(value)
                continue
            if value < 0:
                raise error(
                    f"{path}: body: {element.name} {instance}: list {p.name!r} has a count of {value}"
                )
            offset += value * np.dtype(p.kind).itemsize
            if offset > len(body):
                _binary_truncated(element, instance, path, error)
        rows.append(tuple(row))
    dtype = np.dtype([(p.name, "=" + p.kind) for p in element.properties if p.count_kind is None])
    return np.array(rows, dtype=dtype), offset


def _binary_truncated(element: PlyElement, whole: int, path: Path, error):
    name = "vertices" if element.name == "vertex" else f"'{element.name}' elements"
    raise error(
        f"{path}: body: the header announces {element.count:,} {name}, the file ends within the "
        f"{whole + 1:,}th ({whole:,} whole); the file is truncated"
    )
