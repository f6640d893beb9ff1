"""The transform tree of ``/tf`` and ``/tf_static``: a camera's pose as a chain of transforms.

Numbers in, numbers out (reading the bag is ``replay.bag``'s job). A transform is tf's: its
``header.frame_id`` is the parent, its ``child_frame_id`` the child, and it maps child
coordinates into the parent's, ``X_parent = R X_child + t``. The pose of a frame in the world
is then the product along the path from the world down to it:
``world_T_camera = world_T_a @ a_T_b @ ... @ y_T_camera``, whose rotation turns camera vectors
into world vectors and whose translation is the camera's position in the world (ROS's meaning
of a pose, as a direct transform has it).

Static edges (``/tf_static``) hold at every time, with their latest value; dynamic edges
(``/tf``) are interpolated at the asked time between their two samples around it (straight line,
slerp) when these are at most ``gap`` apart, or else take a sample within ``tolerance``.
Frame ids are compared without a leading '/' (ROS 1's ``/base_link`` is ``base_link``).
"""

from __future__ import annotations

from array import array
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from replay.poses import interpolate_pose, quaternion_matrix


class TfError(ValueError):
    """A transform tree that does not give the camera's pose: one line naming the frame."""


def frame_name(frame: str) -> str:
    """The frame id as compared: ``/base_link`` and ``base_link`` are one frame."""
    return frame.lstrip("/")


