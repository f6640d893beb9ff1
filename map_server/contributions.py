"""Who brought what to the team map, so a robot can be quarantined (pure, no I/O).

The team map is ``base + sum over robots of contribution[robot]`` (information form):
``base`` is the prior plus whatever the store held before contributions were kept (a store
written by an older server: its deltas cannot be told apart any more), and each robot's
contribution is the sum of its applied deltas (float32, dense: 8 bytes per voxel per robot,
bounded by the accepted robots). Quarantining a robot rebuilds the map from ``base`` and the
other robots' contributions: its deltas leave the map, whatever order they came in.
"""

from __future__ import annotations

import numpy as np


class Contributions:
    """``base`` (lam, eta) and per-robot (lam, eta) sums of applied deltas, flat float32."""

    def __init__(self, base_lam: np.ndarray, base_eta: np.ndarray) -> None:
        self.base_lam = np.array(base_lam, np.float32)
        self.base_eta = np.array(base_eta, np.float32)
        self.by_robot: dict[str, tuple[np.ndarray, np.ndarray]] = {}

    def add(self, robot: str, idx: np.ndarray, dlam: np.ndarray, deta: np.ndarray) -> None:
        """Add one delta of ``robot`` (unique int64 ``idx``)."""
        if robot not in self.by_robot:
            size = self.base_lam.size
            self.by_robot[robot] = (np.zeros(size, np.float32), np.zeros(size, np.float32))
        lam, eta = self.by_robot[robot]
        lam[idx] += dlam
        eta[idx] += deta

    def drop(self, robot: str) -> bool:
        """Forget a robot's contribution; True when it had one."""
        return self.by_robot.pop(robot, None) is not None

    def total(self) -> tuple[np.ndarray, np.ndarray]:
        """The map they make: base + every kept contribution (summed in float64, then float32)."""
        lam = self.base_lam.astype(np.float64)
        eta = self.base_eta.astype(np.float64)
        for r_lam, r_eta in self.by_robot.values():
            lam += r_lam
            eta += r_eta
        return lam.astype(np.float32), eta.astype(np.float32)

    # -- persistence: arrays of the snapshot ------------------------------------------------
    def to_arrays(self) -> dict[str, np.ndarray]:
        """``base_lam``, ``base_eta`` and ``contrib_lam/<robot>``, ``contrib_eta/<robot>``."""
        out = {"base_lam": self.base_lam, "base_eta": self.base_eta}
        for robot, (lam, eta) in sorted(self.by_robot.items()):
            out[f"contrib_lam/{robot}"] = lam
            out[f"contrib_eta/{robot}"] = eta
        return out

    @classmethod
    def from_arrays(cls, arrays: dict[str, np.ndarray], size: int) -> Contributions | None:
        """Rebuild from :meth:`to_arrays`' output; None when ``base_lam`` is absent (older store)."""
        if "base_lam" not in arrays or "base_eta" not in arrays:
            return None
        out = cls(arrays["base_lam"], arrays["base_eta"])
        for name, lam in arrays.items():
            if name.startswith("contrib_lam/"):
                robot = name.split("/", 1)[1]
                eta = arrays.get(f"contrib_eta/{robot}")
                if eta is None or lam.shape != (size,) or eta.shape != (size,):
                    raise ValueError(f"contribution of {robot!r} is incomplete")
                out.by_robot[robot] = (np.array(lam, np.float32), np.array(eta, np.float32))
        if out.base_lam.shape != (size,) or out.base_eta.shape != (size,):
            raise ValueError("base arrays do not match the grid")
        return out
