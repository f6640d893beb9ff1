"""Pairing the messages of a recording by timestamp, with counts of what was dropped and why."""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import numpy as np


@dataclass
class Matched:
    """Indices into the reference stream and each other stream, one row per kept reference."""

    reference: np.ndarray
    others: dict[str, np.ndarray]
    dropped: Counter = field(default_factory=Counter)

    def describe(self) -> str:
        kept = f"{len(self.reference)} kept"
        if not self.dropped:
            return kept
        return kept + ", dropped: " + ", ".join(f"{n} {why}" for why, n in sorted(self.dropped.items()))


def nearest(stamps: np.ndarray, targets: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each target time, the index of the nearest stamp (sorted stamps) and the gap (same unit)."""
    stamps = np.asarray(stamps, dtype=np.float64)
    targets = np.asarray(targets, dtype=np.float64)
    if stamps.size == 0:
        return np.zeros(targets.size, np.int64), np.full(targets.size, np.inf)
    right = np.clip(np.searchsorted(stamps, targets), 0, stamps.size - 1)
    left = np.clip(right - 1, 0, stamps.size - 1)
    pick = np.where(np.abs(stamps[left] - targets) <= np.abs(stamps[right] - targets), left, right)
    return pick, np.abs(stamps[pick] - targets)


def match_stamps(reference: np.ndarray, others: dict[str, np.ndarray], tolerance: float) -> Matched:
    """Keep each reference time that every other stream has a message within ``tolerance`` of.

    Times are in one unit (e.g. seconds); each stream must be sorted. A reference with no
    partner in stream ``name`` is counted as ``"no <name> within tolerance"``.
    """
    reference = np.asarray(reference, dtype=np.float64)
    keep = np.ones(reference.size, dtype=bool)
    dropped: Counter = Counter()
    picks = {}
    for name, stamps in others.items():
        idx, gap = nearest(stamps, reference)
        miss = keep & (gap > tolerance)
        if miss.any():
            dropped[f"no {name} within {tolerance:g}"] += int(miss.sum())
        keep &= gap <= tolerance
        picks[name] = idx
    rows = np.flatnonzero(keep)
    return Matched(rows, {name: idx[rows] for name, idx in picks.items()}, dropped)
