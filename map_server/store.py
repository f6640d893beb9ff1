"""The map server's store: a snapshot plus a write-ahead log of accepted delta payloads.

Layout of ``--store DIR`` (see docs/protocol.md, "Store layout"):

- ``store.json``: what the store belongs to (format, mission, grid, sensor model); written
  once when the store is created, checked on every start.
- ``store.lock``: held (``flock``) by the running server, naming its pid and host
  (:class:`map_server.store_files.StoreLock`).
- ``snapshot.npz``: ``lam``, ``eta`` (float32, flat, prior included), ``ledger`` (applied
  delta ids, JSON), ``counters`` (JSON), ``grid`` (JSON) and ``wal`` (the generation of the
  log that follows it). Written atomically: temporary file, fsync, rename, fsync of the folder.
- ``wal-<generation>.log``: an 8-byte magic ``SWARMWAL``, a uint32 version, then one record
  per accepted delta: uint32 length, uint32 CRC32 of the payload, the raw payload (all
  little-endian). :meth:`Store.append` fsyncs before it returns, so a delta counts as
  durable (and is acked) only once its record is on disk.

Recovery loads the snapshot and reads the log of its generation; a torn or corrupt tail
(after a crash or power cut mid-write) is detected by length and CRC, reported and cut off,
so the good prefix survives. Compaction writes a new snapshot and starts the next log; it
waits while the disk could not hold the snapshot and still leave ``log_reserve_bytes`` for
the log, so a snapshot never takes the room the log needs. Every change on disk goes through
one small layer, :class:`map_server.store_files.StoreFiles`.
"""

from __future__ import annotations

import json
import logging
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from map_server.ledger import describe_grid
from map_server.store_files import LOCK_FILE, NO_SPACE, OS_FILES, StoreFiles, StoreInUse, StoreLock
from map_server.wal_file import FORMAT, WAL_HEADER, StoreError, encode_records, read_wal
from swarm.map.grid import Grid
from swarm.map.sensor_model import SensorModel

log = logging.getLogger("swarm.server.store")

IDENTITY_FILE = "store.json"
SNAPSHOT_FILE = "snapshot.npz"
#: Free bytes a compaction leaves for the log at least (it waits for room otherwise).
LOG_RESERVE_BYTES = 64 << 20
_WAL_NAME = re.compile(r"^wal-(\d+)\.log$")
#: What a folder may hold and still be taken as a new store (a start killed while it created one).
_NEW_STORE_LEFTOVERS = {IDENTITY_FILE + ".tmp", LOCK_FILE}


class NoRoom(OSError):
    """A compaction put off: the disk could not hold the snapshot and the log's reserve."""


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


