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
        self.pending_lam = np.zeros(size, np.float32)
        self.pending_eta = np.zeros(size, np.float32)
        self._touched = np.zeros(size, bool)
        # What the utility filter last judged not worth sending, per voxel: the map's lam and
        # eta then, and whether the pending part changed since. A pending voxel whose map
        # values and pending part are unchanged gets the same verdict again, so it is skipped.
        self._judged_lam = np.full(size, np.nan, np.float32)
        self._judged_eta = np.full(size, np.nan, np.float32)
        self._pending_changed = np.zeros(size, bool)
        # what each held voxel's pending information is worth (bits), as last judged
        self._held_bits = np.zeros(size, np.float32)
        self.seq = 0
        self.unacked: OrderedDict[int, Delta] = OrderedDict()
        #: the frame thread adds to ``unacked``, the ack thread forgets and copies it
        self._unacked_lock = threading.Lock()
        self.stats = OutboxStats()

    def add(self, delta: Delta) -> None:
        """Accumulate a batch's information as pending."""
        idx = delta.idx.astype(np.int64)
        self.pending_lam[idx] += delta.dlam
        self.pending_eta[idx] += delta.deta
        self._touched[idx] = True
        self._pending_changed[idx] = True

    def take(self, lam: np.ndarray, eta: np.ndarray, flush: bool = False) -> tuple[int, Delta] | None:
        """The next delta to send, numbered, or None when nothing is worth sending.

        ``lam``/``eta`` are the agent's map, which already holds the pending information; the
        team is taken to know the map minus the pending part. A voxel goes out when adding its
        pending information changes the entropy by ``share_min_bits`` or more, either way (all
        with ``flush``), or when the held voxels are worth more than ``max_held_bits`` together.
        """
        idx = touched = np.flatnonzero(self._touched)
        if len(idx) == 0:
            return None
        if not flush and self.share_min_bits > 0:
            lam_now, eta_now = lam[idx], eta[idx]
            # only the voxels whose map or pending part changed since they were last judged
            stale = (
                self._pending_changed[idx]
                | (lam_now != self._judged_lam[idx])
                | (eta_now != self._judged_eta[idx])
            )
            idx, lam_now, eta_now = idx[stale], lam_now[stale], eta_now[stale]
            dlam, deta = self.pending_lam[idx], self.pending_eta[idx]
            lam_team = np.maximum(lam_now - dlam, np.float32(1e-12))
            h_team = self.table((eta_now - deta) / lam_team, 1.0 / np.sqrt(lam_team))
            h_now = self.table(eta_now / lam_now, 1.0 / np.sqrt(lam_now))
            gain = np.abs(h_team - h_now).astype(np.float32)
            useful = gain >= self.share_min_bits
            kept = idx[~useful]
            self._judged_lam[kept] = lam_now[~useful]
            self._judged_eta[kept] = eta_now[~useful]
            self._pending_changed[kept] = False
            self._held_bits[kept] = gain[~useful]
            self._held_bits[idx[useful]] = 0
            idx = np.union1d(idx[useful], self._released_held(touched))
            dlam, deta = self.pending_lam[idx], self.pending_eta[idx]
            if len(idx) == 0:
                return None
        else:
            dlam, deta = self.pending_lam[idx], self.pending_eta[idx]
        delta = Delta(idx.astype(np.uint32), dlam.copy(), deta.copy())
        self.pending_lam[idx] = 0
        self.pending_eta[idx] = 0
        self._touched[idx] = False
        self._held_bits[idx] = 0
        self.seq += 1
        with self._unacked_lock:
            self.unacked[self.seq] = delta
            while len(self.unacked) > self.max_unacked:
                self.unacked.popitem(last=False)
                self.stats.dropped_unacked += 1
        self.stats.deltas_sent += 1
        self.stats.voxels_sent += len(delta)
        return self.seq, delta

    @property
    def held_bits(self) -> float:
        """What the voxels the filter holds back are worth together (bits), as last judged."""
        return float(self._held_bits[self._touched].sum(dtype=np.float64))

    def _released_held(self, touched: np.ndarray) -> np.ndarray:
        """Held voxels (among ``touched``, the pending ones) to send although each is under
        ``share_min_bits``: none while what is held is worth at most ``max_held_bits``; else
        the most valuable, until what stays held is worth at most half of it. Sorted indices."""
        if not math.isfinite(self.max_held_bits):
            return np.empty(0, np.int64)
        held = touched[self._held_bits[touched] > 0]
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
        idx = np.flatnonzero(self._touched)
        return Delta(idx.astype(np.uint32), self.pending_lam[idx].copy(), self.pending_eta[idx].copy())

    def acknowledge(self, last_contiguous_seq: int) -> None:
        """Forget every delta up to the server's contiguous ack."""
        with self._unacked_lock:
            for seq in [s for s in self.unacked if s <= last_contiguous_seq]:
                del self.unacked[seq]

    def to_resend(self) -> list[tuple[int, Delta]]:
        """Unacked deltas, oldest first (a copy: safe from any thread), to send again."""
        with self._unacked_lock:
            return list(self.unacked.items())
