"""Which shard of the mission's map service a map server is (docs/sharding.md).

A mission's ``map_service`` (``shards``, ``cuts_x``) cuts its grid into slabs along x
(:mod:`swarm.map.shard_layout`). Server ``k`` of ``N`` is an ordinary map server on slab ``k``
(its grid: ``layout.grid_of(k)``) under the key prefix ``bus.shard_mission(mission, k, N)``
(``<mission>/shard/<k>`` when ``N > 1``; the mission's own name when ``N == 1``, so an
unsharded service is exactly as it always was). Mission-level keys (``robot/<rid>/status``,
``mission/done``) stay under the mission's own name.
"""

from __future__ import annotations

from dataclasses import dataclass

from swarm.config import ConfigError, Mission
from swarm.map.grid import Grid
from swarm.map.shard_layout import ShardLayout
from swarm.protocol import bus


@dataclass(frozen=True)
class ShardRole:
    """Shard ``shard`` of ``layout`` in mission ``mission`` (the mission-level key prefix)."""

    mission: str
    shard: int
    layout: ShardLayout

    @classmethod
    def of(cls, mission: Mission, shard: int | None = 0, mission_name: str | None = None) -> ShardRole:
        """The role of shard ``shard`` of ``mission``'s map service; ``mission_name``: the
        mission-level prefix (default: the config's ``mission``). ``shard`` None is shard 0 of
        an unsharded service. Raises ConfigError naming ``map_service.shards`` when ``shard``
        is missing for a sharded service or out of range (or when the layout does not fit)."""
        layout = mission.shard_layout()
        where = f"{mission.source or '<mission>'}: map_service.shards is {layout.count}"
        if shard is None:
            if layout.count > 1:
                raise ConfigError(
                    f"{where}: give --shard K (0..{layout.count - 1}), the slab this server serves"
                )
            shard = 0
        if not 0 <= int(shard) < layout.count:
            valid = "only 0" if layout.count == 1 else f"0..{layout.count - 1}"
            raise ConfigError(f"{where}: no shard {shard} (shards are {valid})")
        return cls(mission_name or mission.mission, int(shard), layout)

    @property
    def count(self) -> int:
        """N, the number of shards (1: unsharded)."""
        return self.layout.count

    @property
    def sharded(self) -> bool:
        return self.layout.count > 1

    @property
    def grid(self) -> Grid:
        """This shard's grid: its slab (the mission's grid when unsharded)."""
        return self.layout.grid_of(self.shard)

    @property
    def prefix(self) -> str:
        """This shard's key prefix (``delta/<rid>``, ``merged``, ``map/*`` live under it)."""
        return self.prefix_of(self.shard)

    def prefix_of(self, shard: int) -> str:
        """Shard ``shard``'s key prefix."""
        return bus.shard_mission(self.mission, shard, self.count)

    @property
    def decides_end(self) -> bool:
        """Whether this server decides and announces the end of the mission (shard 0 only)."""
        return self.shard == 0

    def stats_fields(self) -> dict:
        """``map/stats``' ``shard`` object of a sharded service (none when unsharded): this
        shard's index, the shard count, the x-index cuts ``bounds`` (N+1 ints) and the
        mission-level prefix, from which a client rebuilds the layout (docs/sharding.md)."""
        if not self.sharded:
            return {}
        g = self.layout.grid
        whole = {"shape": list(g.shape), "origin": list(g.origin), "voxel_size": g.voxel}
        return {
            "shard": {
                "index": self.shard,
                "count": self.count,
                "bounds": list(self.layout.bounds),
                "mission": self.mission,
                "mission_grid": whole,
            }
        }

    def describe(self) -> str:
        """``shard 1 of 2: x from 1.5 to 3 m, key prefix swarm/m/shard/1``."""
        grid = self.grid
        return (
            f"shard {self.shard} of {self.count}: x from {grid.lo[0]:g} to {grid.hi[0]:g} m, "
            f"key prefix {bus.key(self.prefix)}"
        )
