"""Reading point clouds: .npy/.npz (N x 3), ASCII ``x y z`` lines (plain or .bz2/.gz), PLY and
PCL's PCD (``swarm.formats.pcd_file``).

Every problem raises :class:`PointCloudError` with one line naming the file, where in it
(the header line, the data line, the element) and the counts involved, e.g.
``scan.ply: body: the header announces 1,000 vertices of 12 bytes (12,000 bytes), the file
holds 6,000 after the header (500 whole vertices); the file is truncated``.

NaN and infinite coordinates are read as they are: they mean "no return" and the fusion
skips and counts them. In text files a value that is not a number (e.g. the ``NODE`` lines
of OctoMap's scan graphs) reads as NaN too, and is counted the same way.

PLY (:mod:`swarm.formats.ply_file`): ASCII or binary of either byte order; the ``vertex``
element may come after other elements and hold list properties; only its x, y, z are kept.
"""

from __future__ import annotations

import bz2
import gzip
import io
import warnings
from pathlib import Path

import numpy as np

from swarm.formats import ply_file
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


# -- PLY (swarm.formats.ply_file) ------------------------------------------------------------


def _read_ply(path: Path) -> np.ndarray:
    """The x, y, z properties of the vertex element of an ASCII or binary PLY file."""
    vertices = read_ply_vertices(path)
    missing = [c for c in "xyz" if c not in vertices]
    if missing:
        raise PointCloudError(
            f"{path}: header: element vertex lacks propert{'y' if len(missing) == 1 else 'ies'} "
            f"{', '.join(missing)} (has {', '.join(vertices) or 'none'})"
        )
    return np.stack([vertices[c].astype(np.float64) for c in "xyz"], axis=1)


def read_ply_vertices(path: str | Path) -> dict[str, np.ndarray]:
    """Every scalar property of the vertex element of a PLY file, by name, in file order.

    ASCII (as float64) and binary files of either byte order (in the file's types); the vertex
    element may hold list properties (skipped) and come after other elements; elements after
    it, such as faces, are not read (:mod:`swarm.formats.ply_file`). Raises PointCloudError
    naming the file and what is wrong, as :func:`read_point_cloud` does.
    """
    return ply_file.read_ply_vertices(path, PointCloudError)


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
