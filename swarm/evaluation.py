"""Map-quality and exploration measures of DESIGN.md section 7: pure functions over numpy arrays.

Arrays of per-voxel values may be given flat (C order, as ``CoverageMap`` keeps them) or
shaped (nx, ny, nz); every function ravels its inputs, so the two forms mix freely.

Definitions:

- *Observable* voxels (:func:`observable_mask`): inside the workspace, at or above the
  floor, and not strictly inside an obstacle. A voxel is strictly inside when it and its
  six face neighbours are all fully covered (neighbours outside the grid count as covered,
  since sensors stay inside the grid). A ray can end on the face of a fully covered voxel
  only from a neighbour that is not fully covered, so those voxels can never be seen.
- *Occupied*: expected coverage E[C] > 0.5 (map) and true coverage > 0.5 (ground truth).
- *Observed* (known) voxels: voxels with information beyond the prior.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from swarm.map.grid import Grid

#: A voxel whose true coverage reaches this level counts as fully covered.
FULL_COVERAGE = 1.0 - 1e-6


def observable_mask(
    true_coverage: np.ndarray,
    grid: Grid,
    workspace: tuple[Sequence[float], Sequence[float]] | None = None,
    floor_z: float | None = 0.0,
    full: float = FULL_COVERAGE,
) -> np.ndarray:
    """Voxels that can be observed, bool of shape ``grid.shape`` (see the module docstring).

    ``workspace``: the box (lo, hi) of the mission; voxels whose centre lies outside it are
    excluded (``Grid.from_bounds`` rounds the grid up, so it may stick out of the box).
    ``floor_z``: voxels whose centre lies below it are excluded (None keeps them).
    ``full``: coverage at or above which a voxel is fully covered.
    Enclosed free space (a hollow box) is not detected: it counts as observable.
    """
    cov = np.asarray(true_coverage).reshape(grid.shape)
    covered = np.pad(cov >= full, 1, constant_values=True)
    inner = covered[1:-1, 1:-1, 1:-1].copy()
    for axis in range(3):
        for step in (-1, 1):
            inner &= np.roll(covered, step, axis=axis)[1:-1, 1:-1, 1:-1]
    mask = ~inner
    centres = grid.centres()
    if workspace is not None:
        lo, hi = (np.asarray(b, dtype=np.float64) for b in workspace)
        mask &= np.all((centres >= lo) & (centres <= hi), axis=-1)
    if floor_z is not None:
        mask &= centres[..., 2] >= floor_z
    return mask


def occupancy_f1(
    expected_coverage: np.ndarray, true_coverage: np.ndarray, mask: np.ndarray
) -> dict[str, float | int]:
    """Occupancy F1 over ``mask``: predicted E[C] > 0.5 against true coverage > 0.5.

    Returns ``f1, precision, recall, tp, fp, fn, n`` (n = voxels evaluated). F1 is
    2 tp / (2 tp + fp + fn); a ratio with a zero denominator (nothing predicted, nothing
    true, or neither) is 1.0, so a map with no positives on either side scores 1.0.
    """
    sel = np.ravel(mask).astype(bool)
    pred = np.ravel(expected_coverage)[sel] > 0.5
    true = np.ravel(true_coverage)[sel] > 0.5
    tp = int(np.count_nonzero(pred & true))
    fp = int(np.count_nonzero(pred & ~true))
    fn = int(np.count_nonzero(~pred & true))
    return {
        "f1": _ratio(2 * tp, 2 * tp + fp + fn),
        "precision": _ratio(tp, tp + fp),
        "recall": _ratio(tp, tp + fn),
        "tp": tp,
        "fp": fp,
        "fn": fn,
        "n": int(np.count_nonzero(sel)),
    }


def _ratio(num: int, den: int) -> float:
    return num / den if den else 1.0


def coverage_mae(expected_coverage: np.ndarray, true_coverage: np.ndarray, mask: np.ndarray) -> float:
    """Mean |E[C] - true coverage| over ``mask``; NaN when the mask is empty."""
    sel = np.ravel(mask).astype(bool)
    if not sel.any():
        return float("nan")
    err = np.ravel(expected_coverage)[sel].astype(np.float64) - np.ravel(true_coverage)[sel]
    return float(np.mean(np.abs(err)))


def explored_fraction(known_mask: np.ndarray, observable_mask: np.ndarray) -> float:
    """Share of the observable voxels that were observed; 0.0 when none is observable."""
    obs = np.ravel(observable_mask).astype(bool)
    total = int(np.count_nonzero(obs))
    if not total:
        return 0.0
    return int(np.count_nonzero(np.ravel(known_mask).astype(bool) & obs)) / total


def overlap_fraction(observed_by: Mapping[str, np.ndarray]) -> float:
    """Share of the voxels observed by any robot that were observed by two or more.

    ``observed_by`` maps robot id -> bool mask (all the same size); 0.0 when nothing was observed.
    """
    if not observed_by:
        return 0.0
    masks = [np.ravel(m).astype(bool) for m in observed_by.values()]
    count = np.zeros(masks[0].size, dtype=np.int32)
    for m in masks:
        count += m
    seen = int(np.count_nonzero(count))
    return int(np.count_nonzero(count >= 2)) / seen if seen else 0.0


def overlap_by_time(first_seen: Mapping[str, np.ndarray], t: float) -> float:
    """:func:`overlap_fraction` of what each robot had shared by sim time ``t``.

    ``first_seen`` maps robot id -> the sim time of the first of its deltas that carried
    each voxel (inf: none did).
    """
    masks = {}
    for robot, times in first_seen.items():
        times = np.ravel(times)
        masks[robot] = np.isfinite(times) & (times <= t)
    return overlap_fraction(masks)


def halfway_time(entropy_curve: Sequence[Sequence[float]], threshold: float) -> float | None:
    """Time of the first sample (t, H) with H at or below halfway from the first sample's
    entropy to ``threshold``: the mission's halfway mark in information; None if never."""
    if not entropy_curve:
        return None
    return mission_time(entropy_curve, 0.5 * (float(entropy_curve[0][1]) + threshold))


