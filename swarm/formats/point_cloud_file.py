"""Reading point clouds: .npy/.npz (N x 3), ASCII ``x y z`` lines (plain or .bz2/.gz) and PLY."""

from __future__ import annotations

import bz2
import gzip
from pathlib import Path

import numpy as np


class PointCloudError(ValueError):
    """A point cloud file that cannot be read, with the file named."""


def read_point_cloud(path: str | Path) -> np.ndarray:
    """Points (N, 3) float64 from a file; the format follows the file name."""
    path = Path(path)
    if not path.exists():
        raise PointCloudError(f"{path}: no such file")
    name = path.name.lower()
    try:
        if name.endswith(".npy"):
            points = np.load(path, allow_pickle=False)
        elif name.endswith(".npz"):
            with np.load(path, allow_pickle=False) as data:
                key = "points" if "points" in data.files else data.files[0]
                points = data[key]
        elif name.endswith(".ply"):
            points = _read_ply(path)
        else:
            points = _read_xyz(path)
    except PointCloudError:
        raise
    except (OSError, ValueError, EOFError) as exc:
        raise PointCloudError(f"{path}: cannot read point cloud: {exc}") from exc
    points = np.asarray(points, dtype=np.float64)
    if points.ndim != 2 or points.shape[1] < 3:
        raise PointCloudError(f"{path}: expected N x 3 points, got shape {points.shape}")
    return points[:, :3]


def _open_text(path: Path):
    name = path.name.lower()
    if name.endswith(".bz2"):
        return bz2.open(path, "rt")
    if name.endswith(".gz"):
        return gzip.open(path, "rt")
    return open(path)


def _read_xyz(path: Path) -> np.ndarray:
    """ASCII lines 'x y z [...]'; '#' comments; unparsable values become NaN (counted later)."""
    with _open_text(path) as f:
        points = np.genfromtxt(f, comments="#", usecols=(0, 1, 2), dtype=np.float64, ndmin=2)
    return points


_PLY_TYPES = {
    "char": "i1", "uchar": "u1", "int8": "i1", "uint8": "u1",
    "short": "i2", "ushort": "u2", "int16": "i2", "uint16": "u2",
    "int": "i4", "uint": "u4", "int32": "i4", "uint32": "u4",
    "float": "f4", "float32": "f4", "double": "f8", "float64": "f8",
}  # fmt: skip


def _read_ply(path: Path) -> np.ndarray:
    """The x, y, z properties of the vertex element of an ASCII or binary PLY file."""
    with open(path, "rb") as f:
        if f.readline().strip() != b"ply":
            raise PointCloudError(f"{path}: not a PLY file (no 'ply' magic line)")
        fmt, count, props, in_vertex = None, 0, [], False
        for raw in f:
            words = raw.decode("ascii", "replace").split()
            if not words:
                continue
            if words[0] == "format":
                fmt = words[1]
            elif words[0] == "element":
                in_vertex = words[1] == "vertex"
                if in_vertex:
                    count = int(words[2])
                elif not props:
                    raise PointCloudError(f"{path}: only PLY files whose first element is vertex")
            elif words[0] == "property" and in_vertex:
                if words[1] == "list":
                    raise PointCloudError(f"{path}: list properties in vertex are not supported")
                props.append((words[2], _PLY_TYPES[words[1]]))
            elif words[0] == "end_header":
                break
        names = [p[0] for p in props]
        if not {"x", "y", "z"} <= set(names):
            raise PointCloudError(f"{path}: PLY vertex lacks x, y, z properties")
        if fmt == "ascii":
            rows = np.loadtxt(f, max_rows=count, ndmin=2)
            return rows[:, [names.index(c) for c in "xyz"]]
        order = {"binary_little_endian": "<", "binary_big_endian": ">"}.get(fmt)
        if order is None:
            raise PointCloudError(f"{path}: unknown PLY format {fmt!r}")
        dtype = np.dtype([(n, order + t) for n, t in props])
        data = np.frombuffer(f.read(dtype.itemsize * count), dtype=dtype, count=count)
        return np.stack([data[c].astype(np.float64) for c in "xyz"], axis=1)


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
