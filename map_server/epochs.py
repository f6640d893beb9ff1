"""The epochs the map server issues, their keys, and which of them are live (docs/protocol.md,
"Epochs").

Each robot's epochs come from its own counter: 1, 2, 3, ... (a store that already holds
deltas of larger epochs, an older store's clock epochs, continues after the largest). An
epoch is issued with a random 16-byte key (the MAC key of its deltas) and is *live* until
the server fences it: a robot keeps at most ``max_live`` live epochs; issuing one more fences
first the oldest epoch that never had a delta applied, else the one whose last delta is the
oldest. Only live epochs' deltas are taken; a fenced epoch's deltas already applied stay in
the map, the log and the snapshot.

Persistence: ``epochs.json`` in the store, written whole at every issue (temporary file,
fsync, rename, fsync of the folder) before the grant is answered, so a server restarted
after a SIGKILL or a power cut never issues an epoch twice nor forgets a live key::

    {"format": 1, "robots": {"r1": {"next": 4, "live": [[2, "<32 hex>"], [3, "..."]],
                                    "fenced": [1]}}}
"""

from __future__ import annotations

import json
import secrets
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path

from map_server.store_files import OS_FILES, StoreFiles
from swarm.protocol.epochs import KEY_BYTES

EPOCHS_FILE = "epochs.json"
FORMAT = 1
#: Live epochs per robot (an epoch is one agent run; more than one is live only across restarts).
MAX_LIVE_EPOCHS = 4
#: Fenced epochs remembered per robot, to say ``stale_epoch`` rather than ``unknown_epoch``.
FENCED_REMEMBERED = 64


class EpochFileError(RuntimeError):
    """``epochs.json`` cannot be read; the text names the file."""


@dataclass
class _Robot:
    next: int = 1
    live: dict[int, bytes] = field(default_factory=dict)  # epoch -> key, in issue order
    fenced: list[int] = field(default_factory=list)


