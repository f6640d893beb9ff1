"""``map.npz``: the file form of a coverage map.

Keys: ``mu``, ``sigma``, ``entropy``, ``expected_coverage`` (float32, nx x ny x nz),
``origin``, ``voxel_size``; and ``sensor`` ([sigma_min, zeta, tau, max_range]) so the
prior can be rebuilt when the map is loaded.

:func:`load_map` also reads a map server's ``snapshot.npz`` (``lam``, ``eta`` flat, ``grid``
JSON; the sensor model from ``store.json`` beside it): the team map as of the server's last
compaction, without the deltas logged after it.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from swarm.formats.errors import InputError
from swarm.map.coverage_map import CoverageMap
from swarm.map.entropy import expected_coverage
from swarm.map.entropy_table import default_table
from swarm.map.grid import Grid
from swarm.map.sensor_model import SensorModel

REQUIRED_KEYS = ("mu", "sigma", "entropy", "expected_coverage", "origin", "voxel_size")
SNAPSHOT_KEYS = ("lam", "eta", "grid")


class MapFileError(InputError):
    """A map file that cannot be read, with the file and key named."""


def save_map(path: str | Path, cmap: CoverageMap) -> None:
    """Write ``cmap`` to ``path`` (compressed npz)."""
    shape = cmap.grid.shape
    mu = cmap.mean().astype(np.float32)
    sigma = cmap.sigma().astype(np.float32)
    s = cmap.sensor
    Path(path).parent.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(
        path,
        mu=mu.reshape(shape),
        sigma=sigma.reshape(shape),
        entropy=default_table()(mu, sigma).astype(np.float32).reshape(shape),
        expected_coverage=expected_coverage(mu, sigma).astype(np.float32).reshape(shape),
        origin=np.asarray(cmap.grid.origin, dtype=np.float64),
        voxel_size=np.float64(cmap.grid.voxel),
        sensor=np.array([s.sigma_min, s.zeta, s.tau, s.max_range], dtype=np.float64),
    )


def load_map(path: str | Path) -> CoverageMap:
    """Read a map written by :func:`save_map` (or any npz with the docs/design.md keys)."""
    path = Path(path)
    try:
        with _npz(path) as data:
            if all(k in data.files for k in SNAPSHOT_KEYS) and "mu" not in data.files:
                return _load_snapshot(data, path)
            missing = [k for k in REQUIRED_KEYS if k not in data.files]
            if missing:
                raise MapFileError(
                    f"{path}: {', '.join(missing)}: missing; a map file holds {', '.join(REQUIRED_KEYS)}"
                )
            mu = data["mu"].astype(np.float64)
            sigma = data["sigma"].astype(np.float64)
            origin = data["origin"]
            voxel = float(data["voxel_size"])
            sensor = _sensor(data, path) if "sensor" in data.files else None
    except MapFileError:
        raise
    except (OSError, ValueError, KeyError) as exc:
        raise MapFileError(f"{path}: cannot read map: {exc}") from exc
    if mu.ndim != 3 or mu.shape != sigma.shape:
        raise MapFileError(f"{path}: mu and sigma must be equal 3-D arrays, got {mu.shape}, {sigma.shape}")
    if not np.all(np.isfinite(mu)):
        raise MapFileError(f"{path}: mu: {int(np.sum(~np.isfinite(mu))):,} voxels are NaN or infinite")
    if not np.all(np.isfinite(sigma) & (sigma > 0)):
        bad = int(np.sum(~(np.isfinite(sigma) & (sigma > 0))))
        raise MapFileError(f"{path}: sigma: {bad:,} voxels are not a finite number > 0")
    if origin.shape != (3,) or not np.all(np.isfinite(origin)):
        raise MapFileError(f"{path}: origin: must be 3 finite numbers, got {origin.tolist()}")
    if not (np.isfinite(voxel) and voxel > 0):
        raise MapFileError(f"{path}: voxel_size: must be a finite number > 0, got {voxel}")
    grid = Grid(tuple(origin.tolist()), voxel, mu.shape)
    lam = 1.0 / sigma**2
    return CoverageMap(grid, sensor, lam.astype(np.float32), (mu * lam).astype(np.float32))


def _sensor(data, path: Path) -> SensorModel:
    values = np.asarray(data["sensor"], dtype=np.float64).reshape(-1)
    if values.shape != (4,) or not np.all(np.isfinite(values)) or not np.all(values[[0, 2, 3]] > 0):
        raise MapFileError(
            f"{path}: sensor: must be [sigma_min, zeta, tau, max_range], finite, with sigma_min, tau, "
            f"max_range > 0; got {values.tolist()}"
        )
    return SensorModel(*values.tolist())


def is_store_snapshot(path: str | Path) -> bool:
    """True when ``path`` is a map server's ``snapshot.npz`` rather than a map file."""
    try:
        with _npz(path) as data:
            return all(k in data.files for k in SNAPSHOT_KEYS) and "mu" not in data.files
    except (OSError, ValueError):
        return False


def _npz(path: Path):
    """``np.load`` of an ``.npz`` archive; a single array (``.npy``, e.g. a depth image from
    ``swarm stereo depth``) is refused naming the file (MapFileError, a ValueError)."""
    try:
        data = np.load(path, allow_pickle=False)
    except ValueError:  # NumPy's "pickled data ... allow_pickle": any file that is no .npy/.npz
        raise MapFileError(f"{path}: not a NumPy .npz map file") from None
    if isinstance(data, np.ndarray):
        raise MapFileError(
            f"{path}: a single array of shape {data.shape} (.npy), not a map file "
            f"(.npz holding {', '.join(REQUIRED_KEYS)})"
        )
    return data


def _load_snapshot(data, path: Path) -> CoverageMap:
    try:
        spec = json.loads(str(data["grid"]))
        grid = Grid(tuple(float(v) for v in spec["origin"]), float(spec["voxel"]), tuple(spec["shape"]))
    except (ValueError, KeyError, TypeError) as exc:
        raise MapFileError(f"{path}: grid: not a grid description ({exc})") from exc
    lam = np.asarray(data["lam"], dtype=np.float32).reshape(-1)
    eta = np.asarray(data["eta"], dtype=np.float32).reshape(-1)
    if lam.size != grid.size or eta.size != grid.size:
        raise MapFileError(f"{path}: lam, eta: {lam.size:,} and {eta.size:,} values for {grid.size:,} voxels")
    if not (np.all(np.isfinite(lam) & (lam > 0)) and np.all(np.isfinite(eta))):
        raise MapFileError(f"{path}: lam, eta: must be finite with lam > 0")
    sensor = None
    identity = path.parent / "store.json"
    if identity.is_file():
        try:
            s = json.loads(identity.read_text(encoding="utf-8"))["sensor"]
            sensor = SensorModel(s["sigma_min"], s["zeta"], s["tau"], s["max_range"])
        except (OSError, ValueError, KeyError, TypeError) as exc:
            raise MapFileError(f"{identity}: sensor: cannot read the store's sensor model ({exc})") from exc
    return CoverageMap(grid, sensor, lam, eta)
