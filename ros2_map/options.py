"""The options of the team map's ROS 2 topics (``swarm map ros2``, docs/ros2.md "Team map"),
validated: names as ROS 2 takes them, a height band that is a band, rates that are rates.
"""

from __future__ import annotations

from typing import Literal

from pydantic import Field, FiniteFloat, field_validator

from swarm.config.models import Section
from swarm.ros2.graph import check_namespace, check_node_name, qualified_name
from swarm.ros2.types import DEFAULT_DISTRO, DISTROS

#: The height band (m) judged when no mission says otherwise: above a 0.1 m floor clearance, up
#: to 0.1 m above a camera at 0.4 m (``swarm.navigation.traversability.robot_band_top``).
DEFAULT_BAND = (0.1, 0.5)


class Ros2MapOptions(Section):
    """What ``swarm map ros2`` publishes, where, and how often.

    ROS side: ``domain_id`` (ROS_DOMAIN_ID), ``distro``, the node's ``namespace`` and
    ``node_name``; topics relative to the namespace unless absolute: ``map_topic``
    (OccupancyGrid), ``updates_topic`` (OccupancyGridUpdate; default ``<map_topic>_updates``, the
    name RViz and Nav2 look for), ``cloud_topic`` (PointCloud2); ``frame_id`` of every message.

    The map: ``band`` [z_lo, z_hi] (m) and ``threshold`` (E[C] above it is occupied) of the 2-D
    projection, ``free_rule`` (``swarm.map.projection``); the cloud holds the voxels with E[C]
    above ``threshold``.

    Rates: the grid at most once per ``period_s`` (when it changed), the cloud at most once per
    ``cloud_period_s`` and at most ``cloud_bytes_per_s`` on average (a larger cloud waits
    longer). Grids of more than ``incremental_above`` cells send only the box of changed cells
    (OccupancyGridUpdate) between whole grids, which go out every ``full_period_s`` while the
    latched grid is behind (or when the box is over half the grid).
    """

    domain_id: int = Field(default=0, ge=0, le=232)
    distro: str = DEFAULT_DISTRO
    namespace: str = "/"
    node_name: str = "swarm_team_map"
    map_topic: str = "map"
    updates_topic: str | None = None
    cloud_topic: str = "team_map_cloud"
    frame_id: str = "map"
    band: tuple[FiniteFloat, FiniteFloat] = DEFAULT_BAND
    threshold: FiniteFloat = Field(default=0.5, gt=0, lt=1)
    free_rule: Literal["all", "any"] = "all"
    grid: bool = True
    cloud: bool = True
    period_s: FiniteFloat = Field(default=1.0, gt=0)
    cloud_period_s: FiniteFloat = Field(default=2.0, gt=0)
    cloud_bytes_per_s: FiniteFloat = Field(default=2e6, gt=0)
    full_period_s: FiniteFloat = Field(default=10.0, gt=0)
    incremental_above: int = Field(default=250_000, ge=0)

    @field_validator("distro")
    @classmethod
    def _known_distro(cls, value: str) -> str:
        if value not in DISTROS:
            raise ValueError(f"must be one of {', '.join(DISTROS)} (got {value!r})")
        return value

    @field_validator("namespace")
    @classmethod
    def _namespace(cls, value: str) -> str:
        return check_namespace(value)

    @field_validator("node_name")
    @classmethod
    def _node_name(cls, value: str) -> str:
        return check_node_name(value)

    @field_validator("map_topic", "updates_topic", "cloud_topic")
    @classmethod
    def _topic(cls, value: str | None) -> str | None:
        if value is not None:
            qualified_name(value, "/", "node")  # raises ValueError naming the bad token
        return value

    @field_validator("frame_id")
    @classmethod
    def _frame(cls, value: str) -> str:
        if not value or value != value.strip() or value.startswith("/") or any(c.isspace() for c in value):
            raise ValueError(f"a tf2 frame id: not empty, no spaces, no leading '/' (got {value!r})")
        return value

    @field_validator("band")
    @classmethod
    def _band(cls, value: tuple[float, float]) -> tuple[float, float]:
        if not value[1] > value[0]:
            raise ValueError(f"the top {value[1]:g} m must be above the bottom {value[0]:g} m")
        return value

    @property
    def updates(self) -> str:
        """The OccupancyGridUpdate topic: ``updates_topic``, else ``<map_topic>_updates``."""
        return self.updates_topic or f"{self.map_topic}_updates"