class EpochRegistry:
    """Issued epochs per robot; :meth:`issue` persists before it returns. One :meth:`issue` at a
    time (the caller serialises them); the readers (:meth:`key_of`, :meth:`refusal`,
    :meth:`touch`) may run meanwhile on another thread: each reads or sets one dict entry."""

    def __init__(
        self, folder: Path | None, files: StoreFiles = OS_FILES, max_live: int = MAX_LIVE_EPOCHS
    ) -> None:
        self.folder = folder
        self.files = files
        self.max_live = max_live
        self._robots: dict[str, _Robot] = {}
        #: (robot, epoch) -> serial of its latest applied delta (in memory; absent: never used)
        self._activity: dict[tuple[str, int], int] = {}
        self._serial = 0

    # -- loading ---------------------------------------------------------------------------
    @classmethod
    def load(
        cls,
        folder: Path,
        files: StoreFiles = OS_FILES,
        max_live: int = MAX_LIVE_EPOCHS,
        used: Iterable[tuple[str, int]] = (),
        counters: dict | None = None,
    ) -> EpochRegistry:
        """The registry of a store: ``epochs.json`` (absent in a new or an older store), with
        each robot's counter raised past ``counters`` (the snapshot's copy) and past every
        ``used`` (robot, epoch) of the store's ledger. Raises EpochFileError."""
        reg = cls(folder, files, max_live)
        path = folder / EPOCHS_FILE
        if path.exists():
            try:
                data = json.loads(path.read_text())
                if not isinstance(data, dict) or data.get("format") != FORMAT:
                    raise ValueError(f"not a format-{FORMAT} epochs file")
                for robot, entry in data["robots"].items():
                    live = {int(e): bytes.fromhex(k) for e, k in entry["live"]}
                    if any(len(k) != KEY_BYTES for k in live.values()):
                        raise ValueError(f"a key of {robot} is not {KEY_BYTES} bytes")
                    reg._robots[str(robot)] = _Robot(
                        int(entry["next"]), live, [int(e) for e in entry["fenced"]]
                    )
            except (OSError, ValueError, KeyError, TypeError, AttributeError) as exc:
                raise EpochFileError(f"{path}: unreadable: {exc}") from exc
        for robot, nxt in (counters or {}).items():
            entry = reg._robots.setdefault(str(robot), _Robot())
            entry.next = max(entry.next, int(nxt))
        for robot, epoch in sorted(used, key=lambda u: u[1]):
            entry = reg._robots.setdefault(robot, _Robot())
            entry.next = max(entry.next, epoch + 1)
            if epoch in entry.live:
                reg.touch(robot, epoch)
        return reg

    # -- issuing and fencing ---------------------------------------------------------------
    def issue(self, robot: str) -> tuple[int, bytes, list[int]]:
        """A new epoch of ``robot`` and its key, and the epochs this fenced; durable on return
        (raises OSError, issuing nothing, when the file cannot be written)."""
        entry = self._robots.setdefault(robot, _Robot())
        epoch, key = entry.next, secrets.token_bytes(KEY_BYTES)
        before = (entry.next, dict(entry.live), list(entry.fenced))
        entry.next += 1
        entry.live[epoch] = key
        fenced = []
        while len(entry.live) > self.max_live:
            victim = self._victim(robot, entry, epoch)
            del entry.live[victim]
            entry.fenced = (entry.fenced + [victim])[-FENCED_REMEMBERED:]
            fenced.append(victim)
        try:
            self.save()
        except OSError:
            entry.next, entry.live, entry.fenced = before
            raise
        for victim in fenced:
            self._activity.pop((robot, victim), None)
        return epoch, key, fenced

    def _victim(self, robot: str, entry: _Robot, keep: int) -> int:
        """The epoch to fence: the oldest never used, else the least recently active."""
        candidates = [e for e in entry.live if e != keep]
        unused = [e for e in candidates if (robot, e) not in self._activity]
        if unused:
            return min(unused)
        return min(candidates, key=lambda e: self._activity[(robot, e)])

    def touch(self, robot: str, epoch: int) -> None:
        """A delta of (robot, epoch) was applied: it is the robot's most recently active."""
        self._serial += 1
        self._activity[(robot, epoch)] = self._serial

    # -- questions -------------------------------------------------------------------------
    def key_of(self, robot: str, epoch: int) -> bytes | None:
        entry = self._robots.get(robot)
        return None if entry is None else entry.live.get(epoch)

    def refusal(self, robot: str, epoch: int) -> tuple[str, str] | None:
        """(kind, reason) unless ``epoch`` is a live epoch of ``robot``."""
        entry = self._robots.get(robot)
        if entry is not None and epoch in entry.live:
            return None
        if entry is not None and epoch in entry.fenced:
            return "stale_epoch", f"epoch {epoch} of {robot} was fenced by a newer one: ask map/epoch again"
        return "unknown_epoch", f"epoch {epoch} was not issued to {robot} (or was fenced): ask map/epoch"

    def live(self) -> dict[str, list[int]]:
        """``{robot: [live epochs, ascending]}``."""
        return {r: sorted(e.live) for r, e in self._robots.items() if e.live}

    def counters(self) -> dict[str, int]:
        """``{robot: next epoch}``, kept in the snapshot's counters too."""
        return {r: e.next for r, e in self._robots.items()}

    # -- persistence -----------------------------------------------------------------------
    def save(self) -> None:
        """Write ``epochs.json`` atomically (no-op for a registry without a folder)."""
        if self.folder is None:
            return
        robots = {
            r: {"next": e.next, "live": [[ep, k.hex()] for ep, k in e.live.items()], "fenced": e.fenced}
            for r, e in sorted(self._robots.items())
        }
        text = json.dumps({"format": FORMAT, "robots": robots}, separators=(",", ":")).encode()
        tmp, path = self.folder / (EPOCHS_FILE + ".tmp"), self.folder / EPOCHS_FILE
        self.files.write_file(tmp, lambda f: f.write(text))
        self.files.replace(tmp, path)
        self.files.fsync_dir(self.folder)
