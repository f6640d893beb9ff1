"""A place to stand and a direction to look: what every exploration strategy returns."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True, eq=False)
class ExplorationTarget:
    """A goal for the navigator: stand at ``xy``, face ``gaze_yaw`` (radians, world frame).

    ``xy`` is the centre of a reachable free cell, or of the robot's own cell (turn in place;
    the robot's cell always counts as reachable, even when inflation marks it blocked).

    ``utility`` is the eq. 35 score for ``"entropy"``, the unknown floor area (m^2) within
    viewing range for ``"frontier"`` and ``"random"``, 0 for ``"wander"``, the number of
    unknown voxels of the column for a 3-D frontier view (``"view"`` for the entropy
    strategy, ``"frontier3d"`` for the frontier one); ``voxel`` is the flat index of l_s
    (entropy targets) or of the column's lowest 3-D frontier voxel (views).
    """

    xy: np.ndarray
    gaze_yaw: float
    utility: float
    voxel: int | None
    kind: str
