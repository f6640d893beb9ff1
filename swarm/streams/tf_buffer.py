"""A live transform buffer: the ``/tf`` and ``/tf_static`` messages of a running robot, and the
camera's pose in a fixed frame at an image's stamp (what tf2's ``Buffer.lookupTransform`` gives).

Transforms arrive one by one, in any order. Each child frame has one parent (tf's rule; the
newest transform names it); a static transform keeps only its latest value, a dynamic one the
samples of the last ``cache_s`` seconds (tf2 keeps 10 s). A lookup walks from the camera up to the
fixed frame and takes each transform on the way at the stamp by the rule of
``swarm.streams.trajectory`` (interpolated between the two samples around the stamp, or the
nearest within a tolerance), composing them as ``swarm.streams.tf_tree.Chain`` does: the same
numbers as ``swarm replay bag`` gives for the same messages.

Why a lookup fails is in ``TfLookupError.reason``:

* ``not_yet``: the stamp is after the newest sample of a transform on the way (it may come:
  tf2's ``MessageFilter`` waits for it);
* ``too_old``: before the oldest sample kept;
* ``gap``: between two samples farther apart than ``gap`` with none near;
* ``no_path``: the camera or the fixed frame is unknown, or not connected;
* ``loop``: the parents make a cycle.

Pure numbers in and out; no messages, clocks or threads here (the caller serialises access).
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass, field

import numpy as np

from swarm.streams.poses import quaternion_matrix
from swarm.streams.tf_tree import TfError, frame_name
from swarm.streams.trajectory import MAX_GAP_S, PosesAt, Trajectory

CACHE_S = 10.0  # seconds of dynamic samples kept per transform, as tf2's buffer
MAX_FRAMES = 4096  # child frames kept at most (a robot has dozens); more are refused
MAX_SAMPLES = 20_000  # samples per transform at most (10 s at 2 kHz)

NOT_YET, TOO_OLD, GAP, NO_PATH, LOOP = "not_yet", "too_old", "gap", "no_path", "loop"


class TfLookupError(TfError):
    """A lookup that gives no pose; ``reason`` is one of the module's reasons."""

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(message)
        self.reason = reason


@dataclass
class _Link:
    """The transforms of one child frame: its parent, and its samples sorted by stamp, each kept
    as (position (3,), rotation (3, 3)), the rotation made once from its quaternion."""

    parent: str
    static: bool
    stamps: list[float] = field(default_factory=list)
    poses: list[tuple[np.ndarray, np.ndarray]] = field(default_factory=list)

    def add(self, row: tuple[float, ...], cache_s: float) -> None:
        pose = (np.array(row[1:4], dtype=np.float64), quaternion_matrix(*row[4:]))
        if self.static:
            self.stamps, self.poses = [row[0]], [pose]
            return
        at = bisect.bisect_right(self.stamps, row[0])
        self.stamps.insert(at, row[0])
        self.poses.insert(at, pose)
        drop = bisect.bisect_left(self.stamps, self.stamps[-1] - cache_s)
        drop = max(drop, len(self.stamps) - MAX_SAMPLES)
        if drop > 0:
            del self.stamps[:drop], self.poses[:drop]

    def at(self, stamp: float, tolerance: float, gap: float) -> PosesAt:
        """This transform at ``stamp``, by ``swarm.streams.trajectory``'s rule (as ``tf_tree.Edge.at``)."""
        if self.static:
            return PosesAt.constant(1, *self.poses[-1])
        after = bisect.bisect_left(self.stamps, stamp)
        if after < len(self.stamps) and self.stamps[after] == stamp:  # a sample at the stamp itself
            return PosesAt.constant(1, *self.poses[after])
        near = slice(max(after - 1, 0), after + 1)  # the two around it, or the one at an end
        positions, rotations = zip(*self.poses[near], strict=True)
        return Trajectory(self.stamps[near], positions, rotations).at(np.array([stamp]), tolerance, gap)


