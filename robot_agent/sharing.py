"""Sharing only what is useful: the agent's delta outbox (docs/design.md sections 3 and 5).

Information gathered locally accumulates per voxel as a pending delta. A voxel is sent once
its pending information is worth at least ``share_min_bits``: by how much the entropy of the
team's belief changes when that information is added to it, either way. Most information
lowers it; information that contradicts the team's belief (a voxel the team holds free seen
occupied, or the reverse) raises it, and matters as much: held back, it would leave the
team map surer, and its entropy lower, than the evidence says.

What the filter holds back is bounded as a whole: when the voxels it holds are worth more
than ``max_held_bits`` together, the most valuable of them go out too, until what is held is
worth at most half of that. Faint readings (a glance through a door, the far end of a beam)
are each under ``share_min_bits``, but a robot gathers them by the hundred thousand; held
back without a bound, they hide from the team map, and from the teammates, entropy this
robot has already removed.

Sent deltas are numbered (epoch, seq 1, 2, ...) and kept until the map server acknowledges
them, so they can be sent again after a reconnect or a server restart; the store is bounded
and counts what it drops.
"""

from __future__ import annotations

import math
import threading
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from swarm.map.delta import Delta
from swarm.map.entropy_table import EntropyTable

#: the outbox's parallel arrays over its pending voxels, sorted by voxel index
_PENDING_ARRAYS = ("_idx", "_lam", "_eta", "_judged_lam", "_judged_eta", "_changed", "_held_bits")


@dataclass
class OutboxStats:
    deltas_sent: int = 0
    voxels_sent: int = 0
    bytes_sent: int = 0
    resent: int = 0
    dropped_unacked: int = 0
    released_held: int = 0  # voxels sent under share_min_bits because too much was held


