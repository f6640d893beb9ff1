"""PCL's point cloud files (``.pcd``, format 0.7 and older): the x, y, z of every point.

The header (one keyword a line, ``#`` comments): ``FIELDS`` names, ``SIZE`` bytes, ``TYPE``
(``F`` float, ``I`` signed, ``U`` unsigned) and ``COUNT`` (elements; default 1) per field,
``WIDTH`` and ``HEIGHT`` (an organised cloud is WIDTH x HEIGHT), ``POINTS``, then ``DATA``:

* ``ascii``: one point a line, the fields' elements in order;
* ``binary``: the points' records packed, little-endian (what PCL writes on x86 and ARM);
* ``binary_compressed``: two uint32 (compressed and raw sizes), then the LZF-compressed data
  laid out field by field (every point's x, then every point's y, ...); data of equal sizes
  that is not LZF is taken as stored uncompressed (some Python writers do so).

Padding fields (named ``_``, PCL's) and fields of several elements (``COUNT`` > 1) are skipped
over.

NaN coordinates (an organised cloud's pixels without a return) are kept: they mean "no
return", as in the other formats. Errors raise ``PointCloudError`` naming the file and the
header keyword or the data.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from swarm.formats.errors import InputError

_TYPES = {("F", 4): "<f4", ("F", 8): "<f8", ("I", 1): "<i1", ("I", 2): "<i2", ("I", 4): "<i4",
          ("I", 8): "<i8", ("U", 1): "<u1", ("U", 2): "<u2", ("U", 4): "<u4", ("U", 8): "<u8"}  # fmt: skip
_KEYWORDS = (
    "VERSION",
    "FIELDS",
    "COLUMNS",
    "SIZE",
    "TYPE",
    "COUNT",
    "WIDTH",
    "HEIGHT",
    "VIEWPOINT",
    "POINTS",
)


def is_pcd(head: bytes) -> bool:
    """Whether a file's first bytes are a PCD header (a ``# .PCD`` comment or ``VERSION``)."""
    first = head.lstrip().split(b"\n", 1)[0].strip()
    return first.startswith(b"# .PCD") or first.startswith(b"VERSION")


def read_pcd(path: Path, error: type[InputError]) -> np.ndarray:
    """Points (N, 3) float64 of a PCD file; ``error`` (the caller's PointCloudError) is raised."""
    data = path.read_bytes()
    fields: dict[str, list[str]] = {}
    pos = 0
    while True:
        end = data.find(b"\n", pos)
        if end < 0:
            raise error(f"{path}: header: no DATA line")
        words = data[pos:end].decode("ascii", "replace").split()
        pos = end + 1
        if not words or words[0].startswith("#"):
            continue
        key = words[0].upper()
        if key == "DATA":
            fields["DATA"] = words[1:]
            break
        if key not in _KEYWORDS:
            raise error(f"{path}: header: unknown keyword {words[0]!r}")
        fields["FIELDS" if key == "COLUMNS" else key] = words[1:]
    names = fields.get("FIELDS", [])
    missing = [c for c in "xyz" if c not in names]
    if missing:
        raise error(f"{path}: FIELDS: no {', '.join(missing)} (has {' '.join(names) or 'none'})")
    dtype = _record(path, fields, names, error)
    count = _count(path, fields, error)
    kind = (fields["DATA"] or [""])[0].lower()
    body = data[pos:]
    if kind == "ascii":
        table = _ascii(path, body, dtype, count, error)
    elif kind == "binary":
        if len(body) < dtype.itemsize * count:
            raise error(
                f"{path}: DATA binary: {count:,} points of {dtype.itemsize} bytes need "
                f"{dtype.itemsize * count:,} bytes, the file holds {len(body):,}; the file is truncated"
            )
        table = np.frombuffer(body, dtype, count)
    elif kind == "binary_compressed":
        table = _compressed(path, body, dtype, count, error)
    else:
        raise error(f"{path}: DATA: {kind!r} is not ascii, binary or binary_compressed")
    return np.stack([table[c].astype(np.float64) for c in "xyz"], axis=1)


def _record(path: Path, fields: dict, names: list[str], error: type[InputError]) -> np.dtype:
    sizes, types = fields.get("SIZE", []), fields.get("TYPE", [])
    counts = fields.get("COUNT", ["1"] * len(names))
    if not (len(sizes) == len(types) == len(counts) == len(names)):
        raise error(
            f"{path}: FIELDS, SIZE, TYPE, COUNT: {len(names)}, {len(sizes)}, {len(types)}, {len(counts)} "
            "entries; each needs one per field"
        )
    record, seen = [], set()
    for i, (name, size, kind, n) in enumerate(zip(names, sizes, types, counts, strict=True)):
        code = _TYPES.get((kind.upper(), int(size) if size.isdigit() else 0))
        if code is None or not n.isdigit() or int(n) < 1:
            raise error(f"{path}: field {name!r}: SIZE {size}, TYPE {kind}, COUNT {n} is not a PCD type")
        unique = name if name not in seen and name != "_" else f"_{i}"  # PCL pads with fields named _
        seen.add(unique)
        record.append((unique, code) if int(n) == 1 else (unique, code, (int(n),)))
    return np.dtype(record)


