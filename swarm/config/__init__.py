"""Mission configuration: pydantic models loaded from YAML, validated with readable errors.

``load_mission(path)`` reads a mission file; every problem is raised as a ``ConfigError``
whose message names the file, the dotted field path and what is wrong, e.g.
``configs/x.yaml: workspace.voxel: must be > 0 (got -0.1)``.

Paths inside a mission (``floor_plan``, rig files) are relative to the mission file.
Rigs: the top-level ``rig`` is the default; ``rigs`` holds named variants (each a set of
overrides of the default rig); a robot's ``rig`` is a name from ``rigs``, a path to a
rig YAML file (overrides too) or an inline mapping of overrides.
"""

from swarm.config.loading import check_mission, load_mission, mission_from_dict, mission_from_map
from swarm.config.mission import Mission
from swarm.config.models import (
    DEFAULT_THRESHOLD_FRACTION,
    OBSERVABLE_FRACTION,
    PRIOR_BITS_PER_VOXEL,
    ConfigError,
    RigConfig,
)
from swarm.formats.validation_errors import describe_validation_error

__all__ = [
    "DEFAULT_THRESHOLD_FRACTION",
    "OBSERVABLE_FRACTION",
    "PRIOR_BITS_PER_VOXEL",
    "ConfigError",
    "Mission",
    "RigConfig",
    "check_mission",
    "describe_validation_error",
    "load_mission",
    "mission_from_dict",
    "mission_from_map",
]