class DeltaOutbox:
    """Pending per-voxel information, the utility filter, and the unacked store of one agent."""

    def __init__(
        self,
        size: int,
        share_min_bits: float,
        table: EntropyTable,
        max_unacked: int = 2000,
        max_held_bits: float = math.inf,
    ) -> None:
        if not max_held_bits > 0:
            raise ValueError(f"max_held_bits must be > 0 (inf: no bound), got {max_held_bits}")
        self.size = size
        self.share_min_bits = float(share_min_bits)
        self.max_held_bits = float(max_held_bits)
        self.table = table
        self.max_unacked = max_unacked
        # The pending voxels, as parallel arrays sorted by voxel index (memory and work grow with
        # what is pending, not with the grid): the information gathered and not sent, what the
        # utility filter last judged not worth sending (the map's lam and eta then, NaN before
        # any verdict) and whether the pending part changed since, and what each is worth
        # (bits) as last judged. A pending voxel whose map values and pending part are unchanged
        # gets the same verdict again, so it is skipped.
        self._idx = np.zeros(0, np.int64)
        self._lam = np.zeros(0, np.float32)
        self._eta = np.zeros(0, np.float32)
        self._judged_lam = np.zeros(0, np.float32)
        self._judged_eta = np.zeros(0, np.float32)
        self._changed = np.zeros(0, bool)
        self._held_bits = np.zeros(0, np.float32)
        self.seq = 0
        self.unacked: OrderedDict[int, Delta] = OrderedDict()
        #: the frame thread adds to ``unacked``, the ack thread forgets and copies it
        self._unacked_lock = threading.Lock()
        self.stats = OutboxStats()

    def add(self, delta: Delta) -> None:
        """Accumulate a batch's information (sorted unique indices) as pending."""
        idx = delta.idx.astype(np.int64)
        if len(idx) == 0:
            return
        if idx[0] < 0 or idx[-1] >= self.size or np.any(idx[1:] <= idx[:-1]):
            raise ValueError(f"a delta's indices must be sorted, unique and under {self.size}")
        pos = np.searchsorted(self._idx, idx)
        known = pos < len(self._idx)
        known[known] = self._idx[pos[known]] == idx[known]
        at = pos[known]
        self._lam[at] += delta.dlam[known]
        self._eta[at] += delta.deta[known]
        self._changed[at] = True
        new = ~known
        if new.any():
            # the grown arrays: the new voxels at their sorted places, the pending ones around them
            count = int(new.sum())
            slots = np.zeros(len(self._idx) + count, bool)
            new_at = pos[new] + np.arange(count)
            slots[new_at] = True
            old_at = np.flatnonzero(~slots)  # integer places: cheaper than the mask, 7 times
            nan = np.full(count, np.nan, np.float32)
            grown = {
                "_idx": idx[new],
                "_lam": delta.dlam[new],
                "_eta": delta.deta[new],
                "_judged_lam": nan,
                "_judged_eta": nan,
                "_changed": np.ones(count, bool),
                "_held_bits": np.zeros(count, np.float32),
            }
            for name in _PENDING_ARRAYS:
                before = getattr(self, name)
                after = np.empty(len(slots), before.dtype)
                after[new_at], after[old_at] = grown[name], before
                setattr(self, name, after)

    def take(self, lam: np.ndarray, eta: np.ndarray, flush: bool = False) -> tuple[int, Delta] | None:
        """The next delta to send, numbered, or None when nothing is worth sending.

        ``lam``/``eta`` are the agent's map, which already holds the pending information; the
        team is taken to know the map minus the pending part. A voxel goes out when adding its
        pending information changes the entropy by ``share_min_bits`` or more, either way (all
        with ``flush``), or when the held voxels are worth more than ``max_held_bits`` together.
        """
        if len(self._idx) == 0:
            return None
        if not flush and self.share_min_bits > 0:
            lam_now, eta_now = lam[self._idx], eta[self._idx]
            # only the voxels whose map or pending part changed since they were last judged
            stale = np.flatnonzero(
                self._changed | (lam_now != self._judged_lam) | (eta_now != self._judged_eta)
            )
            lam_now, eta_now = lam_now[stale], eta_now[stale]
            dlam, deta = self._lam[stale], self._eta[stale]
            lam_team = np.maximum(lam_now - dlam, np.float32(1e-12))
            h_team = self.table((eta_now - deta) / lam_team, 1.0 / np.sqrt(lam_team))
            h_now = self.table(eta_now / lam_now, 1.0 / np.sqrt(lam_now))
            gain = np.abs(h_team - h_now).astype(np.float32)
            useful = gain >= self.share_min_bits
            kept = stale[~useful]
            self._judged_lam[kept] = lam_now[~useful]
            self._judged_eta[kept] = eta_now[~useful]
            self._changed[kept] = False
            self._held_bits[kept] = gain[~useful]
            self._held_bits[stale[useful]] = 0
            out = np.union1d(stale[useful], self._released_held())
            if len(out) == 0:
                return None
        else:
            out = np.arange(len(self._idx))
        delta = Delta(self._idx[out].astype(np.uint32), self._lam[out].copy(), self._eta[out].copy())
        self._forget(out)
        self.seq += 1
        with self._unacked_lock:
            self.unacked[self.seq] = delta
            while len(self.unacked) > self.max_unacked:
                self.unacked.popitem(last=False)
                self.stats.dropped_unacked += 1
        self.stats.deltas_sent += 1
        self.stats.voxels_sent += len(delta)
        return self.seq, delta

    def _forget(self, positions: np.ndarray) -> None:
        """Drop the pending voxels at ``positions`` (of the sorted arrays): they went out."""
        keep = np.ones(len(self._idx), bool)
        keep[positions] = False
        kept = np.flatnonzero(keep)
        for name in _PENDING_ARRAYS:
            setattr(self, name, getattr(self, name)[kept])

    @property
    def held_bits(self) -> float:
        """What the voxels the filter holds back are worth together (bits), as last judged."""
        return float(self._held_bits.sum(dtype=np.float64))

    def _released_held(self) -> np.ndarray:
        """Held voxels to send although each is under ``share_min_bits``: none while what is
        held is worth at most ``max_held_bits``; else the most valuable, until what stays held
        is worth at most half of it. Sorted positions in the pending arrays."""
        if not math.isfinite(self.max_held_bits):
            return np.empty(0, np.int64)
        held = np.flatnonzero(self._held_bits > 0)
        bits = self._held_bits[held].astype(np.float64)
        total = bits.sum()
        if total <= self.max_held_bits:
            return np.empty(0, np.int64)
        order = np.argsort(bits)[::-1]  # most valuable first
        left = total - np.cumsum(bits[order])
        count = int(np.searchsorted(-left, -0.5 * self.max_held_bits)) + 1
        released = np.sort(held[order[:count]])
        self.stats.released_held += len(released)
        return released

    def pending(self) -> Delta:
        """The information gathered and not sent yet (in the agent's map, in no server's)."""
        return Delta(self._idx.astype(np.uint32), self._lam.copy(), self._eta.copy())

    def acknowledge(self, last_contiguous_seq: int) -> None:
        """Forget every delta up to the server's contiguous ack."""
        with self._unacked_lock:
            for seq in [s for s in self.unacked if s <= last_contiguous_seq]:
                del self.unacked[seq]

    def to_resend(self) -> list[tuple[int, Delta]]:
        """Unacked deltas, oldest first (a copy: safe from any thread), to send again."""
        with self._unacked_lock:
            return list(self.unacked.items())