def _count(path: Path, fields: dict, error: type[InputError]) -> int:
    try:
        width, height = (int(fields.get(k, ["1"])[0]) for k in ("WIDTH", "HEIGHT"))
        points = int(fields["POINTS"][0]) if "POINTS" in fields else width * height
    except (ValueError, IndexError):
        raise error(f"{path}: WIDTH, HEIGHT, POINTS: must be whole numbers") from None
    if points < 0 or points != width * height:
        raise error(f"{path}: POINTS: {points} is not WIDTH x HEIGHT = {width} x {height}")
    return points


def _ascii(path: Path, body: bytes, dtype: np.dtype, count: int, error: type[InputError]) -> dict:
    """Each field's first element per point, by field name (the x, y, z read here)."""
    lines = [line.split() for line in body.decode("ascii", "replace").splitlines() if line.strip()]
    if len(lines) < count:
        raise error(f"{path}: DATA ascii: POINTS says {count:,}, the file holds {len(lines):,} point lines")
    width = sum(int(np.prod(dtype[n].shape or (1,))) for n in dtype.names)
    short = next((i for i, line in enumerate(lines[:count]) if len(line) < width), None)
    if short is not None:
        raise error(
            f"{path}: DATA ascii: point {short} has {len(lines[short])} values, the fields need {width}"
        )
    try:
        values = np.array([[float(w) for w in line[:width]] for line in lines[:count]], dtype=np.float64)
    except ValueError:
        raise error(f"{path}: DATA ascii: a point line holds something that is not a number") from None
    columns, at = {}, 0
    for name in dtype.names:
        n = int(np.prod(dtype[name].shape or (1,)))
        columns[name] = values[:, at]
        at += n
    return columns


def _compressed(path: Path, body: bytes, dtype: np.dtype, count: int, error: type[InputError]) -> dict:
    if len(body) < 8:
        raise error(f"{path}: DATA binary_compressed: the file ends before the sizes")
    packed, raw = (int(v) for v in np.frombuffer(body[:8], "<u4"))
    if raw != dtype.itemsize * count or len(body) < 8 + packed:
        raise error(
            f"{path}: DATA binary_compressed: sizes {packed:,} / {raw:,} bytes do not match {count:,} points "
            f"of {dtype.itemsize} bytes and a file of {len(body) - 8:,} data bytes"
        )
    try:
        flat = lzf_decompress(body[8 : 8 + packed], raw)
    except ValueError as exc:
        if packed != raw:
            raise error(f"{path}: DATA binary_compressed: {exc}") from None
        flat = body[8 : 8 + packed]  # stored as it is, not compressed (MapIV/pypcd4#37's writer)
    columns, at = {}, 0
    for name in dtype.names:  # field by field: every point's value of one field, then the next
        base = dtype[name].base
        elements = dtype[name].itemsize // base.itemsize
        columns[name] = np.frombuffer(flat, base, count * elements, offset=at)[::elements]
        at += dtype[name].itemsize * count
    return columns


def lzf_decompress(data: bytes, size: int) -> bytes:
    """LZF (liblzf's format, which PCL uses): a control byte below 32 copies that many + 1
    literal bytes; above, its top 3 bits (7: plus the next byte) + 2 bytes are copied from
    (low 5 bits << 8 | the next byte) + 1 bytes back. Raises ValueError on damaged data."""
    out = bytearray()
    i, n = 0, len(data)
    while i < n:
        ctrl = data[i]
        i += 1
        if ctrl < 32:
            if i + ctrl + 1 > n:
                raise ValueError("the compressed data is cut short")
            out += data[i : i + ctrl + 1]
            i += ctrl + 1
            continue
        length = ctrl >> 5
        if length == 7:
            if i >= n:
                raise ValueError("the compressed data is cut short")
            length += data[i]
            i += 1
        if i >= n:
            raise ValueError("the compressed data is cut short")
        back = ((ctrl & 0x1F) << 8 | data[i]) + 1
        i += 1
        if back > len(out):
            raise ValueError("a back reference points before the start")
        start = len(out) - back
        if back >= length + 2:
            out += out[start : start + length + 2]
        else:  # the copy overlaps what it writes: byte by byte
            for k in range(length + 2):
                out.append(out[start + k])
    if len(out) != size:
        raise ValueError(f"decompresses to {len(out):,} bytes, the header says {size:,}")
    return bytes(out)
