"""The transform tree of ``/tf`` and ``/tf_static``: a camera's pose as a chain of transforms.

Numbers in, numbers out (reading the bag is ``replay.bag``'s job). A transform is tf's: its
``header.frame_id`` is the parent, its ``child_frame_id`` the child, and it maps child
coordinates into the parent's, ``X_parent = R X_child + t``. The pose of a frame in the world
is then the product along the path from the world down to it:
``world_T_camera = world_T_a @ a_T_b @ ... @ y_T_camera``, whose rotation turns camera vectors
into world vectors and whose translation is the camera's position in the world (ROS's meaning
of a pose, as a direct transform has it).

Static edges (``/tf_static``) hold at every time, with their latest value; dynamic edges
(``/tf``) take their value at the asked time by the rule of ``replay.trajectory`` (the one a
pose topic's messages follow): interpolated between the two samples around it when these are at
most ``gap`` apart, or else a sample within ``tolerance``.
Frame ids are compared without a leading '/' (ROS 1's ``/base_link`` is ``base_link``).
"""

from __future__ import annotations

from array import array
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from swarm.streams.poses import quaternion_matrix
from swarm.streams.trajectory import PosesAt, Trajectory


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
    def _trajectory(self) -> Trajectory:
        return Trajectory(*self.samples())

    def at(self, stamps: np.ndarray, tolerance: float, gap: float) -> PosesAt:
        """This edge's transform at each of ``stamps`` (s): a static edge's latest value, a dynamic
        edge's by the rule of ``replay.trajectory`` (interpolated, or a sample within ``tolerance``)."""
        if self.static:
            _, positions, rotations = self.samples()
            return PosesAt.constant(np.size(stamps), positions[-1], rotations[-1])
        return self._trajectory.at(stamps, tolerance, gap)

    def __str__(self) -> str:
        return f"{self.parent} -> {self.child}"


@dataclass
class Chain:
    """The edges from ``world`` down to ``child``, world first."""

    world: str
    child: str
    edges: list[Edge]

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
        stamps = np.asarray(stamps, dtype=np.float64).reshape(-1)
        world = PosesAt.constant(stamps.size, np.zeros(3), np.eye(3))
        for edge in self.edges:  # world_T_child = world_T_a @ a_T_b @ ...
            step = edge.at(stamps, tolerance, gap)
            world.positions = world.positions + np.einsum("nij,nj->ni", world.rotations, step.positions)
            world.rotations = world.rotations @ step.rotations
            world.found &= step.found
            world.interpolated |= step.interpolated
        return world.rows()


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
