"""One robot's local map: fuse its own frames (stereo matched first) into its coverage map
(eq. 24-25), and keep the map's per-voxel entropy up to date. The team's deltas reach the same
map and entropy through the agent's :class:`swarm.protocol.team_replica.TeamReplica`, which
updates both in place.
"""

from __future__ import annotations

import numpy as np

from robot_agent.stereo import StereoMatcher, points_from_depth
from swarm.map.coverage_map import CoverageMap
from swarm.map.delta import Delta
from swarm.map.entropy_cache import EntropyCache
from swarm.map.entropy_table import EntropyTable
from swarm.map.grid import Grid
from swarm.map.sensor_model import SensorModel
from swarm.navigation.target_cache import ChangedTiles, TargetCache
from swarm.protocol.wire import Frame


class LocalMap:
    """A robot's coverage map (``map``) on the mission's ``grid`` and its per-voxel entropy
    (``entropy``, an EntropyCache on ``table``); ``matcher`` turns stereo pairs into depth
    (None for a range camera). ``targets`` keeps the slab's eq. 32-35 fields per tile, redone
    where ``changes`` says the map changed."""

    def __init__(
        self, grid: Grid, sensor: SensorModel, table: EntropyTable, matcher: StereoMatcher | None
    ) -> None:
        self.grid = grid
        self.sensor = sensor
        self.table = table
        self.matcher = matcher
        self.map = CoverageMap(grid, sensor)
        #: the tiles of columns whose voxels changed (own frames, the team's deltas, a snapshot:
        #: every change goes through the entropy cache), and the eq. 35 fields kept per tile
        self.changes = ChangedTiles(grid.shape)
        self.targets = TargetCache(grid, self.changes)
        self.entropy = EntropyCache.from_information(
            self.map.lam, self.map.eta, table=table, on_change=self.changes.note
        )

    def points(self, frame: Frame) -> np.ndarray:
        """World points of a frame's valid pixels within max range (stereo is matched first)."""
        cam = frame.camera
        if frame.is_depth:
            depth = frame.depth
        else:
            if self.matcher is None:
                raise ValueError("a stereo frame for a robot whose rig is a range camera")
            depth = self.matcher.depth(frame.left, frame.right, cam)
        return points_from_depth(
            depth, cam.fx, cam.fy, cam.cx, cam.cy, frame.pose.xyz, frame.pose.ypr, self.sensor.max_range
        )

    def fuse(self, frame: Frame) -> Delta:
        """Fuse a frame's batch into the local map (eq. 24-25); returns the information it added."""
        result = self.map.integrate(np.asarray(frame.pose.xyz), self.points(frame))
        self.apply_entropy(result.delta)
        return result.delta

    def apply_entropy(self, delta: Delta) -> None:
        """Bring the entropy of the voxels ``delta`` touched up to date with the map."""
        idx = delta.idx.astype(np.int64)
        self.entropy.update_information(idx, self.map.lam[idx], self.map.eta[idx])

    def recompute_entropy(self) -> None:
        """The entropy of every voxel from the map again, in place (after the map's arrays were
        set whole; the team replica holds the same cache)."""
        self.entropy.refill_information(self.map.lam, self.map.eta)

    @property
    def entropy_bits(self) -> float:
        """The map's entropy H (bits, eq. 36's left side)."""
        return float(self.entropy.total)
