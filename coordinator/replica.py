"""The coordinator's replica of the team map: a :class:`TeamReplica` plus who brought what.

The map, its entropy, the applied-delta record, the checks and the catch-up are the shared
:class:`swarm.protocol.team_replica.TeamReplica`; the coordinator adds attribution: per robot,
the x-y cells it brought information to (:class:`coordinator.assignment.ObservedColumns`),
which lower a robot's teammates' ground.
"""

from __future__ import annotations

import numpy as np

from coordinator.assignment import ObservedColumns
from swarm.map.delta import Delta
from swarm.map.grid import Grid
from swarm.map.sensor_model import SensorModel
from swarm.navigation.target_cache import ChangedTiles
from swarm.protocol.team_replica import TeamReplica
from swarm.protocol.wire import DeltaMessage, Snapshot


class CoordinatorReplica(TeamReplica):
    """The coordinator's team map: a ``TeamReplica`` and the ground each robot observed.

    Thread-safe as a ``TeamReplica`` is (``lock``). ``counts`` also holds ``unattributed``:
    deltas applied of a robot beyond the ``max_robots`` tracked.
    """

    def __init__(self, grid: Grid, sensor: SensorModel, max_robots: int | None = None, **replica) -> None:
        """``max_robots``: how many robots' ground is tracked (ObservedColumns), None: all;
        ``replica``: the keyword arguments of ``TeamReplica`` (``fetch``, ``peer_log``, ...)."""
        super().__init__(grid, sensor, name="coordinator", entropy_per_delta=False, **replica)
        self.columns = ObservedColumns(grid.shape, max_robots)
        #: the tiles of columns whose voxels changed, for the coordinator's caches
        self.changes = ChangedTiles(grid.shape)

    def applied_hook(self, msg: DeltaMessage, idx: np.ndarray, size: int) -> None:
        self.changes.mark(idx)
        if not self.columns.add(msg.robot, idx, msg.dlam):
            self.counts["unattributed"] += 1  # applied, but the robot's ground is not tracked

    def add_local(self, delta: Delta) -> None:
        super().add_local(delta)
        self.changes.mark(delta.idx.astype(np.int64))

    def loaded_hook(self, snap: Snapshot) -> None:
        """A snapshot does not say which robot saw what: attribution goes on from later deltas
        (every tile counts as changed)."""
        self.changes.mark_all()

    def teammates_ground(self, robot: str) -> np.ndarray:
        """(nx, ny): x-y cells to which other robots brought more information than ``robot``."""
        with self.lock:
            return self.columns.teammates_ground(robot)
