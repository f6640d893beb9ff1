"""The pose at an image's stamp, from timed pose samples: the one rule of every pose source of a
recording (a bag's pose topic, each ``/tf`` transform on the camera's chain).

At a time ``t``:

1. a sample stamped ``t`` is the pose;
2. else, between two samples at most ``max_gap`` apart (``MAX_GAP_S``, 0.2 s), the pose is
   interpolated at ``t``'s fraction of the way: the position on the straight line, the rotation
   about the one axis turning the first into the second (slerp);
3. else (before the first sample, after the last, or in a longer gap) the nearest sample within
   ``tolerance`` is the pose;
4. else there is none (the image is dropped).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from swarm.streams.matching import nearest
from swarm.streams.poses import interpolate_pose

MAX_GAP_S = 0.2  # samples at most this far apart (s) are interpolated between


@dataclass
class PosesAt:
    """Poses at N asked stamps: ``found`` (N,) bool, ``positions`` (N, 3) m, ``rotations``
    (N, 3, 3) (zero and identity where not found), ``interpolated`` (N,) bool (rule 2)."""

    found: np.ndarray
    positions: np.ndarray
    rotations: np.ndarray
    interpolated: np.ndarray

    @classmethod
    def constant(cls, count: int, position: np.ndarray, rotation: np.ndarray) -> PosesAt:
        """One pose at every stamp (a static transform)."""
        return cls(
            np.ones(count, dtype=bool),
            np.tile(np.asarray(position, dtype=np.float64), (count, 1)),
            np.tile(np.asarray(rotation, dtype=np.float64), (count, 1, 1)),
            np.zeros(count, dtype=bool),
        )

    def rows(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
        """(indices of the stamps found, their positions (K, 3), rotations (K, 3, 3), how many of
        them were interpolated)."""
        rows = np.flatnonzero(self.found)
        return rows, self.positions[rows], self.rotations[rows], int(self.interpolated[rows].sum())


class Trajectory:
    """Timed samples of a pose (any order; sorted here, stably): stamps (N,) s, positions (N, 3) m,
    rotations (N, 3, 3) turning the moving frame's vectors into the reference frame's."""

    def __init__(self, stamps, positions, rotations) -> None:
        stamps = np.asarray(stamps, dtype=np.float64).reshape(-1)
        order = np.argsort(stamps, kind="stable")
        self.stamps = stamps[order]
        self.positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)[order]
        self.rotations = np.asarray(rotations, dtype=np.float64).reshape(-1, 3, 3)[order]

    def at(self, stamps, tolerance: float, max_gap: float = MAX_GAP_S) -> PosesAt:
        """The pose at each of ``stamps`` (s) by the module's rule."""
        t = np.asarray(stamps, dtype=np.float64).reshape(-1)
        out = PosesAt(
            np.zeros(t.size, dtype=bool),
            np.zeros((t.size, 3)),
            np.tile(np.eye(3), (t.size, 1, 1)),
            np.zeros(t.size, dtype=bool),
        )
        n = self.stamps.size
        if n == 0:
            return out
        after = np.searchsorted(self.stamps, t)  # stamps[after - 1] < t <= stamps[after]
        exact = (after < n) & (self.stamps[np.minimum(after, n - 1)] == t)
        inside = (after > 0) & (after < n) & ~exact
        before = np.clip(after - 1, 0, n - 1)
        span = self.stamps[np.minimum(after, n - 1)] - self.stamps[before]
        between = inside & (span <= max_gap)
        pick, gap = nearest(self.stamps, t)
        pick = np.where(exact, np.minimum(after, n - 1), pick)
        held = exact | (~between & (gap <= tolerance))
        out.positions[held] = self.positions[pick[held]]
        out.rotations[held] = self.rotations[pick[held]]
        for row in np.flatnonzero(between):
            j = after[row]
            s = (t[row] - self.stamps[j - 1]) / (self.stamps[j] - self.stamps[j - 1])
            out.positions[row], out.rotations[row] = interpolate_pose(
                s, self.positions[j - 1], self.rotations[j - 1], self.positions[j], self.rotations[j]
            )
        out.found[:] = held | between
        out.interpolated[:] = between
        return out

    def poses_at(
        self, stamps, tolerance: float, max_gap: float = MAX_GAP_S
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
        """(rows of ``stamps`` with a pose, positions (K, 3), rotations (K, 3, 3), how many were
        interpolated): ``PosesAt.rows`` of ``at``."""
        return self.at(stamps, tolerance, max_gap).rows()
