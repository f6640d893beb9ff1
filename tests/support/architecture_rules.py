"""Which package may import which (docs/architecture.md), read from the source with ``ast``.

Layers, bottom up: the maths ``swarm.map``; the core (``swarm.navigation``, ``swarm.formats``,
``swarm.protocol``, ``swarm.config``), each allowed the layers named in ``ALLOWED``; the roles
(``robot_agent``, ``map_server``, ``coordinator``, ``sim2d``), which import the core and never
each other; the tooling on top (``swarm.mission``, ``swarm.bench``, ``swarm.cli``), which may
import anything. No module may take part in an import cycle.
"""

from __future__ import annotations

import ast
import sys
from collections import defaultdict
from pathlib import Path

PACKAGES = ("swarm", "robot_agent", "map_server", "coordinator", "sim2d", "replay", "ros2_map")
ROLES = ("robot_agent", "map_server", "coordinator", "sim2d", "replay", "ros2_map")
CORE = (
    "swarm.map",
    "swarm.navigation",
    "swarm.formats",
    "swarm.protocol",
    "swarm.config",
    "swarm.streams",
    "swarm.ros2",
)
TOOLING = ("swarm.mission", "swarm.bench", "swarm.cli")

#: Project groups each group may import (besides itself); tooling may import anything.
ALLOWED: dict[str, set[str]] = {
    "swarm": {"swarm"},  # the top-level swarm/__init__.py (version only)
    "swarm.map": set(),
    "swarm.navigation": {"swarm.map"},
    "swarm.formats": {"swarm.map"},
    "swarm.protocol": {"swarm.map", "swarm.formats"},
    "swarm.config": {"swarm.map", "swarm.formats", "swarm.protocol", "swarm.ros2"},  # ros2: ROS names
    "swarm.streams": {"swarm.map", "swarm.formats", "swarm.protocol"},  # camera streams to frames
    "swarm.ros2": {"swarm.map", "swarm.formats", "swarm.protocol", "swarm.streams"},  # rmw_zenoh's wire
    "swarm.security": {"swarm.protocol"},  # certificates and access rules; used by the tooling
    **{role: {"swarm", *CORE} for role in ROLES},
    "swarm.view": {"swarm", *CORE},  # the live view: a bus client like a role, never a role itself
}
#: Third-party packages the maths may use (docs/design.md: numpy, scipy and numba only).
MATHS_THIRD_PARTY = {"numpy", "scipy", "numba"}


def group_of(module: str, root: Path) -> str:
    """``swarm.map.grid`` -> ``swarm.map``; ``robot_agent.agent`` -> ``robot_agent``."""
    parts = module.split(".")
    if parts[0] == "swarm" and len(parts) > 1 and (root / "swarm" / parts[1]).is_dir():
        return ".".join(parts[:2])
    return parts[0]


def module_imports(root: Path) -> dict[str, set[str]]:
    """Every project module (dotted name) -> the absolute modules it imports (any level)."""
    out: dict[str, set[str]] = {}
    for path in sorted(root.rglob("*.py")):
        rel = path.relative_to(root)
        if rel.parts[0] not in PACKAGES:
            continue
        parts = list(rel.with_suffix("").parts)
        if parts[-1] == "__init__":
            parts.pop()
        module = ".".join(parts)
        found: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"), str(path))):
            if isinstance(node, ast.Import):
                found.update(a.name for a in node.names)
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                found.add(node.module)
                found.update(f"{node.module}.{a.name}" for a in node.names)
        out[module] = found
    return out


def violations(root: Path) -> list[str]:
    """Broken layering rules, one line each (empty when the house is in order)."""
    imports = module_imports(root)
    problems: list[str] = []
    for module, names in sorted(imports.items()):
        group = group_of(module, root)
        for name in sorted(names):
            top = name.split(".")[0]
            if group == "swarm.map" and top not in PACKAGES:
                if top not in MATHS_THIRD_PARTY and top not in sys.stdlib_module_names:
                    problems.append(f"{module} imports {name}: the maths uses numpy, scipy and numba only")
                continue
            if top not in PACKAGES or group in TOOLING:
                continue
            target = group_of(name, root)
            if target == group or target in ALLOWED.get(group, set()):
                continue
            if name not in imports and name.rsplit(".", 1)[0] in imports:
                continue  # `from pkg.module import Name`: judged by the module itself
            problems.append(f"{module} imports {name}: {group} may not import {target}")
    problems.extend(f"import cycle: {' -> '.join(cycle)}" for cycle in cycles(imports))
    return problems


def cycles(imports: dict[str, set[str]]) -> list[list[str]]:
    """Import cycles among project modules (each reported once, from its smallest name)."""
    graph = defaultdict(set)
    for module, names in imports.items():
        for name in names:
            if name in imports and name != module and not module.startswith(name + "."):
                graph[module].add(name)
    found: list[list[str]] = []
    seen: set[tuple[str, ...]] = set()
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(node: str) -> None:
        state[node] = 1
        stack.append(node)
        for nxt in sorted(graph[node]):
            if state.get(nxt) == 1:
                cycle = stack[stack.index(nxt) :]
                start = cycle.index(min(cycle))
                key = tuple(cycle[start:] + cycle[:start])
                if key not in seen:
                    seen.add(key)
                    found.append([*key, key[0]])
            elif nxt not in state:
                visit(nxt)
        stack.pop()
        state[node] = 2

    for module in sorted(imports):
        if module not in state:
            visit(module)
    return found
