"""The map server's store: a snapshot plus a write-ahead log of accepted delta payloads.

Layout of ``--store DIR`` (see docs/protocol.md):

- ``store.json``: what the store belongs to (format, mission, grid, sensor model); written
  once when the store is created, checked on every start.
- ``snapshot.npz``: ``lam``, ``eta`` (float32, flat, prior included), ``ledger`` (applied
  delta ids, JSON), ``counters`` (JSON), ``grid`` (JSON) and ``wal`` (the generation of the
  log that follows it). Written atomically: temporary file, fsync, ``os.replace``, fsync of
  the folder.
- ``wal-<generation>.log``: an 8-byte magic ``SWARMWAL``, a uint32 version, then one record
  per accepted delta: uint32 length, uint32 CRC32 of the payload, the raw payload (all
  little-endian). :meth:`Store.append` fsyncs before it returns, so a delta counts as
  durable (and is acked) only once its record is on disk.

Recovery loads the snapshot and reads the log of its generation; a torn or corrupt tail
(after a crash or SIGKILL mid-write) is detected by length and CRC, reported and cut off,
so the good prefix survives. Compaction writes a new snapshot and starts the next log.
"""

from __future__ import annotations

import json
import logging
import os
import re
import struct
import zlib
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from map_server.ledger import describe_grid
from swarm.map.grid import Grid
from swarm.map.sensor_model import SensorModel

log = logging.getLogger("swarm.server.store")

FORMAT = 1
WAL_MAGIC = b"SWARMWAL"
WAL_HEADER = WAL_MAGIC + struct.pack("<I", FORMAT)
RECORD_HEADER = struct.Struct("<II")  # length, crc32
#: A record longer than this is taken as corruption, not as a delta.
MAX_RECORD_BYTES = 1 << 30
IDENTITY_FILE = "store.json"
SNAPSHOT_FILE = "snapshot.npz"
_WAL_NAME = re.compile(r"^wal-(\d+)\.log$")


class StoreError(RuntimeError):
    """A store that cannot be used; the text names the folder and the problem."""


@dataclass(frozen=True)
class StoreIdentity:
    """What a store belongs to: the mission name, its grid and its sensor model (the prior)."""

    mission: str
    grid: Grid
    sensor: SensorModel

    def to_json(self) -> dict:
        s = self.sensor
        return {
            "format": FORMAT,
            "mission": self.mission,
            "grid": self.grid.to_dict(),
            "sensor": {"sigma_min": s.sigma_min, "zeta": s.zeta, "tau": s.tau, "max_range": s.max_range},
        }

    def matches(self, data: dict) -> bool:
        try:
            grid = Grid.from_dict(data["grid"])
            sensor = SensorModel(**data["sensor"])
        except (KeyError, TypeError, ValueError):
            return False
        return data.get("mission") == self.mission and grid.matches(self.grid) and sensor == self.sensor

    def describe(self) -> str:
        return f"mission {self.mission!r}, grid {describe_grid(self.grid)}, sensor {self.sensor}"


@dataclass
class Recovered:
    """What a store held at start: the snapshot's arrays (None before the first snapshot),
    its ledger and counters, and the WAL payloads written after it, in order."""

    lam: np.ndarray | None = None
    eta: np.ndarray | None = None
    ledger_json: str = "[]"
    counters: dict = field(default_factory=dict)
    wal_payloads: list[bytes] = field(default_factory=list)
    torn_bytes: int = 0
    #: the snapshot's other arrays (the per-robot contributions of map_server.contributions)
    arrays: dict[str, np.ndarray] = field(default_factory=dict)


def _fsync_dir(path: Path) -> None:
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _write_atomic(path: Path, data: bytes) -> None:
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as f:
        f.write(data)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, path)
    _fsync_dir(path.parent)


def read_wal(path: Path, truncate: bool = True) -> tuple[list[bytes], int]:
    """The intact records of a WAL file and the number of bytes after them (torn or corrupt),
    which are cut off the file when ``truncate``. Raises StoreError for a file that is not a WAL."""
    data = path.read_bytes()
    if len(data) < len(WAL_HEADER):
        if data and not WAL_HEADER.startswith(data):
            raise StoreError(f"{path}: not a swarm write-ahead log (bad header)")
        good = 0  # a torn header: the file holds no record
        payloads: list[bytes] = []
    else:
        if data[: len(WAL_MAGIC)] != WAL_MAGIC:
            raise StoreError(f"{path}: not a swarm write-ahead log (bad magic)")
        (version,) = struct.unpack_from("<I", data, len(WAL_MAGIC))
        if version != FORMAT:
            raise StoreError(f"{path}: write-ahead log format {version}, this server reads {FORMAT}")
        payloads, good = _records(data)
    torn = len(data) - good
    if torn and truncate:
        with open(path, "r+b") as f:
            f.truncate(good)
            f.flush()
            os.fsync(f.fileno())
    return payloads, torn


