"""OctoMap's binary occupancy file (``.bt``): read and write, our own code.

Read as OctoMap 1.x reads it (``AbstractOccupancyOcTree::readBinary``): any occupancy tree's
``id`` (the deprecated ``id 1`` is ``OcTree``), and the legacy header-less form of OctoMap's
first releases (int32 3, float64 res, uint32 size, then the tree) too.

The format, as OctoMap writes it (``AbstractOccupancyOcTree::writeBinaryConst`` and
``OccupancyOcTreeBase::writeBinaryNode`` in OctoMap 1.x):

* a text header: the line ``# Octomap OcTree binary file``, any ``#`` comment lines, then
  ``id OcTree``, ``size <nodes>``, ``res <voxel edge in metres>`` and ``data``, one per line;
* the tree, depth first from the root: every inner node is two bytes, two bits per child
  (children 0-3 in the first byte, 4-7 in the second, child ``i`` at bits ``2i, 2i+1``):
  ``00`` unknown (no child), ``01`` (value 1) a free leaf, ``10`` (value 2) an occupied leaf,
  ``11`` an inner node, whose own two bytes follow after the current node's, in child order.

``size`` counts every node of the tree (the root, inner nodes and leaves); OctoMap refuses a
file whose count disagrees. The tree has 16 levels below the root. A leaf-level voxel has the
*key* ``k = floor(x / res) + 32768`` per axis (so voxels are anchored at the world origin), and
the child index at depth ``d`` (root 0) is ``bx + 2 by + 4 bz`` with ``b`` bit ``15 - d`` of the
key. A leaf above the last level (a *pruned* node) stands for all ``2**(16 - d)`` cubed voxels
below it. Only maximum-likelihood states are stored: free or occupied, no probabilities.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from swarm.formats.errors import InputError

TREE_DEPTH = 16
#: key of the voxel whose min corner is the world origin
KEY_ORIGIN = 1 << (TREE_DEPTH - 1)
MAGIC = b"# Octomap OcTree binary file"
#: the first line of a full ``.ot`` file (``AbstractOcTree::write``)
OT_MAGIC = b"# Octomap OcTree file"
#: bytes of a node's data in a ``.ot`` file, by tree type: float log-odds, then a ColorOcTree's
#: r, g, b or an OcTreeStamped's uint32 stamp. (A ``.bt`` holds the same data for all three.)
OT_NODE_BYTES = {"OcTree": 4, "ColorOcTree": 7, "OcTreeStamped": 8}
#: OctoMap's trees that are not occupancy trees (they cannot write a ``.bt``)
NOT_OCCUPANCY_TREES = ("CountingOcTree",)
FREE, OCCUPIED, INNER = 1, 2, 3  # the 2-bit child codes
#: the header of a ``.bt`` written before OctoMap's text header (read by OctoMap 1.x still, with
#: a warning): tree type 3 (int32), resolution (float64), node count (uint32), little-endian
LEGACY_HEADER = struct.Struct("<idI")


class OctomapFileError(InputError):
    """A ``.bt`` file that cannot be read or a tree that cannot be written; names the file."""


@dataclass
class OctreeLeaves:
    """The leaves of an occupancy octree, pruned ones included.

    ``key`` (N, 3) int64: the leaf-level key of each leaf's min corner; ``depth`` (N,) int:
    the leaf's depth (16 = one voxel of edge ``resolution``; 16 - n: a cube of 2**n voxels per
    edge); ``occupied`` (N,) bool. ``resolution`` in metres.
    """

    resolution: float
    key: np.ndarray
    depth: np.ndarray
    occupied: np.ndarray

    def edge_voxels(self) -> np.ndarray:
        """Voxels per edge of each leaf, (N,) int64."""
        return np.left_shift(1, TREE_DEPTH - self.depth.astype(np.int64))

    def voxel_counts(self) -> tuple[int, int]:
        """(occupied, free) leaf-level voxels, pruned leaves expanded."""
        volume = self.edge_voxels() ** 3
        return int(volume[self.occupied].sum()), int(volume[~self.occupied].sum())


# -- Morton codes: the depth-first child order of the tree ----------------------------------


def _spread(v: np.ndarray) -> np.ndarray:
    """Bits b of 16-bit ``v`` moved to bits 3b (uint64)."""
    v = v.astype(np.uint64) & np.uint64(0xFFFF)
    out = np.zeros_like(v)
    for b in range(TREE_DEPTH):
        out |= ((v >> np.uint64(b)) & np.uint64(1)) << np.uint64(3 * b)
    return out


def _gather(code: np.ndarray) -> np.ndarray:
    """Inverse of :func:`_spread`: bits 3b of ``code`` to bits b."""
    out = np.zeros_like(code)
    for b in range(TREE_DEPTH):
        out |= ((code >> np.uint64(3 * b)) & np.uint64(1)) << np.uint64(b)
    return out


def morton(key: np.ndarray) -> np.ndarray:
    """Leaf-level keys (N, 3) -> 48-bit codes whose 3-bit groups, from the top, are child indices."""
    key = np.asarray(key)
    return _spread(key[:, 0]) | (_spread(key[:, 1]) << np.uint64(1)) | (_spread(key[:, 2]) << np.uint64(2))


def unmorton(code: np.ndarray) -> np.ndarray:
    """48-bit codes -> leaf-level keys (N, 3) int64."""
    code = np.asarray(code, dtype=np.uint64)
    return np.stack([_gather(code >> np.uint64(a)) for a in range(3)], axis=1).astype(np.int64)


# -- writing -------------------------------------------------------------------------------


def encode_tree(key: np.ndarray, occupied: np.ndarray) -> tuple[int, bytes]:
    """The node count and the data bytes of the pruned tree of leaf-level voxels.

    ``key`` (N, 3) integer keys in [0, 65536), distinct; ``occupied`` (N,) bool (False: free).
    Eight equal leaf siblings are pruned into their parent, level by level, as OctoMap does
    before it writes. Raises ValueError on keys out of range or repeated.
    """
    key = np.asarray(key, dtype=np.int64).reshape(-1, 3)
    occupied = np.asarray(occupied, dtype=bool).reshape(-1)
    if len(key) != len(occupied):
        raise ValueError(f"{len(key)} keys but {len(occupied)} states")
    if len(key) == 0:
        return 0, b""
    if key.min() < 0 or key.max() >= 1 << TREE_DEPTH:
        raise ValueError("octree keys must lie in [0, 65536): the map is too far from the origin")
    code = morton(key)
    order = np.argsort(code, kind="stable")
    code = code[order]
    if np.any(code[1:] == code[:-1]):
        raise ValueError("the same voxel is given twice")
    state = np.where(occupied[order], OCCUPIED, FREE).astype(np.uint8)
    depths, codes, records = [], [], []
    nodes = 1  # the root
    for depth in range(TREE_DEPTH, 0, -1):
        parent = code >> np.uint64(3)
        child = (code & np.uint64(7)).astype(np.uint16)
        starts = np.flatnonzero(np.r_[True, parent[1:] != parent[:-1]])
        counts = np.diff(np.r_[starts, len(parent)])
        low = np.minimum.reduceat(state, starts)
        high = np.maximum.reduceat(state, starts)
        pruned = (counts == 8) & (low == high) & (low != INNER)
        record = np.bitwise_or.reduceat(state.astype(np.uint16) << (2 * child), starts)
        inner = ~pruned
        depths.append(np.full(int(inner.sum()), depth - 1, np.int64))
        codes.append(parent[starts][inner])
        records.append(record[inner])
        nodes += int(counts[inner].sum())
        code, state = parent[starts], np.where(pruned, low, INNER).astype(np.uint8)
    if state[0] != INNER:
        raise ValueError("the whole octree space is one state: OctoMap cannot store a leaf root")
    depth = np.concatenate(depths)
    padded = np.concatenate(codes) << (np.uint64(3) * (TREE_DEPTH - depth).astype(np.uint64))
    preorder = np.lexsort((depth, padded))  # a node before its descendants, children in order
    return nodes, np.concatenate(records)[preorder].astype("<u2").tobytes()


def write_bt(path: str | Path, resolution: float, key: np.ndarray, occupied: np.ndarray) -> int:
    """Write leaf-level voxels (see :func:`encode_tree`) to an OctoMap ``.bt``; returns the node count.

    Raises OctomapFileError naming ``path`` when the tree cannot be encoded or written.
    """
    path = Path(path)
    if not (np.isfinite(resolution) and resolution > 0):
        raise OctomapFileError(f"{path}: resolution must be a positive number, got {resolution!r}")
    try:
        nodes, data = encode_tree(key, occupied)
    except ValueError as exc:
        raise OctomapFileError(f"{path}: {exc}") from exc
    header = (
        f"{MAGIC.decode()}\n# written by swarm: the maximum-likelihood occupancy of a coverage map\n"
        f"id OcTree\nsize {nodes}\nres {float(resolution)!r}\ndata\n"
    )
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(header.encode("ascii") + data)
    except OSError as exc:
        raise OctomapFileError(f"{path}: cannot write: {exc}") from exc
    return nodes


# -- reading -------------------------------------------------------------------------------


def _read_header(path: Path, raw: bytes, magic: bytes) -> tuple[dict[str, str], int]:
    """Header fields and the offset of the tree data (after the ``data`` line)."""
    first = raw.find(b"\n")
    if first < 0:
        raise OctomapFileError(f"{path}: header ends after its first line (no 'data' line)")
    fields: dict[str, str] = {}
    pos = first + 1
    while True:
        end = raw.find(b"\n", pos)
        if end < 0:
            raise OctomapFileError(f"{path}: header ends before its 'data' line")
        words = raw[pos:end].decode("ascii", "replace").split()
        pos = end + 1
        if not words or words[0].startswith("#"):
            continue
        if words[0] == "data":
            return fields, pos
        fields[words[0]] = words[1] if len(words) > 1 else ""


def _header_numbers(
    path: Path, fields: dict[str, str], node_bytes: dict[str, int], any_id: bool = False
) -> tuple[float, int]:
    """``res`` and ``size`` of a header whose ``id`` is one of ``node_bytes``'s tree types (with
    ``any_id``, as for a ``.bt``, any id but ``NOT_OCCUPANCY_TREES``). OctoMap 1.x changes the
    deprecated ``id 1`` to ``OcTree`` (``AbstractOcTree::readHeader``); so does this, in ``fields``."""
    if fields.get("id") == "1":
        fields["id"] = "OcTree"
    tree = fields.get("id")
    if not tree or (tree not in node_bytes and not (any_id and tree not in NOT_OCCUPANCY_TREES)):
        raise OctomapFileError(
            f"{path}: id: only occupancy trees ({', '.join(node_bytes)}) are supported, got {tree!r}"
        )
    try:
        resolution = float(fields["res"])
        size = int(fields.get("size", "0"))
    except (KeyError, ValueError) as exc:
        raise OctomapFileError(f"{path}: res/size: missing or not a number ({exc})") from exc
    if not (np.isfinite(resolution) and resolution > 0):
        raise OctomapFileError(f"{path}: res: must be a positive number, got {fields['res']!r}")
    if size < 0:
        raise OctomapFileError(f"{path}: size: must be >= 0, got {size}")
    return resolution, size


def _leaves(resolution: float, codes: list[int], depths: list[int], occupied: list[bool]) -> OctreeLeaves:
    depth_arr = np.asarray(depths, dtype=np.int64)
    code_arr = np.asarray(codes, dtype=np.uint64) << (
        np.uint64(3) * (TREE_DEPTH - depth_arr).astype(np.uint64)
    )
    return OctreeLeaves(
        resolution=resolution,
        key=unmorton(code_arr) if len(code_arr) else np.zeros((0, 3), np.int64),
        depth=depth_arr,
        occupied=np.asarray(occupied, dtype=bool),
    )


def _read_bytes(path: Path) -> bytes:
    try:
        return path.read_bytes()
    except OSError as exc:
        raise OctomapFileError(f"{path}: cannot read: {exc.strerror or exc}") from exc


def _is_legacy_bt(raw: bytes) -> bool:
    """A ``.bt`` of OctoMap before its text header: int32 tree type 3, float64 res, uint32 size."""
    return len(raw) >= LEGACY_HEADER.size and raw[:4] == struct.pack("<i", 3)


def _legacy_header(path: Path, raw: bytes) -> tuple[float, int, int]:
    """(res, size, offset of the tree data) of a legacy ``.bt`` (``readBinaryLegacyHeader``)."""
    _tree_type, resolution, size = LEGACY_HEADER.unpack_from(raw)
    if not (np.isfinite(resolution) and resolution > 0):
        raise OctomapFileError(f"{path}: res: must be a positive number, got {resolution!r} (legacy header)")
    return resolution, size, LEGACY_HEADER.size


def read_octree(path: str | Path) -> OctreeLeaves:
    """Every leaf of an OctoMap file: a binary ``.bt`` (:func:`read_bt`) or a full ``.ot``
    (:func:`read_ot`), told apart by the first line. Raises OctomapFileError naming the file."""
    path = Path(path)
    raw = _read_bytes(path)
    if raw.startswith(OT_MAGIC):
        return read_ot(path)
    if not (raw.startswith(MAGIC) or _is_legacy_bt(raw)):
        first = raw.split(b"\n", 1)[0][:60].decode("ascii", "replace")
        raise OctomapFileError(
            f"{path}: not an OctoMap file: the first line is {first!r}, not {MAGIC.decode()!r} (.bt) "
            f"or {OT_MAGIC.decode()!r} (.ot)"
        )
    return read_bt(path)


def read_bt(path: str | Path) -> OctreeLeaves:
    """Every leaf of an OctoMap ``.bt`` file (pruned leaves kept whole; see :class:`OctreeLeaves`).

    The ``id`` may be any occupancy tree (``OcTree``, ``ColorOcTree``, ``OcTreeStamped``: their
    binary data is the same, colours and stamps are not in it). Raises OctomapFileError naming the
    file and the field for a bad header (another type, resolution not positive), truncated data or
    a node count other than ``size``.
    """
    path = Path(path)
    raw = _read_bytes(path)
    if raw.startswith(MAGIC):
        fields, pos = _read_header(path, raw, MAGIC)
        # OctoMap's readBinary takes any id: every occupancy tree writes the same binary data
        resolution, size = _header_numbers(path, fields, OT_NODE_BYTES, any_id=True)
    elif _is_legacy_bt(raw):
        resolution, size, pos = _legacy_header(path, raw)
    else:
        hint = " (a full .ot file: read_octree reads both)" if raw.startswith(OT_MAGIC) else ""
        raise OctomapFileError(
            f"{path}: not an OctoMap binary file (first line is not {MAGIC.decode()!r}){hint}"
        )
    codes: list[int] = []
    depths: list[int] = []
    states: list[int] = []
    nodes = 0
    if size > 0:
        data = raw[pos:]
        stack = [(0, 0)]  # (code, depth) of inner nodes still to read, the next on top
        at, nodes = 0, 1
        while stack:
            code, depth = stack.pop()
            if at + 2 > len(data):
                raise OctomapFileError(f"{path}: data: the tree is truncated at byte {pos + at}")
            record = data[at] | (data[at + 1] << 8)
            at += 2
            inner = []
            for child in range(8):
                s = (record >> (2 * child)) & 3
                if s == 0:
                    continue
                nodes += 1
                if s == INNER:
                    if depth + 1 >= TREE_DEPTH:
                        raise OctomapFileError(f"{path}: data: the tree is deeper than {TREE_DEPTH} levels")
                    inner.append(((code << 3) | child, depth + 1))
                else:
                    codes.append((code << 3) | child)
                    depths.append(depth + 1)
                    states.append(s)
            stack.extend(reversed(inner))
        if nodes != size:
            raise OctomapFileError(f"{path}: size: the header says {size} nodes, the data holds {nodes}")
    return _leaves(resolution, codes, depths, [s == OCCUPIED for s in states])


def read_ot(path: str | Path) -> OctreeLeaves:
    """Every leaf of an OctoMap full ``.ot`` file (``AbstractOcTree::write``): after the header,
    the nodes depth first, each its float32 log-odds (then a ``ColorOcTree``'s 3 colour bytes or an
    ``OcTreeStamped``'s 4-byte stamp) and a byte whose bit ``i`` says child ``i`` follows. A leaf is
    occupied when its log-odds is >= 0 (OctoMap's default threshold, probability 0.5); colours and
    stamps are dropped. Raises OctomapFileError naming the file and the field."""
    path = Path(path)
    raw = _read_bytes(path)
    if not raw.startswith(OT_MAGIC):
        raise OctomapFileError(f"{path}: not an OctoMap .ot file (first line is not {OT_MAGIC.decode()!r})")
    fields, pos = _read_header(path, raw, OT_MAGIC)
    resolution, size = _header_numbers(path, fields, OT_NODE_BYTES)
    value_bytes = OT_NODE_BYTES[fields["id"]]
    data = raw[pos:]
    codes: list[int] = []
    depths: list[int] = []
    occupied: list[bool] = []
    stack = [(0, 0)] if size > 0 else []
    at = nodes = 0
    while stack:
        code, depth = stack.pop()
        if at + value_bytes + 1 > len(data):
            raise OctomapFileError(f"{path}: data: the tree is truncated at byte {pos + at}")
        (log_odds,) = struct.unpack_from("<f", data, at)
        children = data[at + value_bytes]
        at += value_bytes + 1
        nodes += 1
        if not np.isfinite(log_odds):
            raise OctomapFileError(f"{path}: data: node {nodes} holds a log-odds of {log_odds}")
        if children == 0:
            codes.append(code)
            depths.append(depth)
            occupied.append(log_odds >= 0.0)
            continue
        if depth >= TREE_DEPTH:
            raise OctomapFileError(f"{path}: data: the tree is deeper than {TREE_DEPTH} levels")
        stack.extend(
            ((code << 3) | child, depth + 1) for child in reversed(range(8)) if children >> child & 1
        )
    if nodes != size:
        raise OctomapFileError(f"{path}: size: the header says {size} nodes, the data holds {nodes}")
    return _leaves(resolution, codes, depths, occupied)