def entropy_split(
    entropy_per_voxel: np.ndarray, observable_mask: np.ndarray, initial_per_voxel: float | np.ndarray
) -> dict[str, float]:
    """Where the final entropy lies: observable voxels or voxels that can never be observed.

    ``initial_per_voxel``: the entropy of each voxel before the mission (a scalar for a
    uniform prior, or an array). Returns, in bits unless a fraction:

    - ``initial_bits``, ``final_bits``: totals over the map;
    - ``final_observable_bits``, ``final_unobservable_bits``;
    - ``unobservable_share``: final_unobservable / final (0 when final is 0);
    - ``decrease``: 1 - final / initial over the whole map;
    - ``decrease_observable``: 1 - final / initial over observable voxels only.
    """
    h = np.ravel(entropy_per_voxel).astype(np.float64)
    obs = np.ravel(observable_mask).astype(bool)
    h0 = np.broadcast_to(np.asarray(initial_per_voxel, dtype=np.float64), h.shape)
    final, final_obs = float(h.sum()), float(h[obs].sum())
    initial, initial_obs = float(h0.sum()), float(h0[obs].sum())
    return {
        "initial_bits": initial,
        "final_bits": final,
        "final_observable_bits": final_obs,
        "final_unobservable_bits": final - final_obs,
        "unobservable_share": (final - final_obs) / final if final > 0 else 0.0,
        "decrease": 1.0 - final / initial if initial > 0 else 0.0,
        "decrease_observable": 1.0 - final_obs / initial_obs if initial_obs > 0 else 0.0,
    }


def mission_time(entropy_curve: Sequence[Sequence[float]], threshold: float) -> float | None:
    """Time t of the first sample (t, H) with H <= ``threshold`` (paper eq. 36); None if never."""
    for t, h in entropy_curve:
        if h <= threshold:
            return float(t)
    return None


def path_length(trajectory: Sequence[Sequence[float]]) -> float:
    """Length (m) of a trajectory of [t, x, y, ...] samples: the sum of its segment lengths in x-y."""
    pts = np.asarray(trajectory, dtype=np.float64)
    if pts.ndim != 2 or len(pts) < 2:
        return 0.0
    return float(np.sum(np.hypot(np.diff(pts[:, 1]), np.diff(pts[:, 2]))))
