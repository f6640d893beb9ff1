"""What the team map's topics send and when: the 2-D grid (whole, or the box of changed cells)
and the occupied cloud, each rate-limited. No Zenoh here: ``take`` returns the ROS 2 message
to publish now, or None, and counts it as sent.

The grid. Subscribers hold the last whole grid (latched: a late joiner gets it) with the
updates sent after it applied. A grid of at most ``incremental_above`` cells goes out whole
whenever it changed, at most once per ``period_s``. A larger one sends the box of cells that
changed since the last message (``map_msgs/OccupancyGridUpdate``) instead, and goes out whole
when that box is over half the grid, or once ``full_period_s`` passed since the last whole grid
while the latched one is behind: a late joiner's grid is at most that old.

The cloud goes out whole whenever some voxel changed, at most once per ``cloud_period_s``, and
after a cloud of B bytes not before B / ``cloud_bytes_per_s`` seconds.
"""

from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from ros2_map.options import Ros2MapOptions
from ros2_map.replica import FollowedMap
from swarm.map.projection import (
    band_layers,
    changed_box,
    columns_of,
    occupied_cloud,
    project,
    project_columns,
)
from swarm.ros2.map_messages import occupancy_grid, occupancy_grid_update, point_cloud
from swarm.ros2.types import Ros2Types


class GridOutput:
    """The 2-D projection of ``fmap`` over the options' band, and what subscribers hold of it.

    Raises ValueError when no map layer lies in the band.
    """

    def __init__(self, fmap: FollowedMap, options: Ros2MapOptions, types: Ros2Types) -> None:
        self.fmap, self.options, self.types = fmap, options, types
        grid = fmap.grid
        self.layers = band_layers(grid, *options.band)
        self.origin = (grid.lo[0], grid.lo[1], grid.lo[2] + self.layers[0] * grid.voxel)
        self.cells = project(grid, fmap.coverage, fmap.map.lam, fmap.known_lam, self.layers,
                             options.threshold, options.free_rule)  # fmt: skip
        self.held: np.ndarray | None = None  # what a subscriber of every message holds
        self.changed = True  # cells projected again since the last message
        self.latched_behind = False  # the latched whole grid misses updates sent after it
        self.last_full = -math.inf
        self.next_due = -math.inf

    @property
    def incremental(self) -> bool:
        return self.cells.size > self.options.incremental_above

    def note(self, voxels: np.ndarray) -> None:
        """Project again the columns holding ``voxels`` (refreshed in ``fmap``)."""
        if voxels.size == 0:
            return
        fmap, options = self.fmap, self.options
        columns = columns_of(fmap.grid, voxels)
        values = project_columns(fmap.grid, fmap.coverage, fmap.map.lam, fmap.known_lam, self.layers,
                                 columns, options.threshold, options.free_rule)  # fmt: skip
        self.cells.reshape(-1)[columns] = values
        self.changed = True

    def take(self, now: float, stamp: float) -> tuple[str, Any] | None:
        """("full", OccupancyGrid) or ("update", OccupancyGridUpdate) to send at monotonic time
        ``now`` (stamped ``stamp``, UNIX s), or None when nothing is due."""
        full_due = now - self.last_full >= self.options.full_period_s
        if now < self.next_due or not (self.changed or (self.latched_behind and full_due)):
            return None
        self.changed = False
        box = None if self.held is None else changed_box(self.held, self.cells)
        if self.held is not None and box is None and not (self.latched_behind and full_due):
            return None
        if self.held is None or not self.incremental or full_due or _area(box) * 2 > self.cells.size:
            kind, message = "full", self._full(stamp)
            self.last_full, self.latched_behind = now, False
        else:
            kind = "update"
            message = occupancy_grid_update(self.types, self.cells, box, self.options.frame_id, stamp)
            self.latched_behind = True
        self.held = self.cells.copy()
        self.next_due = now + self.options.period_s
        return kind, message

    def _full(self, stamp: float) -> Any:
        voxel = self.fmap.grid.voxel
        return occupancy_grid(self.types, self.cells, self.origin, voxel, self.options.frame_id, stamp)


def _area(box: tuple[slice, slice] | None) -> int:
    if box is None:
        return 0
    return (box[0].stop - box[0].start) * (box[1].stop - box[1].start)


class CloudOutput:
    """The occupied voxels of ``fmap`` as one PointCloud2, rate-limited (module doc)."""

    def __init__(self, fmap: FollowedMap, options: Ros2MapOptions, types: Ros2Types) -> None:
        self.fmap, self.options, self.types = fmap, options, types
        self.changed = True
        self.next_due = -math.inf
        self.points = 0  # in the last cloud

    def note(self, voxels: np.ndarray) -> None:
        if voxels.size:
            self.changed = True

    def take(self, now: float, stamp: float) -> Any | None:
        """The PointCloud2 to send at monotonic ``now`` (stamped ``stamp``), or None."""
        if not self.changed or now < self.next_due:
            return None
        fmap, options = self.fmap, self.options
        points = occupied_cloud(fmap.grid, fmap.coverage, fmap.map.lam, fmap.map.eta,
                                fmap.entropy.values, options.threshold)  # fmt: skip
        self.changed = False
        self.points = int(points.size)
        self.next_due = now + max(options.cloud_period_s, points.nbytes / options.cloud_bytes_per_s)
        return point_cloud(self.types, points, options.frame_id, stamp)


class MapOutputs:
    """The grid and the cloud of one followed map (either None when the options turn it off)."""

    def __init__(self, fmap: FollowedMap, options: Ros2MapOptions, types: Ros2Types) -> None:
        self.fmap = fmap
        self.grid = GridOutput(fmap, options, types) if options.grid else None
        self.cloud = CloudOutput(fmap, options, types) if options.cloud else None

    def carry_rates(self, before: MapOutputs) -> None:
        """Keep ``before``'s next times (the rate limits hold across a new snapshot)."""
        for new, old in ((self.grid, before.grid), (self.cloud, before.cloud)):
            if new is not None and old is not None:
                new.next_due = old.next_due

    def due(self, now: float, stamp: float) -> list[tuple[str, Any, float]]:
        """What to send at monotonic ``now``, stamped ``stamp``: (kind, message, seconds spent
        building it), kind "full" (OccupancyGrid), "update" (OccupancyGridUpdate) or "cloud";
        the replica's changed voxels are refreshed first when a message may be due."""
        outs = [out for out in (self.grid, self.cloud) if out is not None]
        if self.fmap.pending and any(now >= out.next_due for out in outs):
            voxels = self.fmap.refresh()
            for out in outs:
                out.note(voxels)
        sent = []
        if self.grid is not None:
            started = time.perf_counter()
            taken = self.grid.take(now, stamp)
            if taken is not None:
                sent.append((*taken, time.perf_counter() - started))
        if self.cloud is not None:
            started = time.perf_counter()
            message = self.cloud.take(now, stamp)
            if message is not None:
                sent.append(("cloud", message, time.perf_counter() - started))
        return sent

    def idle(self) -> bool:
        """Whether every change refreshed so far has gone out."""
        return not self.fmap.pending and not any(
            out is not None and out.changed for out in (self.grid, self.cloud)
        )
