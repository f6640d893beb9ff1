"""Voxel deltas: the information (dlam, deta) a robot gathered, per voxel (docs/design.md section 3).

In information form a Gaussian product is a sum, so deltas from any robots, applied in
any order, give the same map (paper eq. 24-25). A delta is sparse: sorted unique flat
indices with float32 increments.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Delta:
    """Sparse information increments: ``idx`` (uint32, sorted, unique), ``dlam``, ``deta`` (float32)."""

    idx: np.ndarray
    dlam: np.ndarray
    deta: np.ndarray

    def __post_init__(self) -> None:
        if not (len(self.idx) == len(self.dlam) == len(self.deta)):
            raise ValueError(
                f"delta arrays differ in length: idx {len(self.idx)}, dlam {len(self.dlam)}, "
                f"deta {len(self.deta)}"
            )

    def __len__(self) -> int:
        return len(self.idx)

    @classmethod
    def empty(cls) -> Delta:
        return cls(np.zeros(0, dtype=np.uint32), np.zeros(0, dtype=np.float32), np.zeros(0, np.float32))

    @classmethod
    def accumulate(cls, flat: np.ndarray, lam: np.ndarray, eta: np.ndarray, size: int) -> Delta:
        """Sum per-entry information (flat voxel index, lam, eta) into a delta over ``size`` voxels."""
        flat = np.asarray(flat, dtype=np.int64)
        if len(flat) == 0:
            return cls.empty()
        if len(flat) * 4 >= size:
            # Dense accumulation is cheaper when the entries are many compared to the grid.
            lam_sum = np.bincount(flat, weights=lam, minlength=size)
            eta_sum = np.bincount(flat, weights=eta, minlength=size)
            idx = np.flatnonzero(lam_sum)
            return cls(
                idx.astype(np.uint32),
                lam_sum[idx].astype(np.float32),
                eta_sum[idx].astype(np.float32),
            )
        idx, inverse = np.unique(flat, return_inverse=True)
        lam_sum = np.bincount(inverse, weights=lam, minlength=len(idx))
        eta_sum = np.bincount(inverse, weights=eta, minlength=len(idx))
        return cls(idx.astype(np.uint32), lam_sum.astype(np.float32), eta_sum.astype(np.float32))

    def is_finite(self) -> bool:
        return bool(np.all(np.isfinite(self.dlam)) and np.all(np.isfinite(self.deta)))

    def nbytes(self) -> int:
        return self.idx.nbytes + self.dlam.nbytes + self.deta.nbytes


def merge_deltas(deltas: Iterable[Delta], size: int) -> Delta:
    """One delta equal to applying all ``deltas`` (their sum per voxel)."""
    deltas = list(deltas)
    if not deltas:
        return Delta.empty()
    return Delta.accumulate(
        np.concatenate([d.idx for d in deltas]).astype(np.int64),
        np.concatenate([d.dlam for d in deltas]).astype(np.float64),
        np.concatenate([d.deta for d in deltas]).astype(np.float64),
        size,
    )
