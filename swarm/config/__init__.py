"""Mission configuration: pydantic models loaded from YAML, validated with readable errors.

``load_mission(path)`` reads a mission file; every problem is raised as a ``ConfigError``
whose message names the file, the dotted field path and what is wrong, e.g.
``configs/x.yaml: workspace.voxel: must be > 0 (got -0.1)``.

Paths inside a mission (``floor_plan``, rig files) are relative to the mission file.
Rigs: the top-level ``rig`` is the default; ``rigs`` holds named variants (each a set of
overrides of the default rig); a robot's ``rig`` is a name from ``rigs``, a path to a
rig YAML file (overrides too) or an inline mapping of overrides.
A robot's ``start`` is where the simulator places it: optional in the file, required by the
simulator alone (``Mission.start_poses``: a ConfigError naming ``robots[i].start``); the other
roles take a robot's pose from its frames.
"""

from importlib import import_module

#: Each name this package offers -> the module of the package that defines it, imported when
#: first asked for (a command line's --help needs a default or two, not pydantic and the maths).
_HOMES = {
    **dict.fromkeys(("check_mission", "load_mission", "mission_from_dict", "mission_from_map"), "loading"),
    "Mission": "mission",
    **dict.fromkeys(("DEFAULT_THRESHOLD_FRACTION", "OBSERVABLE_FRACTION", "PRIOR_BITS_PER_VOXEL"), "models"),
    **dict.fromkeys(("ConfigError", "RigConfig"), "models"),
}


def __getattr__(name: str):
    if name == "describe_validation_error":
        from swarm.formats.validation_errors import describe_validation_error

        return describe_validation_error
    if name not in _HOMES:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    return getattr(import_module(f"{__name__}.{_HOMES[name]}"), name)


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