def _records(data: bytes) -> tuple[list[bytes], int]:
    """Records of a WAL image after its header; the offset where the intact ones end."""
    payloads = []
    pos = len(WAL_HEADER)
    while pos + RECORD_HEADER.size <= len(data):
        length, crc = RECORD_HEADER.unpack_from(data, pos)
        start = pos + RECORD_HEADER.size
        if length > MAX_RECORD_BYTES or start + length > len(data):
            break
        payload = data[start : start + length]
        if zlib.crc32(payload) != crc:
            break
        payloads.append(payload)
        pos = start + length
    return payloads, pos


def encode_records(payloads: Sequence[bytes]) -> bytes:
    """WAL records (length, CRC32, payload) of ``payloads``."""
    parts = []
    for p in payloads:
        parts.append(RECORD_HEADER.pack(len(p), zlib.crc32(p)))
        parts.append(p)
    return b"".join(parts)


class Store:
    """A snapshot and a write-ahead log in one folder; use :meth:`open`."""

    def __init__(self, path: Path, identity: StoreIdentity, generation: int, fsync: bool = True) -> None:
        self.path = path
        self.identity = identity
        self.generation = generation
        self.fsync = fsync
        self.wal_records = 0
        self.wal_bytes = 0
        self.snapshots_written = 0
        self._wal: int | None = None  # file descriptor of the open log

    # -- opening and recovery ------------------------------------------------------------
    @classmethod
    def open(cls, path: str | Path, identity: StoreIdentity, fsync: bool = True) -> tuple[Store, Recovered]:
        """Open (or create) the store at ``path`` for ``identity`` and recover what it holds.

        Raises StoreError when the folder belongs to another mission or grid, or is not a store.
        """
        path = Path(path)
        ident_path = path / IDENTITY_FILE
        if ident_path.exists():
            try:
                data = json.loads(ident_path.read_text())
            except (OSError, ValueError) as exc:
                raise StoreError(f"{ident_path}: unreadable store identity: {exc}") from exc
            if not isinstance(data, dict) or data.get("format") != FORMAT:
                raise StoreError(f"{ident_path}: not a format-{FORMAT} swarm map store")
            if not identity.matches(data):
                raise StoreError(
                    f"{path}: this store was written for {_describe_json(data)}; the server runs "
                    f"{identity.describe()}. Use another --store folder, or remove {path} to start afresh"
                )
        else:
            # a start killed before store.json replaced its temporary file leaves only that file
            leftover = IDENTITY_FILE + ".tmp"
            if path.exists() and any(p.name != leftover for p in path.iterdir()):
                raise StoreError(f"{path}: folder is not empty and has no {IDENTITY_FILE}: not a map store")
            path.mkdir(parents=True, exist_ok=True)
            _write_atomic(ident_path, json.dumps(identity.to_json(), indent=1).encode())
        for tmp in path.glob("*.tmp"):
            tmp.unlink()

        recovered = Recovered()
        generation = 1
        snap_path = path / SNAPSHOT_FILE
        if snap_path.exists():
            generation = cls._load_snapshot(snap_path, identity, recovered)
        store = cls(path, identity, generation, fsync)
        for gen, wal in store._wal_files():
            if gen < generation:
                wal.unlink()  # compacted into the snapshot already
            elif gen > generation:
                raise StoreError(f"{wal}: a log newer than {snap_path} (generation {generation})")
        wal_path = store._wal_path(generation)
        if wal_path.exists():
            payloads, torn = read_wal(wal_path)
            recovered.wal_payloads = payloads
            recovered.torn_bytes = torn
            if torn:
                log.warning(
                    "%s: cut %d bytes of a torn or corrupt tail after %d records",
                    wal_path,
                    torn,
                    len(payloads),
                )
            store.wal_records = len(payloads)
            store.wal_bytes = wal_path.stat().st_size - len(WAL_HEADER)
        store._open_wal()
        return store, recovered

    @staticmethod
    def _load_snapshot(snap_path: Path, identity: StoreIdentity, out: Recovered) -> int:
        try:
            with np.load(snap_path, allow_pickle=False) as data:
                grid = Grid.from_dict(json.loads(str(data["grid"])))
                lam = data["lam"].astype(np.float32)
                eta = data["eta"].astype(np.float32)
                out.ledger_json = str(data["ledger"])
                out.counters = json.loads(str(data["counters"]))
                generation = int(data["wal"])
                standard = {"grid", "lam", "eta", "ledger", "counters", "wal"}
                out.arrays = {name: data[name] for name in data.files if name not in standard}
        except (OSError, KeyError, ValueError) as exc:
            raise StoreError(f"{snap_path}: cannot read snapshot: {exc}") from exc
        if not grid.matches(identity.grid) or lam.shape != (grid.size,) or eta.shape != (grid.size,):
            raise StoreError(f"{snap_path}: snapshot grid {describe_grid(grid)} does not match the store")
        out.lam, out.eta = lam, eta
        return generation

    def _wal_path(self, generation: int) -> Path:
        return self.path / f"wal-{generation:06d}.log"

    def _wal_files(self) -> list[tuple[int, Path]]:
        found = []
        for p in self.path.iterdir():
            m = _WAL_NAME.match(p.name)
            if m:
                found.append((int(m.group(1)), p))
        return sorted(found)

    def _open_wal(self) -> None:
        wal_path = self._wal_path(self.generation)
        fresh = not wal_path.exists() or wal_path.stat().st_size == 0
        if fresh:
            with open(wal_path, "wb") as f:
                f.write(WAL_HEADER)
                f.flush()
                os.fsync(f.fileno())
            _fsync_dir(self.path)
        self._wal = os.open(wal_path, os.O_WRONLY | os.O_APPEND)

    # -- writing -------------------------------------------------------------------------
    def append(self, payloads: Sequence[bytes]) -> None:
        """Append one record per payload and fsync: on return they are durable.

        On an OSError (disk full, I/O error) the log is cut back to where it was, so a partial
        record never hides the records written after it, and the error is raised; if even
        that fails the store closes and every later append raises StoreError.
        """
        if self._wal is None:
            raise StoreError(f"{self.path}: store is closed")
        data = memoryview(encode_records(payloads))
        start = os.lseek(self._wal, 0, os.SEEK_END)
        try:
            written = 0
            while written < len(data):
                written += os.write(self._wal, data[written:])
            if self.fsync:
                os.fsync(self._wal)
        except OSError:
            try:
                os.ftruncate(self._wal, start)
                os.fsync(self._wal)
            except OSError:
                self.close()
            raise
        self.wal_records += len(payloads)
        self.wal_bytes += len(data)

    def should_compact(self, max_bytes: int, max_records: int) -> bool:
        return self.wal_records > 0 and (self.wal_bytes >= max_bytes or self.wal_records >= max_records)

    def compact(
        self,
        grid: Grid,
        lam: np.ndarray,
        eta: np.ndarray,
        ledger_json: str,
        counters: dict,
        arrays: dict[str, np.ndarray] | None = None,
    ) -> None:
        """Write the snapshot atomically (with ``arrays`` beside the map), then start the next
        log and delete the old one."""
        nxt = self.generation + 1
        tmp = self.path / (SNAPSHOT_FILE + ".tmp")
        with open(tmp, "wb") as f:
            np.savez(
                f,
                lam=np.ascontiguousarray(lam, np.float32),
                eta=np.ascontiguousarray(eta, np.float32),
                grid=np.array(json.dumps(grid.to_dict())),
                ledger=np.array(ledger_json),
                counters=np.array(json.dumps(counters)),
                wal=np.int64(nxt),
                **{name: np.ascontiguousarray(a, np.float32) for name, a in (arrays or {}).items()},
            )
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, self.path / SNAPSHOT_FILE)
        _fsync_dir(self.path)
        old = self._wal_path(self.generation)
        self.close()
        self.generation = nxt
        self._open_wal()
        old.unlink(missing_ok=True)
        self.wal_records = 0
        self.wal_bytes = 0
        self.snapshots_written += 1

    def close(self) -> None:
        if self._wal is not None:
            os.close(self._wal)
            self._wal = None


def _describe_json(data: dict) -> str:
    try:
        grid = describe_grid(Grid.from_dict(data["grid"]))
    except (KeyError, TypeError, ValueError):
        grid = "an unreadable grid"
    return f"mission {data.get('mission')!r}, grid {grid}, sensor {data.get('sensor')}"
