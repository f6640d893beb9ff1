"""Map-quality and exploration measures of docs/design.md section 7: pure functions over numpy arrays.

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


def overlap_up_to(first_delta: Mapping[str, np.ndarray], n: int) -> float:
    """:func:`overlap_fraction` of what each robot had shared by the team's delta number ``n``.

    ``first_delta`` maps robot id -> per voxel the number (1, 2, ... in the order the deltas
    of all robots were applied) of the first of the robot's deltas that carried it; a voxel
    whose number is above ``n`` (or a "never" marker above every n) was not shared by then.
    """
    return overlap_fraction({robot: np.ravel(first) <= n for robot, first in first_delta.items()})


def first_seen_times(first_delta: np.ndarray, curve_t: np.ndarray, never: int) -> np.ndarray:
    """Sim time of each voxel's first delta, from its delta number and the curve's sample
    times (``curve_t[n]``: the time of delta n); inf where the number is ``never``."""
    first_delta = np.asarray(first_delta)
    seen = first_delta != never
    times = np.full(first_delta.shape, np.inf, np.float32)
    times[seen] = np.asarray(curve_t, np.float64)[first_delta[seen]]
    return times


def first_sample_at_or_below(entropy_curve: Sequence[Sequence[float]], level: float) -> int | None:
    """Index of the first sample (t, H) of the curve with H <= ``level``; None if none is."""
    for i, (_t, h) in enumerate(entropy_curve):
        if h <= level:
            return i
    return None


def halfway_level(entropy_curve: Sequence[Sequence[float]], threshold: float) -> float | None:
    """The entropy halfway from the curve's first sample to ``threshold``; None for no curve."""
    if not entropy_curve:
        return None
    return 0.5 * (float(entropy_curve[0][1]) + threshold)


def overlaps_during_mission(
    first_delta: Mapping[str, np.ndarray], entropy_curve: Sequence[Sequence[float]], threshold: float
) -> dict[str, float | None]:
    """docs/design.md's overlap over what the robots had shared at two moments of the mission.

    ``overlap_halfway``: up to the delta that first brought the team entropy halfway from
    its start to H_th. ``overlap_before_threshold``: up to the delta before the one that
    first brought it to H_th (eq. 36). An agent whose own map, with what it has not shared,
    is below H_th flushes all it holds; that flush is what usually brings the team map to
    H_th, and leaving it out leaves what the agents shared through their utility filter.
    Deltas count in the order the monitor applied them: ``first_delta`` as in
    :func:`overlap_up_to`, delta n being the one after which ``entropy_curve[n]`` was sampled.
    Also the halfway time; each figure None if its moment never came.
    """
    half = halfway_level(entropy_curve, threshold)
    n_half = None if half is None else first_sample_at_or_below(entropy_curve, half)
    n_th = first_sample_at_or_below(entropy_curve, threshold)
    return {
        "halfway_time_s": None if n_half is None else float(entropy_curve[n_half][0]),
        "overlap_halfway": None if n_half is None else overlap_up_to(first_delta, n_half),
        "overlap_before_threshold": None if n_th is None else overlap_up_to(first_delta, n_th - 1),
    }


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
    i = first_sample_at_or_below(entropy_curve, threshold)
    return None if i is None else float(entropy_curve[i][0])


def path_length(trajectory: Sequence[Sequence[float]]) -> float:
    """Length (m) of a trajectory of [t, x, y, ...] samples: the sum of its segment lengths in x-y."""
    pts = np.asarray(trajectory, dtype=np.float64)
    if pts.ndim != 2 or len(pts) < 2:
        return 0.0
    return float(np.sum(np.hypot(np.diff(pts[:, 1]), np.diff(pts[:, 2]))))
