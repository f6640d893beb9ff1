"""Coordinated target assignment for a team (Burgard et al. 2005) over eq. 35 targets.

Pure numpy, no I/O and no clock of its own (times are arguments). The coordinator role
(``coordinator.role``) feeds it the entropy targets of the team map (paper eq. 30-35, from
``swarm.navigation.exploration.rank_entropy_targets``) and the path cost of each robot to
each of them; docs/coordinator.md has the rule with examples.

The rule (Burgard, Moors, Stachniss, Schneider: "Coordinated multi-robot exploration",
IEEE T-RO 21(3), 2005, algorithm 1), with our choices of U, P and normalisation:

1. Every target t starts with the utility U_t = S_t / max_t' S_t', where S_t is its eq. 35
   score |grad H_G(l_t)| (1 - E[C_l_t]) (bits/m): the best target has U = 1, as all
   frontier cells have U = 1 in Burgard's algorithm.
2. Repeatedly pick the (robot r, target t) pair, among robots without a target and targets
   not yet given, that maximises  U_t - beta * V_r(t),  where V_r(t) is r's path length (m)
   to t and beta (1/m) trades utility for travel (Burgard's eq. 5).
3. Lower the utility of every remaining target t' near the chosen t:
   U_t' <- U_t' * P(|x_t' - x_t|), with P(d) = min(d / R, 1): 0 at the chosen target, growing
   linearly to 1 at the footprint radius R (the area a robot observes around its target;
   the linear ramp stands for Burgard's visibility probability, which falls roughly
   linearly with the range).
4. Hard spacing: while some remaining target lies at least R from every chosen target, only
   such targets may be chosen, so no two robots work within one footprint of each other
   while anything else with positive utility is left. Only when every target is within a
   footprint does the discount alone decide.

Our addition, for robots that have already mapped part of the world: before step 2, robot
r's utility of t is also lowered by its teammates' ground, U_t <- U_t (1 - w f_r(t)), where
f_r(t) is the share of the x-y cells within R of t that are a teammate's ground
(:func:`teammates_share`): a cell is the ground of the robot whose deltas brought its column
the most information (:class:`ObservedColumns`), and w in [0, 1] is ``overlap_weight``.
Burgard's discount keeps robots away from where the others are going; this one keeps each
robot away from where the others have been, since whatever r observes there is observed a
second time.

For one request (robot r asks again; the others keep what they hold) the targets held by
the other robots count as chosen already: steps 3-4 are applied for each of them, then step
2 is taken for r alone (:func:`best_target`). :class:`coordinator.assignment_book.AssignmentBook`
keeps who holds what and releases a target when its robot asks again, reports it is done, or
goes silent.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from swarm.config import Mission

__all__ = [
    "CoordinationParams",
    "ObservedColumns",
    "assign_team",
    "best_target",
    "discounted_utilities",
    "normalised_utilities",
    "outside_footprints",
    "teammates_share",
    "visibility_discount",
]


@dataclass(frozen=True)
class CoordinationParams:
    """Parameters of the assignment rule (module doc) and of the book's release rules.

    ``beta`` (1/m): utility lost per metre of path (U is normalised to 1 for the best
    target), so 0.1 means ten metres of travel cost as much as the best target is worth.
    ``footprint_radius`` (m): R of the discount P(d), of the hard spacing and of the
    teammates' share f_r(t). ``overlap_weight`` (w, 0-1): how much of a target's utility the
    teammates' ground takes away (0: Burgard's rule alone).
    ``robot_timeout_s``: a robot not heard from (status or request) for longer than this
    loses its target. ``status_grace_s``: for this long after an assignment, the robot's
    statuses do not change its target (they may have been sent before it got the answer),
    except one of DONE_STATES.
    """

    beta: float = 0.1
    footprint_radius: float = 3.0
    overlap_weight: float = 1.0
    robot_timeout_s: float = 10.0
    status_grace_s: float = 2.0

    def __post_init__(self) -> None:
        checks = {
            "beta": self.beta >= 0,
            "footprint_radius": self.footprint_radius > 0,
            "overlap_weight": 0 <= self.overlap_weight <= 1,
            "robot_timeout_s": self.robot_timeout_s > 0,
            "status_grace_s": self.status_grace_s >= 0,
        }
        for name, ok in checks.items():
            value = getattr(self, name)
            if not (ok and math.isfinite(value)):
                raise ValueError(f"coordination: {name} must be a finite number in range, got {value!r}")


# ---------------------------------------------------------------------------------------
# The rule
# ---------------------------------------------------------------------------------------
def visibility_discount(distance, footprint_radius: float) -> np.ndarray:
    """P(d) = min(d / R, 1) (step 3 of the module doc): 0 at a chosen target, 1 beyond R."""
    if not footprint_radius > 0:
        raise ValueError(f"footprint radius must be > 0, got {footprint_radius!r}")
    d = np.asarray(distance, dtype=np.float64)
    return np.clip(d / float(footprint_radius), 0.0, 1.0)


def _points(values, name: str) -> np.ndarray:
    pts = np.asarray(values, dtype=np.float64)
    if pts.size == 0:
        return np.zeros((0, 2))
    if pts.ndim != 2 or pts.shape[1] < 2:
        raise ValueError(f"{name} must be points of shape (N, 2) or (N, 3), got {pts.shape}")
    return pts[:, :2]


def _distances(positions: np.ndarray, chosen: np.ndarray) -> np.ndarray:
    """(K, M) x-y distances between targets and chosen points."""
    return np.linalg.norm(positions[:, None, :] - chosen[None, :, :], axis=-1)


def normalised_utilities(scores) -> np.ndarray:
    """U_t = S_t / max S (step 1): eq. 35 scores scaled so the best is 1; non-finite -> 0."""
    s = np.asarray(scores, dtype=np.float64).ravel().copy()
    s[~np.isfinite(s)] = 0.0
    top = float(s.max()) if s.size else 0.0
    return s / top if top > 0 else np.zeros_like(s)


def discounted_utilities(utilities, positions, chosen, footprint_radius: float) -> np.ndarray:
    """U_t * prod over chosen points c of P(|x_t - c|) (step 3, for every chosen point)."""
    u = np.asarray(utilities, dtype=np.float64).ravel()
    pos = _points(positions, "positions")
    ch = _points(chosen, "chosen")
    if len(pos) != len(u):
        raise ValueError(f"{len(u)} utilities but {len(pos)} positions")
    if len(ch) == 0 or len(u) == 0:
        return u.copy()
    return u * np.prod(visibility_discount(_distances(pos, ch), footprint_radius), axis=1)


def outside_footprints(positions, chosen, footprint_radius: float) -> np.ndarray:
    """Targets at least R from every chosen point (all of them when nothing is chosen)."""
    pos = _points(positions, "positions")
    ch = _points(chosen, "chosen")
    if len(ch) == 0:
        return np.ones(len(pos), dtype=bool)
    return np.all(_distances(pos, ch) >= footprint_radius, axis=1)


def teammates_share(points, teammates_ground: np.ndarray, lo, voxel: float, radius: float) -> np.ndarray:
    """f_r(t) of the module doc: for each point, the share of the x-y cells within ``radius``
    of it (inside the grid) that are True in ``teammates_ground`` (nx, ny).

    ``lo`` is the grid's x-y origin and ``voxel`` its cell size (m); a point's own cell is
    the one it lies in. Points outside the grid count only the in-grid part of their disc
    (0.0 when none of it is inside).
    """
    mask = np.asarray(teammates_ground, dtype=bool)
    pts = _points(points, "points")
    if mask.ndim != 2:
        raise ValueError(f"teammates_ground must be an (nx, ny) mask, got shape {mask.shape}")
    if not (voxel > 0 and radius >= 0):
        raise ValueError(f"voxel must be > 0 and radius >= 0, got {voxel!r} and {radius!r}")
    if len(pts) == 0:
        return np.zeros(0)
    # the disc, row by row: offsets dy in [-w, w] on row dx (w = -1: none), as the test
    # (dx^2 + dy^2) e^2 <= R^2 has them (growing with |dy|, so each row is one run)
    reach = int(math.floor(radius / voxel))
    d = np.arange(-reach, reach + 1)
    inside = (d[:, None] * d[:, None] + d[None, :] * d[None, :]) * voxel * voxel <= radius * radius
    w = (inside.sum(axis=1) - 1) // 2  # (D,)
    nx, ny = mask.shape
    prefix = np.zeros((nx, ny + 1), dtype=np.int64)  # cells of the mask before column j, per row
    np.cumsum(mask, axis=1, out=prefix[:, 1:])
    cells = np.floor((pts - np.asarray(lo, dtype=np.float64)[:2]) / voxel).astype(np.int64)
    rows = cells[:, :1] + d[None, :]  # (K, D)
    ok = (rows >= 0) & (rows < nx) & (w[None, :] >= 0)
    j0 = np.clip(cells[:, 1:] - w[None, :], 0, ny)
    j1 = np.clip(cells[:, 1:] + w[None, :] + 1, 0, ny)
    width = np.where(ok, np.maximum(j1 - j0, 0), 0)
    r = np.clip(rows, 0, nx - 1)
    hits = np.where(width > 0, prefix[r, np.maximum(j1, j0)] - prefix[r, j0], 0).sum(axis=1)
    total = width.sum(axis=1)
    return np.where(total > 0, hits / np.maximum(total, 1), 0.0)


def _own_utilities(utilities: np.ndarray, shares, weight: float) -> np.ndarray:
    """U_t (1 - w f_r(t)): the module doc's lowering for teammates' ground."""
    if shares is None:
        return utilities
    f = np.asarray(shares, dtype=np.float64)
    if f.shape != utilities.shape:
        raise ValueError(f"teammates' shares have shape {f.shape}, utilities {utilities.shape}")
    return utilities * (1.0 - weight * np.clip(np.nan_to_num(f), 0.0, 1.0))


def _eligible(utilities: np.ndarray, outside: np.ndarray, ok: np.ndarray) -> np.ndarray:
    """Step 4: only targets outside every footprint while any of them has U > 0; else any
    with U > 0 (a target at a chosen one has U = 0, so it is never given twice)."""
    useful = ok & (utilities > 0)
    spaced = useful & outside
    return spaced if spaced.any() else useful


def best_target(
    utilities,
    positions,
    costs,
    held: Sequence | np.ndarray = (),
    params: CoordinationParams = CoordinationParams(),
    teammates: Sequence | np.ndarray | None = None,
) -> int | None:
    """The target for one robot: argmax U'_t - beta V(t) (step 2) with the others' ``held``
    targets discounted (step 3) and spaced from (step 4).

    ``utilities`` (K,) are eq. 35 scores (normalised here, step 1), ``positions`` (K, 2|3)
    the targets, ``costs`` (K,) the robot's path lengths (inf: unreachable, never chosen),
    ``held`` (M, 2|3) the other robots' targets, ``teammates`` (K,) the shares f_r(t) of
    teammates' ground (None: no lowering). The lowering changes the scores,
    not which targets are eligible. None when no reachable target has U' > 0.
    """
    u = normalised_utilities(utilities)
    pos = _points(positions, "positions")
    cost = np.asarray(costs, dtype=np.float64).ravel()
    if not (len(u) == len(pos) == len(cost)):
        raise ValueError(
            f"utilities, positions and costs differ in length: {len(u)}, {len(pos)}, {len(cost)}"
        )
    ok = np.isfinite(cost)
    u = discounted_utilities(u, pos, held, params.footprint_radius)
    eligible = _eligible(u, outside_footprints(pos, held, params.footprint_radius), ok)
    if not eligible.any():
        return None
    own = _own_utilities(u, teammates, params.overlap_weight)
    score = np.where(eligible, own - params.beta * np.where(ok, cost, 0.0), -np.inf)
    return int(np.argmax(score))


def assign_team(
    utilities,
    positions,
    costs,
    held: Sequence | np.ndarray = (),
    params: CoordinationParams = CoordinationParams(),
    teammates: np.ndarray | None = None,
) -> list[tuple[int, int]]:
    """Burgard's greedy assignment of targets to several robots at once (steps 1-4).

    ``costs`` (R, K): robot r's path length to target t (inf: unreachable). ``held`` (M, 2|3):
    targets already taken by robots outside this batch. ``teammates`` (R, K): the shares
    f_r(t) (None: no lowering; see :func:`best_target`). Returns the (robot, target) index
    pairs in the order they were chosen; a robot missing from it got nothing (no reachable
    target with U' > 0 was left for it). No target is given twice.
    """
    u = normalised_utilities(utilities)
    pos = _points(positions, "positions")
    cost = np.asarray(costs, dtype=np.float64)
    if cost.ndim != 2 or cost.shape[1] != len(u) or len(pos) != len(u):
        raise ValueError(f"costs must be (robots, {len(u)}) for {len(u)} targets, got {cost.shape}")
    shares = np.zeros(cost.shape) if teammates is None else np.asarray(teammates, dtype=np.float64)
    if shares.shape != cost.shape:
        raise ValueError(f"teammates' shares must have the shape of costs {cost.shape}, got {shares.shape}")
    chosen = list(_points(held, "held"))
    u = discounted_utilities(u, pos, chosen, params.footprint_radius) if chosen else u
    out: list[tuple[int, int]] = []
    waiting = list(range(cost.shape[0]))
    while waiting:
        outside = outside_footprints(pos, np.asarray(chosen), params.footprint_radius)
        eligible = np.stack([_eligible(u, outside, np.isfinite(cost[r])) for r in waiting])
        if not eligible.any():
            break
        own = np.stack([_own_utilities(u, shares[r], params.overlap_weight) for r in waiting])
        path = params.beta * np.where(eligible, cost[waiting], 0.0)
        score = np.where(eligible, own - path, -np.inf)
        w, t = np.unravel_index(int(np.argmax(score)), score.shape)
        out.append((waiting.pop(int(w)), int(t)))
        chosen.append(pos[t])
        u = u * visibility_discount(np.linalg.norm(pos - pos[t], axis=1), params.footprint_radius)
    return out


# ---------------------------------------------------------------------------------------
# Who has seen what
# ---------------------------------------------------------------------------------------
class ObservedColumns:
    """Whose ground each x-y cell is: the information (sum of added precision, dlam) each
    robot's deltas brought to the voxels of the cell's column. A cell is a robot's *own*
    ground when that robot brought it the most information, so a glance through a door
    does not make a room mapped by a teammate one's own. Feeds f_r(t) (:func:`teammates_share`).

    ``shape`` is the grid's (nx, ny, nz); voxel indices are flat in C order, so a voxel's
    column is its index // nz. Each robot costs 8 bytes per cell: at most ``max_robots``
    robots are credited (the first to come; None: no bound), since on an open bus anyone can
    put deltas of invented robots on ``merged``. Per cell the largest total, its robot and
    the largest total of the other robots are kept as deltas come (totals only grow), so
    :meth:`teammates_ground` is one pass over the cells whatever the number of robots.
    """

    def __init__(self, shape: Sequence[int], max_robots: int | None = None) -> None:
        nx, ny, nz = (int(n) for n in shape)
        self.shape = (nx, ny)
        self._nz = nz
        self.max_robots = max_robots
        self._by_robot: dict[str, np.ndarray] = {}
        self._index: dict[str, int] = {}
        n = nx * ny
        self._best = np.zeros(n)  # the largest total of the cell
        self._owner = np.full(n, -1, dtype=np.int64)  # a robot with it (-1: none yet)
        self._second = np.zeros(n)  # the largest total of the robots other than the owner

    def add(self, robot: str, voxels, information) -> bool:
        """Credit ``robot`` with ``information`` (dlam, >= 0) on ``voxels`` (flat indices); False
        (nothing credited) for a new robot beyond ``max_robots``."""
        cells = np.asarray(voxels, dtype=np.int64) // self._nz
        info = np.clip(np.nan_to_num(np.asarray(information, dtype=np.float64)), 0.0, None)
        if cells.shape != info.shape:
            raise ValueError(f"{cells.shape[0]} voxels but information of shape {info.shape}")
        total = self._by_robot.get(robot)
        if total is None:
            if self.max_robots is not None and len(self._by_robot) >= self.max_robots:
                return False
            total = self._by_robot[robot] = np.zeros(self.shape[0] * self.shape[1])
            self._index[robot] = len(self._index)
        # per touched cell only (a whole-floor bincount per delta costs more than the delta)
        touched, where = np.unique(cells, return_inverse=True)
        total[touched] += np.bincount(where, weights=info, minlength=touched.size)
        self._raise(self._index[robot], touched, total)
        return True

    def _raise(self, k: int, cells: np.ndarray, total: np.ndarray) -> None:
        """Robot ``k``'s totals of ``cells`` grew to ``total[cells]``: update best, owner, second."""
        v = total[cells]
        best = self._best[cells]
        own = self._owner[cells] == k
        up = ~own & (v > best)  # k overtakes the owner, who becomes the best of the others
        rest = ~own & ~up
        self._second[cells[up]] = best[up]
        self._owner[cells[up]] = k
        self._best[cells[own | up]] = v[own | up]
        self._second[cells[rest]] = np.maximum(self._second[cells[rest]], v[rest])

    def robots(self) -> list[str]:
        return sorted(self._by_robot)

    def teammates_ground(self, robot: str) -> np.ndarray:
        """(nx, ny): cells to which some other robot brought more information than ``robot``."""
        k = self._index.get(robot, -2)
        others = np.where(self._owner == k, self._second, self._best)
        mine = self._by_robot.get(robot)
        theirs = others > (0.0 if mine is None else mine)
        return theirs.reshape(self.shape)


def params_from_mission(mission: Mission) -> CoordinationParams:
    """The assignment parameters of a mission's ``coordination`` section.

    The footprint radius defaults to min(2 xi, sensor reach): two robots whose targets are
    at least 2 xi apart choose their next targets (within xi of where they stand, eq. 30)
    from disjoint neighbourhoods, and nothing beyond the sensor's reach (its max range, or
    the rigs' hit range when shorter: ``Mission.sensor_reach``) is seen from a target.
    """
    c = mission.coordination
    footprint = c.footprint_radius
    if footprint is None:
        footprint = min(2.0 * mission.exploration.radius, mission.sensor_reach())
    return CoordinationParams(
        beta=c.beta,
        footprint_radius=footprint,
        overlap_weight=c.overlap_weight,
        robot_timeout_s=c.robot_timeout_s,
    )
