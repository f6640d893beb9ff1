"""Sharing only what is useful: the agent's delta outbox (docs/design.md sections 3 and 5).

Information gathered locally accumulates per voxel as a pending delta. A voxel is sent once
its pending information is worth at least ``share_min_bits``: the entropy the team belief
loses when that information is added to it. Sent deltas are numbered (epoch, seq 1, 2, ...)
and kept until the map server acknowledges them, so they can be sent again after a
reconnect or a server restart; the store is bounded and counts what it drops.
"""

from __future__ import annotations

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


class DeltaOutbox:
    """Pending per-voxel information, the utility filter, and the unacked store of one agent."""

    def __init__(
        self, size: int, share_min_bits: float, table: EntropyTable, max_unacked: int = 2000
    ) -> None:
        self.size = size
        self.share_min_bits = float(share_min_bits)
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
        self.seq = 0
        self.unacked: OrderedDict[int, Delta] = OrderedDict()
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
        pending information lowers the entropy by ``share_min_bits`` or more (all with ``flush``).
        """
        idx = np.flatnonzero(self._touched)
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
            useful = (h_team - h_now) >= self.share_min_bits
            kept = idx[~useful]
            self._judged_lam[kept] = lam_now[~useful]
            self._judged_eta[kept] = eta_now[~useful]
            self._pending_changed[kept] = False
            idx, dlam, deta = idx[useful], dlam[useful], deta[useful]
            if len(idx) == 0:
                return None
        else:
            dlam, deta = self.pending_lam[idx], self.pending_eta[idx]
        delta = Delta(idx.astype(np.uint32), dlam.copy(), deta.copy())
        self.pending_lam[idx] = 0
        self.pending_eta[idx] = 0
        self._touched[idx] = False
        self.seq += 1
        self.unacked[self.seq] = delta
        while len(self.unacked) > self.max_unacked:
            self.unacked.popitem(last=False)
            self.stats.dropped_unacked += 1
        self.stats.deltas_sent += 1
        self.stats.voxels_sent += len(delta)
        return self.seq, delta

    def acknowledge(self, last_contiguous_seq: int) -> None:
        """Forget every delta up to the server's contiguous ack."""
        for seq in [s for s in self.unacked if s <= last_contiguous_seq]:
            del self.unacked[seq]

    def to_resend(self) -> list[tuple[int, Delta]]:
        """Unacked deltas, oldest first, to send again."""
        return list(self.unacked.items())
