"""The delta outbox's utility filter over dense per-voxel arrays: the oracle of the sparse
robot_agent.sharing.DeltaOutbox (slow, O(grid) per take; the same verdicts by construction)."""

from __future__ import annotations

import math

import numpy as np

from swarm.map.delta import Delta
from swarm.map.entropy_table import EntropyTable


class DenseOutbox:
    """Pending information in arrays over every voxel; ``take`` returns the delta only."""

    def __init__(self, size: int, share_min_bits: float, table: EntropyTable, max_held_bits: float) -> None:
        self.share_min_bits, self.max_held_bits, self.table = share_min_bits, max_held_bits, table
        self.pending_lam = np.zeros(size, np.float32)
        self.pending_eta = np.zeros(size, np.float32)
        self.touched = np.zeros(size, bool)
        self.judged_lam = np.full(size, np.nan, np.float32)
        self.judged_eta = np.full(size, np.nan, np.float32)
        self.changed = np.zeros(size, bool)
        self.held_bits = np.zeros(size, np.float32)

    def add(self, delta: Delta) -> None:
        idx = delta.idx.astype(np.int64)
        self.pending_lam[idx] += delta.dlam
        self.pending_eta[idx] += delta.deta
        self.touched[idx] = True
        self.changed[idx] = True

    def take(self, lam: np.ndarray, eta: np.ndarray, flush: bool = False) -> Delta | None:
        idx = pending = np.flatnonzero(self.touched)
        if len(idx) == 0:
            return None
        if not flush and self.share_min_bits > 0:
            lam_now, eta_now = lam[idx], eta[idx]
            stale = self.changed[idx] | (lam_now != self.judged_lam[idx]) | (eta_now != self.judged_eta[idx])
            idx, lam_now, eta_now = idx[stale], lam_now[stale], eta_now[stale]
            dlam, deta = self.pending_lam[idx], self.pending_eta[idx]
            lam_team = np.maximum(lam_now - dlam, np.float32(1e-12))
            h_team = self.table((eta_now - deta) / lam_team, 1.0 / np.sqrt(lam_team))
            h_now = self.table(eta_now / lam_now, 1.0 / np.sqrt(lam_now))
            gain = np.abs(h_team - h_now).astype(np.float32)
            useful = gain >= self.share_min_bits
            kept = idx[~useful]
            self.judged_lam[kept], self.judged_eta[kept] = lam_now[~useful], eta_now[~useful]
            self.changed[kept] = False
            self.held_bits[kept] = gain[~useful]
            self.held_bits[idx[useful]] = 0
            idx = np.union1d(idx[useful], self._released(pending))
            if len(idx) == 0:
                return None
        delta = Delta(idx.astype(np.uint32), self.pending_lam[idx].copy(), self.pending_eta[idx].copy())
        self.pending_lam[idx] = self.pending_eta[idx] = 0
        self.touched[idx] = False
        self.held_bits[idx] = 0
        return delta

    def _released(self, pending: np.ndarray) -> np.ndarray:
        if not math.isfinite(self.max_held_bits):
            return np.empty(0, np.int64)
        held = pending[self.held_bits[pending] > 0]
        bits = self.held_bits[held].astype(np.float64)
        if bits.sum() <= self.max_held_bits:
            return np.empty(0, np.int64)
        order = np.argsort(bits)[::-1]
        left = bits.sum() - np.cumsum(bits[order])
        return np.sort(held[order[: int(np.searchsorted(-left, -0.5 * self.max_held_bits)) + 1]])