class TfBuffer:
    """Transforms by child frame; ``add`` them as they come, ``lookup`` a pose at a stamp."""

    def __init__(self, cache_s: float = CACHE_S, max_frames: int = MAX_FRAMES, gap: float = MAX_GAP_S):
        self.cache_s = float(cache_s)
        self.max_frames = int(max_frames)
        self.gap = float(gap)
        self._links: dict[str, _Link] = {}

    @property
    def frames(self) -> list[str]:
        return sorted({f for child, link in self._links.items() for f in (child, link.parent)})

    def add(self, parent: str, child: str, stamp: float, xyz, wxyz, static: bool) -> str | None:
        """Take one transform (X_parent = R(wxyz) X_child + xyz, at ``stamp`` s). Returns None, or
        why it was refused: ``unusable`` (NaN, inf, a zero quaternion), ``self`` (a frame its own
        parent), ``frames`` (beyond ``max_frames``)."""
        parent, child = frame_name(str(parent)), frame_name(str(child))
        row = (float(stamp), *(float(v) for v in xyz), *(float(v) for v in wxyz))
        if len(row) != 8 or not all(math.isfinite(v) for v in row) or math.hypot(*row[4:]) <= 1e-9:
            return "unusable"
        if parent == child or not parent or not child:
            return "self"
        link = self._links.get(child)
        if link is None or link.parent != parent or link.static != bool(static):
            if link is None and len(self._links) >= self.max_frames:
                return "frames"
            link = self._links[child] = _Link(parent, bool(static))  # tf: the newest names the parent
        link.add(row, self.cache_s)
        return None

    def lookup(
        self, world: str, child: str, stamp: float, tolerance: float, wait: bool = False
    ) -> tuple[np.ndarray, np.ndarray]:
        """``child``'s position (3,) m and rotation world_R_child (3, 3) in ``world`` at ``stamp``.

        ``wait``: a stamp after the newest sample of a dynamic transform on the way is ``not_yet``
        even when that sample is within ``tolerance`` (a later one may come to interpolate with,
        as a recording would have it). Raises ``TfLookupError`` (its ``reason`` says why)."""
        world, child = frame_name(world), frame_name(child)
        path = [child]
        links: list[tuple[str, _Link]] = []
        frame = child
        while frame != world:
            link = self._links.get(frame)
            if link is None:
                known = child in self._links or any(x.parent == child for x in self._links.values())
                what = f"frame {world!r} is not above {child!r}" if known else f"no transform to {child!r}"
                raise TfLookupError(NO_PATH, f"{what} (frames: {', '.join(self.frames) or 'none yet'})")
            if link.parent in path:
                cycle = " -> ".join([link.parent, *reversed(path[path.index(link.parent) :])])
                raise TfLookupError(LOOP, f"the transforms make a cycle: {cycle}")
            links.append((frame, link))
            path.append(link.parent)
            frame = link.parent
        if not links:
            raise TfLookupError(NO_PATH, f"frame {child!r} is the fixed frame itself, not a camera under it")
        if wait:
            for name, link in links:
                if not link.static and link.stamps[-1] < stamp:
                    late = stamp - link.stamps[-1]
                    raise TfLookupError(
                        NOT_YET, f"{link.parent} -> {name}: newest transform {late:.3f} s before the stamp"
                    )
        pose = PosesAt.constant(1, np.zeros(3), np.eye(3))
        for _, link in reversed(links):  # world_T_child = world_T_a @ a_T_b @ ..., as Chain.poses_at
            step = link.at(stamp, tolerance, self.gap)
            if not step.found[0]:
                raise self._why_not(links, stamp, tolerance)
            pose.positions = pose.positions + np.einsum("nij,nj->ni", pose.rotations, step.positions)
            pose.rotations = pose.rotations @ step.rotations
        return pose.positions[0], pose.rotations[0]

    def _why_not(self, links: list[tuple[str, _Link]], stamp: float, tolerance: float) -> TfLookupError:
        for name, link in links:
            if link.static:
                continue
            newest, oldest = link.stamps[-1], link.stamps[0]
            where = f"{link.parent} -> {name}"
            if stamp > newest + tolerance:
                return TfLookupError(
                    NOT_YET, f"{where}: newest transform {stamp - newest:.3f} s before the stamp"
                )
            if stamp < oldest - tolerance:
                return TfLookupError(
                    TOO_OLD, f"{where}: the stamp is {oldest - stamp:.3f} s before the oldest kept"
                )
        return TfLookupError(
            GAP, f"no transform within {tolerance:g} s and no two within {self.gap:g} s around it"
        )
