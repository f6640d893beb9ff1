"""Where a robot should go next: the paper's entropy-gradient target and two baselines.

Pure functions of one :class:`~swarm.navigation.search_context.SearchContext` (the map, its
entropy, the robot's pose, its traversability grid and planner cost map) and a frozen
:class:`SearchOptions` (docs/design.md section 3, "Exploration", paper eq. 27-36); no I/O, no
state. The strategies' names are :data:`swarm.navigation.strategies.STRATEGIES`.

- ``"entropy"`` (the paper): l_s = argmax |grad H_G(l)| (1 - E[C_l]) over the slab of
  voxels at sensor height within xi of the robot (eq. 30, 32, 33, 35), among voxels the
  robot can *view* from reachable space; gaze along grad H_G(l_s) (eq. 34). The robot
  stands back from l_s, on the side the gradient comes from, so that l_s and the higher
  entropy beyond it are in its field of view. When nothing within xi is conclusive the
  radius is doubled up to the whole map (our extension, so that missions finish); then it
  probes the largest unknown floor region that only unknown or ambiguous columns close
  off (a room behind a door; :mod:`swarm.navigation.probing`); then, given the camera's
  reach, the robot looks at the nearest 3-D frontier voxel above or below the slab
  (:mod:`swarm.navigation.view_targets`); then it wanders while unknown voxels bordering
  known free space remain in view of reachable space; otherwise there is
  no reachable informative target (None, a mission stop condition).
- ``"frontier"`` (Yamauchi 1997): the nearest reachable frontier cell by path cost; when the
  2-D frontier is empty, the nearest 3-D frontier view (given the camera's reach).
- ``"random"``: a uniformly random reachable cell within 2 xi.

``rank_entropy_targets`` lists the entropy candidates in the order ``choose_target`` tries
them, each with its standing point, gaze, eq. 35 utility and path cost: the coordinator
scores them for several robots (docs/coordinator.md).

Viewing model. The sensor's plane is the slab layer k0 that holds the sensor (eq. 30). A
slab voxel is *opaque* when it is known and E[C] >= 0.2 (not surely free); unknown and
free voxels are transparent. A voxel is *in view* of reachable space within a range r
when a path of at most r through transparent slab voxels (octagonal metric: 4- and
8-neighbour steps alternate) joins it to a reachable cell. An entropy target's standing point is then
checked exactly (:mod:`swarm.navigation.standing_points`: distance, angle to the gaze,
straight line of sight); candidates without one are skipped.

Grids: the traversability grid must be the map's x-y columns (same origin, resolution
and shape), as :func:`swarm.navigation.traversability.build_traversability` makes it
(:meth:`SearchContext.build` checks).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, replace

import numpy as np

from swarm.map.gradient import candidate_voxels, entropy_gradient, project_on_plane, robot_axes, target_scores
from swarm.navigation.baselines import frontier_cells, frontier_target, random_cell_target, random_target
from swarm.navigation.probing import probe_target
from swarm.navigation.search_context import SearchContext
from swarm.navigation.standing_points import ViewGeometry, standing_cell
from swarm.navigation.strategies import STRATEGIES, check_strategy
from swarm.navigation.targets import ExplorationTarget
from swarm.navigation.traversability import TraversabilityGrid
from swarm.navigation.view_targets import CameraReach, uncertain_voxels, view_target

__all__ = [
    "DEFAULT_MIN_STEP_BITS",
    "STRATEGIES",
    "EntropyCandidate",
    "ExplorationTarget",
    "SearchContext",
    "SearchOptions",
    "choose_target",
    "frontier_cells",
    "last_look_target",
    "rank_entropy_targets",
    "slab_fields",
    "wander_target",
]

#: Default eq. 35 threshold, as an entropy step between neighbouring voxels: a score is
#: conclusive when it beats a 2-bit step (per voxel edge) at a surely empty voxel, or a
#: 4-bit step at an unknown one (E[C] = 1/2); tuned on the office simulation.
DEFAULT_MIN_STEP_BITS = 2.0
#: Candidates the standing-point check rejects before the radius is widened anyway.
MAX_TRIES = 64

#: The eq. 32-35 fields of the slab (:func:`slab_fields`): the projected gradient grad H_G
#: (nx, ny, 3), its norm (nx, ny) and the eq. 35 score (nx, ny, float64, bits/m).
SlabFields = tuple[np.ndarray, np.ndarray, np.ndarray]
#: Where to stand to view a slab column: :func:`swarm.navigation.standing_points.standing_cell`'s
#: signature (a caller may memoise it).
StandingFn = Callable[[SearchContext, int, int, np.ndarray, ViewGeometry], "tuple[int, int] | None"]


@dataclass(frozen=True)
class SearchOptions:
    """How a target search looks: the knobs, fixed for a robot or a call (the state is the
    :class:`SearchContext`).

    ``radius``: the neighbourhood xi of eq. 30 (m); ``min_score``: the eq. 35 threshold
    (bits/m; None: DEFAULT_MIN_STEP_BITS / voxel edge); ``view``: where the robot may stand to
    look at an entropy target; ``widen``: double xi up to the whole map when nothing within it
    is conclusive (False: the paper's fixed radius, then wander, then None); ``camera``: the
    camera's elevation band and range, for the 3-D frontier views (None: no views);
    ``max_looks``: frontier strategy, looks per 3-D frontier column, each from another cell
    (:mod:`swarm.navigation.view_targets`; the entropy strategy looks at each column once).
    """

    radius: float = 1.5
    min_score: float | None = None
    view: ViewGeometry = ViewGeometry()
    widen: bool = True
    camera: CameraReach | None = None
    max_looks: int = 1

    def __post_init__(self) -> None:
        if not self.radius > 0:
            raise ValueError(f"radius must be > 0, got {self.radius}")
        if self.min_score is not None and not self.min_score >= 0:
            raise ValueError(f"min_score must be >= 0, got {self.min_score}")
        if self.max_looks < 1:
            raise ValueError(f"max_looks must be >= 1, got {self.max_looks}")


@dataclass(frozen=True, eq=False)
class EntropyCandidate:
    """One eq. 35 target with where to look at it from (see :func:`rank_entropy_targets`).

    ``voxel`` is the flat index of the slab voxel l, ``point`` its centre w(l) (3,);
    ``xy`` the standing point (a reachable cell centre), ``gaze_yaw`` the direction of
    grad H_G(l) (eq. 34), ``utility`` the eq. 35 score |grad H_G(l)| (1 - E[C_l]) in
    bits/m, ``path_cost`` the planner's path length (m) from the robot to ``xy`` (0 when
    it is the robot's own cell).
    """

    voxel: int
    point: np.ndarray
    xy: np.ndarray
    gaze_yaw: float
    utility: float
    path_cost: float

    def as_target(self) -> ExplorationTarget:
        """The navigator's goal for this candidate (what :func:`choose_target` returns)."""
        return ExplorationTarget(
            xy=self.xy, gaze_yaw=self.gaze_yaw, utility=self.utility, voxel=self.voxel, kind="entropy"
        )


def choose_target(
    strategy: str,
    ctx: SearchContext,
    options: SearchOptions,
    rng: np.random.Generator,
    *,
    tried: Sequence[np.ndarray] = (),
    stands: Sequence[np.ndarray] | None = None,
    optimistic: TraversabilityGrid | None = None,
    slab: SlabFields | None = None,
    stand: StandingFn = standing_cell,
) -> ExplorationTarget | None:
    """The next target of ``strategy`` (one of STRATEGIES) in ``ctx``, or None when done.

    With ``options.camera``, a strategy whose own targets have run out (no eq. 35 target and
    no unknown slab voxel in view; no 2-D frontier) goes on to the nearest 3-D frontier voxel
    it can be pointed at (:func:`swarm.navigation.view_targets.view_target`, kind ``"view"``),
    skipping the columns in ``tried`` (x-y); None only when none is left either. For
    ``"frontier"``, ``stands`` (where the robot stood for each of ``tried``) and
    ``options.max_looks`` let a column be looked at again from elsewhere.

    ``optimistic``: the grid of :func:`swarm.navigation.probing.optimistic_traversability`.
    When given, the entropy strategy with no eq. 35 target first probes the largest unknown
    floor region it opens (kind ``"probe"``, :func:`swarm.navigation.probing.probe_target`:
    a room behind a door whose floor is unknown), before the 3-D views; plan to a probe on
    ``optimistic``. ``slab``/``stand``: the context's :func:`slab_fields` and a memo of
    ``standing_cell`` when kept already (swarm.navigation.target_cache; the entropy strategy
    reads them). ValueError for an unknown strategy.
    """
    check_strategy(strategy)
    if strategy == "entropy":
        return _entropy_target(ctx, options, rng, tried, optimistic, slab, stand)
    if strategy == "frontier":
        found = frontier_target(ctx, options.view.far)
        if found is None and options.camera is not None:
            found = view_target(
                ctx, options.camera, tried, kind="frontier3d", stands=stands, max_looks=options.max_looks
            )
        return found
    return random_target(ctx, 2.0 * options.radius, rng, options.view.far)


def last_look_target(
    ctx: SearchContext, camera: CameraReach, min_bits: float, tried: Sequence[np.ndarray] = ()
) -> ExplorationTarget | None:
    """Where a robot that has no other target left would stop: the nearest view (kind
    ``"last look"``) of a voxel still holding at least ``min_bits`` of entropy (known or not)
    on a face of known free space, skipping the columns in ``tried``
    (:func:`swarm.navigation.view_targets.uncertain_voxels`); None when no such voxel is in
    view of a reachable cell."""
    voxels = uncertain_voxels(ctx, ctx.entropy, min_bits)
    return view_target(ctx, camera, tried, kind="last look", voxels=voxels)


def rank_entropy_targets(
    ctx: SearchContext,
    options: SearchOptions,
    *,
    limit: int | None = None,
    min_separation: float = 0.0,
    max_rejects: int = MAX_TRIES,
    slab: SlabFields | None = None,
    stand: StandingFn = standing_cell,
) -> list[EntropyCandidate]:
    """Entropy targets (eq. 30-35) in the order ``choose_target("entropy", ...)`` tries them.

    Candidates come ring by ring (xi, then 2 xi, 4 xi, ... while ``options.widen``), by
    decreasing eq. 35 utility within a ring, each with a standing point and its path cost from
    the context's planner cost; the first one is ``choose_target``'s entropy target whenever that
    is not a wander. A radius at least the map's extent gives one ring: the whole map by
    utility. ``min_separation`` (m) skips a voxel column closer than that to one already listed
    (a spread-out list for the coordinator); ``limit`` caps the length; ``max_rejects``
    candidates without a standing point end a ring early. Empty when nothing viewable beats
    the threshold (no wandering here). ``slab``: the context's :func:`slab_fields`, if kept
    already (a cache; None: computed here); ``stand``: ``standing_cell`` or a memo of it.
    """
    if limit is not None and limit < 1:
        raise ValueError(f"limit must be >= 1, got {limit}")
    if max_rejects < 1:
        raise ValueError(f"max_rejects must be >= 1, got {max_rejects}")
    found = _entropy_candidates(ctx, options, max_rejects, min_separation, slab, stand)
    out: list[EntropyCandidate] = []
    for candidate in found:
        out.append(candidate)
        if limit is not None and len(out) >= limit:
            break
    return out


def wander_target(
    ctx: SearchContext, radius: float, rng: np.random.Generator, avoid: np.ndarray | None = None
) -> ExplorationTarget | None:
    """``choose_target``'s wander, for a caller that knows where the robot should not go.

    When eq. 35 offers nothing, an agent wanders: a uniform reachable cell within
    ``radius`` (m) of it (else anywhere reachable), random gaze, while any unknown slab voxel
    is in view of reachable space (None otherwise: nothing left to see). Here the cell is
    also kept out of ``avoid`` ((nx, ny) bool) and away from the context's excluded points
    while any other reachable cell is left.
    """
    if not ctx.reach.any() or not ctx.unknown_in_view():
        return None
    allowed = ctx.allowed if avoid is None else ctx.allowed & ~np.asarray(avoid, dtype=bool)
    pool = ctx.reach & allowed
    pool[ctx.start] = False
    if not pool.any():
        allowed = ctx.allowed if (ctx.reach & ctx.allowed).any() else np.ones_like(ctx.allowed)
    return random_cell_target(replace(ctx, allowed=allowed), radius, rng, "wander", 0.0)


# ---------------------------------------------------------------------------------------
# Entropy gradient (the paper)
# ---------------------------------------------------------------------------------------
def _entropy_target(
    ctx: SearchContext,
    options: SearchOptions,
    rng: np.random.Generator,
    tried: Sequence[np.ndarray] = (),
    optimistic: TraversabilityGrid | None = None,
    slab: SlabFields | None = None,
    stand: StandingFn = standing_cell,
) -> ExplorationTarget | None:
    """Eq. 35 target among viewable slab voxels within xi, widening xi, 2 xi, ...; else a probe
    into unknown floor (with ``optimistic``); else a 3-D frontier view (with a camera); else
    wander/None."""
    best = next(_entropy_candidates(ctx, options, slab=slab, stand=stand), None)
    if best is not None:
        return best.as_target()
    if optimistic is not None:
        probe = probe_target(ctx, optimistic)
        if probe is not None:
            return probe
    if options.camera is not None:
        seen = view_target(ctx, options.camera, tried)
        if seen is not None:
            return seen
    if not ctx.reach.any() or not ctx.unknown_in_view():
        return None
    return random_cell_target(ctx, 2.0 * options.radius, rng, "wander", 0.0)


def slab_fields(H_slab: np.ndarray, voxel: float, slab_cov: np.ndarray, yaw: float = 0.0) -> SlabFields:
    """Eq. 32 (backward differences) on the slab, projected on the motion plane (eq. 33), and
    the eq. 35 score |grad H_G| (1 - E[C]) of each slab column.

    ``H_slab`` (nx, ny, 1 | 2): entropy (bits) of the layer below the slab and of the slab (the
    slab alone at the lowest layer), ``slab_cov`` (nx, ny): E[C] of the slab voxels, ``yaw``
    the robot's (rad; a ground robot's plane is horizontal whatever its yaw). Element-wise
    but for the differences, so a block of columns with one column of halo before it in x
    and y gives the same values as the whole slab (the coordinator's cache relies on it).
    """
    G = entropy_gradient(H_slab, voxel)[:, :, -1]
    G = project_on_plane(G, robot_axes(yaw)[2])
    gnorm = np.sqrt(np.einsum("ijk,ijk->ij", G, G))
    score = target_scores(gnorm, slab_cov, np.arange(gnorm.size)).reshape(gnorm.shape)
    return G, gnorm, score


def _all_columns_within(grid, position: np.ndarray, k0: int, xi: float) -> bool:
    """Whether eq. 30's neighbourhood of radius ``xi`` holds every column of layer ``k0``
    (``candidate_voxels``' test at the farthest corner column, same arithmetic)."""
    nx, ny, _ = grid.shape
    o, e = grid.origin, grid.voxel
    dx = o[0] + (np.array([0, nx - 1]) + 0.5) * e - position[0]
    dy = o[1] + (np.array([0, ny - 1]) + 0.5) * e - position[1]
    dz = o[2] + (k0 + 0.5) * e - position[2]
    return bool(np.max(dx**2) + np.max(dy**2) + dz**2 <= xi * xi)


def _entropy_candidates(
    ctx: SearchContext,
    options: SearchOptions,
    max_rejects: int = MAX_TRIES,
    min_separation: float = 0.0,
    slab: SlabFields | None = None,
    stand: StandingFn = standing_cell,
) -> Iterator[EntropyCandidate]:
    """Eq. 35 candidates with a standing point, best first within xi, then 2 xi, 4 xi, ...

    Within one radius the open slab columns (viewable from reachable space, allowed, score
    above ``min_score``) are tried by decreasing eq. 35 score; a column without a standing
    point is closed and counts as a reject, and after ``max_rejects`` rejects in one radius
    the radius is widened anyway. A column within ``min_separation`` (m) of a column already
    yielded is skipped (not a reject). Each column is yielded at most once.
    """
    grid = ctx.cmap.grid
    nx, ny, nz = grid.shape
    e = grid.voxel
    H = ctx.entropy.reshape(nx, ny, nz)
    min_score = DEFAULT_MIN_STEP_BITS / e if options.min_score is None else options.min_score
    view = options.view
    if not ctx.reach.any():
        return
    # eq. 32 on the slab (one layer below it for the z difference), projected (eq. 33), eq. 35
    k0 = ctx.k0
    if slab is None:
        slab = slab_fields(H[:, :, max(k0 - 1, 0) : k0 + 1], e, ctx.slab_cov, ctx.yaw)
    G, gnorm, score = slab
    open_ = ctx.in_view(view.far) & ctx.allowed & (score > min_score)
    # distance to the farthest slab voxel: beyond it, widening adds nothing
    far = np.linalg.norm(np.maximum(ctx.position - grid.lo, grid.hi - ctx.position)[:2]) + e
    z = grid.lo[2] + (k0 + 0.5) * e
    taken = np.empty((0, 2))  # the yielded columns' centres, in order (grown by doubling)
    n_taken = 0
    xi = float(options.radius)
    while open_.any():
        if _all_columns_within(grid, ctx.position, k0, xi):
            cols = np.flatnonzero(open_.ravel())  # eq. 30 holds the whole layer
        else:
            flat = candidate_voxels(grid.shape, e, grid.origin, ctx.position, xi)  # eq. 30
            cols = flat // nz
            cols = cols[open_.ravel()[cols]]
        tries = 0
        for c in cols[np.argsort(-score.ravel()[cols], kind="stable")]:
            i, j = divmod(int(c), ny)
            if not open_[i, j]:
                continue
            here = ctx.centre(i, j)
            if n_taken and min_separation > 0:
                if np.min(np.linalg.norm(taken[:n_taken] - here, axis=1)) < min_separation:
                    continue
            g = G[i, j, :2] / gnorm[i, j]
            cell = stand(ctx, i, j, g, view)
            open_[i, j] = False
            if cell is not None:
                if n_taken == len(taken):
                    taken = np.concatenate([taken, np.empty((max(len(taken), 16), 2))])
                taken[n_taken] = here
                n_taken += 1
                yield EntropyCandidate(
                    voxel=int(c) * nz + k0,
                    point=np.array([here[0], here[1], z]),
                    xy=ctx.centre(*cell),
                    gaze_yaw=math.atan2(g[1], g[0]),  # eq. 34, towards higher entropy
                    utility=float(score[i, j]),
                    path_cost=0.0 if cell == ctx.start else float(ctx.cost[cell]),
                )
                continue
            tries += 1
            if tries >= max_rejects:
                break
        if not options.widen or xi >= far:
            break
        xi *= 2.0
