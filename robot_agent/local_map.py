"""One robot's local map: fuse its own frames (stereo matched first) into its coverage map
(eq. 24-25), and keep the map's per-voxel entropy up to date. The team's deltas reach the same
map and entropy through the agent's :class:`swarm.protocol.team_replica.TeamReplica`.
"""

from __future__ import annotations

import numpy as np

from robot_agent.stereo import points_from_depth
from swarm.map.delta import Delta
from swarm.protocol.wire import Frame


class LocalMapping:
    """The perception half of :class:`robot_agent.explorer.Explorer`: its methods read and
    update the explorer's ``grid``, ``sensor``, ``matcher``, ``table``, ``map``
    (CoverageMap) and ``entropy`` (EntropyCache)."""

    def points(self, frame: Frame) -> np.ndarray:
        """World points of a frame's valid pixels within max range (stereo is matched first)."""
        cam = frame.camera
        if frame.is_depth:
            depth = frame.depth
        else:
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
        idx = delta.idx.astype(np.int64)
        self.entropy.update_information(idx, self.map.lam[idx], self.map.eta[idx])

    @property
    def map_entropy(self) -> float:
        return float(self.entropy.total)