class Store:
    """A snapshot and a write-ahead log in one folder; use :meth:`open`."""

    def __init__(
        self,
        path: Path,
        identity: StoreIdentity,
        generation: int,
        fsync: bool = True,
        files: StoreFiles = OS_FILES,
    ) -> None:
        self.path = path
        self.identity = identity
        self.generation = generation
        self.fsync = fsync
        self.files = files
        self.log_reserve_bytes = LOG_RESERVE_BYTES
        self.wal_records = 0
        self.wal_bytes = 0
        self.snapshots_written = 0
        #: True when this open created the store (a failed start removes it again: discard_new)
        self.created = False
        self._made_folder = False
        self._wal: int | None = None  # file descriptor of the open log
        self._good_size = len(WAL_HEADER)  # where the log's intact records end
        self._closed = False
        self._lock: StoreLock | None = None

    # -- opening and recovery ------------------------------------------------------------
    @classmethod
    def open(
        cls, path: str | Path, identity: StoreIdentity, fsync: bool = True, files: StoreFiles = OS_FILES
    ) -> tuple[Store, Recovered]:
        """Open (or create) the store at ``path`` for ``identity``, lock it and recover what it holds.

        Raises StoreError when the folder belongs to another mission or grid, is not a store,
        or is in use by another server (the message names that server's pid and host).
        """
        path = Path(path)
        store = cls(path, identity, 1, fsync, files)
        try:
            recovered = store._open()
        except Exception:
            store.discard_new()
            raise
        except BaseException:  # interrupted: keep the files as a killed process would
            store.close()
            raise
        return store, recovered

    def _open(self) -> Recovered:
        path, files = self.path, self.files
        ident_path = path / IDENTITY_FILE
        if not ident_path.exists():
            if path.exists() and any(p.name not in _NEW_STORE_LEFTOVERS for p in path.iterdir()):
                raise StoreError(f"{path}: folder is not empty and has no {IDENTITY_FILE}: not a map store")
            self._made_folder = not path.exists()
            files.make_dir(path)
        self._take_lock()
        if ident_path.exists():
            self._check_identity(ident_path)
        else:
            self.created = True
            tmp = path / (IDENTITY_FILE + ".tmp")
            text = json.dumps(self.identity.to_json(), indent=1).encode()
            files.write_file(tmp, lambda f: f.write(text))
            files.replace(tmp, ident_path)
            files.fsync_dir(path)
        for tmp in path.glob("*.tmp"):
            files.unlink(tmp)

        recovered = Recovered()
        snap_path = path / SNAPSHOT_FILE
        if snap_path.exists():
            self.generation = self._load_snapshot(snap_path, self.identity, recovered)
        for gen, wal in self._wal_files():
            if gen < self.generation:
                files.unlink(wal)  # compacted into the snapshot already
            elif gen > self.generation:
                raise StoreError(f"{wal}: a log newer than {snap_path} (generation {self.generation})")
        wal_path = self._wal_path(self.generation)
        if wal_path.exists():
            payloads, torn = read_wal(wal_path, files=files)
            recovered.wal_payloads = payloads
            recovered.torn_bytes = torn
            if torn:
                log.warning(
                    "%s: cut %d bytes of a torn or corrupt tail after %d records",
                    wal_path,
                    torn,
                    len(payloads),
                )
            self.wal_records = len(payloads)
            self._good_size = max(wal_path.stat().st_size, len(WAL_HEADER))
            self.wal_bytes = self._good_size - len(WAL_HEADER)
        self._open_wal()
        return recovered

    def _take_lock(self) -> None:
        try:
            self._lock = StoreLock(self.path)
        except StoreInUse as exc:
            raise StoreError(str(exc)) from None

    def _check_identity(self, ident_path: Path) -> None:
        try:
            data = json.loads(ident_path.read_text())
        except (OSError, ValueError) as exc:
            raise StoreError(f"{ident_path}: unreadable store identity: {exc}") from exc
        if not isinstance(data, dict) or data.get("format") != FORMAT:
            raise StoreError(f"{ident_path}: not a format-{FORMAT} swarm map store")
        if not self.identity.matches(data):
            raise StoreError(
                f"{self.path}: this store was written for {_describe_json(data)}; the server runs "
                f"{self.identity.describe()}. Use another --store folder, or remove {self.path} to start "
                "afresh"
            )

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
        """Open the log of this generation for appending, first writing its header (and
        syncing the folder) when it has none, and cutting it back to its intact records."""
        wal_path = self._wal_path(self.generation)
        if not wal_path.exists() or wal_path.stat().st_size < len(WAL_HEADER):
            self.files.write_file(wal_path, lambda f: f.write(WAL_HEADER))
            self.files.fsync_dir(self.path)
        fd = self.files.open_append(wal_path)
        try:
            if self.files.size(fd) != self._good_size:  # a failed append could not cut itself off
                self.files.truncate(fd, self._good_size)
        except BaseException:
            self.files.close(fd)
            raise
        self._wal = fd

    # -- writing -------------------------------------------------------------------------
    def append(self, payloads: Sequence[bytes]) -> None:
        """Append one record per payload and fsync: on return they are durable.

        On an OSError (disk full, I/O error) the log is cut back to where it was, so a partial
        record never hides the records written after it, and the error is raised; if even the
        cut fails, the next append opens the log again and cuts it first (raising OSError
        while it cannot). Raises StoreError once the store is closed.
        """
        if self._closed:
            raise StoreError(f"{self.path}: store is closed")
        if self._wal is None:
            self._open_wal()
        data = encode_records(payloads)
        try:
            self.files.append(self._wal, data)
            if self.fsync:
                self.files.fsync(self._wal)
        except OSError:
            try:
                self.files.truncate(self._wal, self._good_size)
            except OSError:
                self._drop_wal()
            raise
        self._good_size += len(data)
        self.wal_records += len(payloads)
        self.wal_bytes += len(data)

    def _drop_wal(self) -> None:
        if self._wal is not None:
            try:
                self.files.close(self._wal)
            except OSError:
                pass
            self._wal = None

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
        log and delete the old one.

        Raises :class:`NoRoom` (writing nothing) when the disk could not hold the snapshot and
        still leave ``log_reserve_bytes``; any other OSError after removing the half-written
        snapshot. Either way the old snapshot and log stay in force and appends go on.
        """
        nxt = self.generation + 1
        arrays = {"lam": lam, "eta": eta, **(arrays or {})}
        fields = {"grid": json.dumps(grid.to_dict()), "ledger": ledger_json, "counters": json.dumps(counters)}
        needed = sum(4 * a.size for a in arrays.values()) + sum(map(len, fields.values())) + (64 << 10)
        free = self.files.free_bytes(self.path)
        if free < needed + self.log_reserve_bytes:
            raise NoRoom(
                f"{self.path}: {free / 2**20:.1f} MB free; a snapshot needs {needed / 2**20:.1f} MB and "
                f"{self.log_reserve_bytes / 2**20:.1f} MB stay for the log"
            )
        tmp = self.path / (SNAPSHOT_FILE + ".tmp")

        def fill(f) -> None:
            np.savez(
                f,
                **{name: np.ascontiguousarray(a, np.float32) for name, a in arrays.items()},
                **{name: np.array(text) for name, text in fields.items()},
                wal=np.int64(nxt),
            )

        try:
            self.files.write_file(tmp, fill)
        except Exception:
            self.files.unlink(tmp)  # a half-written snapshot must not take the log's room
            raise
        self.files.replace(tmp, self.path / SNAPSHOT_FILE)
        self.files.fsync_dir(self.path)
        # the snapshot names generation nxt: from here on, records go to its log only
        old = self._wal_path(self.generation)
        self._drop_wal()
        self.generation = nxt
        self._good_size = len(WAL_HEADER)
        self.wal_records = 0
        self.wal_bytes = 0
        self.snapshots_written += 1
        try:
            self._open_wal()
            self.files.unlink(old)
        except OSError as exc:  # the next append creates the log; the next start deletes the old one
            log.warning("%s: after the snapshot: %s", self.path, exc)

    def close(self) -> None:
        """Close the log and release the lock; appends raise StoreError after this."""
        self._drop_wal()
        self._closed = True
        if self._lock is not None:
            self._lock.release()
            self._lock = None

    def discard_new(self) -> None:
        """Close, and when this open created the store and nothing was logged in it, delete
        it again (the folder too, if this open made it): a start that fails leaves nothing."""
        self.close()
        if not self.created or self.wal_records or self.snapshots_written:
            return
        for name in (IDENTITY_FILE, IDENTITY_FILE + ".tmp", self._wal_path(1).name, LOCK_FILE):
            try:
                (self.path / name).unlink(missing_ok=True)
            except OSError:
                return
        if self._made_folder:
            try:
                self.path.rmdir()
            except OSError:
                pass


def is_no_space(exc: BaseException) -> bool:
    """Whether ``exc`` says the disk (or the quota) is full."""
    return isinstance(exc, NoRoom) or (isinstance(exc, OSError) and exc.errno in NO_SPACE)


def _describe_json(data: dict) -> str:
    try:
        grid = describe_grid(Grid.from_dict(data["grid"]))
    except (KeyError, TypeError, ValueError):
        grid = "an unreadable grid"
    return f"mission {data.get('mission')!r}, grid {grid}, sensor {data.get('sensor')}"