@dataclass
class Edge:
    """The transforms ``parent -> child`` of one kind (static or dynamic), in the order added.

    Kept as their numbers (8 a transform: stamp, translation, quaternion w x y z), which a
    robot's dozens of joint frames at 50 Hz need, and turned into rotations when first asked
    (once every transform is added).
    """

    parent: str
    child: str
    static: bool
    numbers: array = field(default_factory=lambda: array("d"), repr=False)

    @cached_property
    def _usable(self) -> tuple[list[float], list[np.ndarray], list[np.ndarray], int]:
        rows = np.array(self.numbers, dtype=np.float64).reshape(-1, 8)
        ok = np.all(np.isfinite(rows), axis=1) & (np.linalg.norm(rows[:, 4:], axis=1) > 1e-9)
        kept = rows[ok]
        rotations = [quaternion_matrix(*row[4:]) for row in kept]
        return kept[:, 0].tolist(), [row[1:4].copy() for row in kept], rotations, int((~ok).sum())

    def samples(self) -> tuple[list[float], list[np.ndarray], list[np.ndarray]]:
        """(stamps, translations, rotations) in the order added, without the unusable ones."""
        return self._usable[:3]

    @property
    def unusable(self) -> int:
        """Transforms whose numbers are not one (NaN, a zero quaternion), left out."""
        return self._usable[3]

    @cached_property
    def _sorted(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        stamps, positions, rotations = (np.asarray(v) for v in self.samples())
        order = np.argsort(stamps, kind="stable")
        return stamps[order], positions[order], rotations[order]

    def at(self, t: float, tolerance: float, gap: float) -> tuple[np.ndarray, np.ndarray, bool] | None:
        """(translation, rotation, interpolated) of this edge at time ``t``, or None if it has none."""
        if self.static:  # its latest value
            _, positions, rotations = self.samples()
            return positions[-1], rotations[-1], False
        stamps, positions, rotations = self._sorted
        j = int(np.searchsorted(stamps, t))  # stamps[j - 1] < t <= stamps[j]
        if j < stamps.size and stamps[j] == t:
            return positions[j], rotations[j], False
        if 0 < j < stamps.size and stamps[j] - stamps[j - 1] <= gap:
            s = (t - stamps[j - 1]) / (stamps[j] - stamps[j - 1])
            p, r = interpolate_pose(s, positions[j - 1], rotations[j - 1], positions[j], rotations[j])
            return p, r, True
        near = [k for k in (j - 1, j) if 0 <= k < stamps.size and abs(stamps[k] - t) <= tolerance]
        if not near:
            return None
        k = min(near, key=lambda k: abs(stamps[k] - t))
        return positions[k], rotations[k], False

    def __str__(self) -> str:
        return f"{self.parent} -> {self.child}"


@dataclass
class Chain:
    """The edges from ``world`` down to ``child``, world first."""

    world: str
    child: str
    edges: list[Edge]

    @property
    def direct(self) -> bool:
        """One dynamic transform world -> child: the pose topic's samples are the poses as they are."""
        return len(self.edges) == 1 and not self.edges[0].static

    @property
    def unusable(self) -> int:
        return sum(e.unusable for e in self.edges)

    def stamps(self) -> np.ndarray:
        """Every stamp of the chain's dynamic transforms, or of its static ones if all are (sorted)."""
        dynamic = [e for e in self.edges if not e.static]
        stamps = [t for e in dynamic or self.edges for t in e.samples()[0]]
        return np.sort(np.asarray(stamps, dtype=np.float64))

    def describe(self) -> str:
        kinds = " ".join(f"{'=' if e.static else '-'}> {e.child}" for e in self.edges)
        return f"{self.world} {kinds}"

    def poses_at(
        self, stamps: np.ndarray, tolerance: float, gap: float
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, int]:
        """The child's pose in the world at each stamp the chain has a value at: (rows of ``stamps``,
        positions (N, 3), world_R_child (N, 3, 3), how many needed an interpolated transform)."""
        rows, positions, rotations = [], [], []
        interpolated = 0
        for row, t in enumerate(np.asarray(stamps, dtype=np.float64)):
            p, r, turned = np.zeros(3), np.eye(3), False
            for edge in self.edges:  # world_T_child = world_T_a @ a_T_b @ ...
                value = edge.at(float(t), tolerance, gap)
                if value is None:
                    break
                p, r = p + r @ value[0], r @ value[1]
                turned |= value[2]
            else:
                rows.append(row)
                positions.append(p)
                rotations.append(r)
                interpolated += turned
        return (
            np.asarray(rows, dtype=np.int64),
            np.asarray(positions, dtype=np.float64).reshape(-1, 3),
            np.asarray(rotations, dtype=np.float64).reshape(-1, 3, 3),
            interpolated,
        )


class TfTree:
    """The transforms of a recording by (parent, child, static); ``chain()`` finds a frame's path."""

    def __init__(self) -> None:
        self._edges: dict[tuple[str, str, bool], Edge] = {}

    def _edge(self, parent: str, child: str, static: bool) -> Edge:
        key = (frame_name(parent), frame_name(child), static)
        if key not in self._edges:
            self._edges[key] = Edge(*key)
        return self._edges[key]

    def add(self, parent: str, child: str, stamp: float, xyz, wxyz, static: bool) -> None:
        """A transform parent -> child at ``stamp``: X_parent = R X_child + ``xyz``, with R the
        rotation of the quaternion ``wxyz`` (w, x, y, z); one of NaN or a zero quaternion is counted
        as unusable and left out."""
        self._edge(parent, child, static).numbers.extend((stamp, *xyz, *wxyz))

    @property
    def frames(self) -> list[str]:
        return sorted({f for parent, child, _ in self._edges for f in (parent, child)})

    def _parent_edges(self, frame: str) -> list[Edge]:
        return [e for (_, child, _), e in self._edges.items() if child == frame]

    def chain(self, child: str, world: str | None = None) -> Chain:
        """The path from ``world`` (default: the root above ``child``) down to ``child``.

        Raises ``TfError`` for a frame not in the tree, a world that is not one of the child's
        ancestors, a frame with two parents on the way, a cycle, or a dynamic transform on the way
        with no usable sample.
        """
        child = frame_name(child)
        world = None if world is None else frame_name(world)
        if child not in self.frames:
            raise TfError(f"frame {child!r} is not in the transform tree (frames: {', '.join(self.frames)})")
        path, edges = [child], []
        frame = child
        while frame != world:
            above = self._parent_edges(frame)
            parents = sorted({e.parent for e in above})
            if not parents:
                if world is None:
                    break
                ancestors = ", ".join(path[1:]) or "none, it is a root"
                raise TfError(f"frame {world!r} is not an ancestor of {child!r} (its ancestors: {ancestors})")
            if len(parents) > 1:
                raise TfError(
                    f"frame {frame!r} has two parents, {parents[0]!r} and {parents[1]!r} (tf allows one)"
                )
            if len(above) > 1:
                raise TfError(f"transform {above[0]} is on both /tf and /tf_static (tf allows one)")
            edge = above[0]
            if edge.parent in path:
                cycle = " -> ".join([edge.parent, *reversed(path[path.index(edge.parent) :])])
                raise TfError(f"the transforms make a cycle: {cycle}")
            if not edge.samples()[0]:
                raise TfError(f"every transform {edge} is unusable (NaN, or a zero quaternion)")
            path.append(edge.parent)
            edges.append(edge)
            frame = edge.parent
        if not edges:
            what = "is the world frame asked" if world == child else "has no parent: it is a root"
            raise TfError(f"frame {child!r} {what}, not a camera under it")
        return Chain(path[-1], child, edges[::-1])
