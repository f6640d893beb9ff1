"""``swarm bench coordinator``: the coordinator's answer time for a large team on a large site.

A mission of N robots on a synthetic office floor (rooms of 8 m x 6 m with 1 m doors off
2 m corridors; default 80 m x 48 m x 2.2 m at 0.1 m, 8.4 M voxels) is partly explored first:
each robot walks through the free space and fuses camera frames of rays cast against the
floor plan with the project's own fusion (:func:`swarm.map.fusion.batch_information`), and
the deltas are applied to a :class:`coordinator.state.CoordinatorState`'s team map as the
merged stream would. Then every robot asks for a target in turn
(:meth:`CoordinatorState.answer`), while between two requests the robots keep walking and
their new frames keep arriving. Printed: p50 / p95 / max answer time, the share of each
phase (``PHASES``: team-map copy, entropy, candidates, planning, assignment), the peak
memory (``ru_maxrss``) and, with ``--profile``, the functions cProfile finds slowest.
"""

from __future__ import annotations

import cProfile
import io
import math
import pstats
import resource
import time
from collections import defaultdict
from contextlib import ExitStack, contextmanager

import numpy as np

from coordinator.state import CoordinatorState
from swarm.config import mission_from_dict
from swarm.map.fusion import batch_information
from swarm.protocol.wire import AssignRequest, DeltaMessage, Pose

#: Room size (m), door width (m), corridor width (m) and spacing (m) of the synthetic floor.
ROOM = (8.0, 6.0)
DOOR = 1.0
CORRIDOR = 2.0
CORRIDOR_EVERY = (20.0, 12.0)
CAMERA_HEIGHT = 0.4
#: Rays of one camera frame (horizontal x vertical) and its field of view (degrees).
FRAME_RAYS = (64, 40)
FRAME_FOV_DEG = (60.0, 45.0)
STEP_M = 0.4
#: (phase, owner, attribute): the timed functions; a phase's time excludes the phases timed
#: inside it. A missing attribute is skipped (the figures of another version of the code).
PHASE_HOOKS = (
    ("copy", "swarm.protocol.team_replica:TeamReplica", "copy"),
    ("planning", "coordinator.state:CoordinatorState", "_reach"),
    ("planning", "coordinator.state:CoordinatorState", "_floor"),
    ("planning", "coordinator.state:CoordinatorState", "_cost_map"),
    ("candidates", "coordinator.state:CoordinatorState", "candidates_for"),
    ("candidates", "coordinator.state:CoordinatorState", "cached_candidates"),
    ("entropy", "coordinator.state:CoordinatorState", "_slab"),
    ("entropy", "swarm.navigation.search_context:SearchContext", "build"),
    ("entropy", "swarm.navigation.exploration", "entropy_gradient"),
    ("entropy", "swarm.navigation.exploration", "target_scores"),
    ("entropy", "swarm.navigation.exploration", "slab_scores"),
    ("assignment", "coordinator.state:CoordinatorState", "_teammates_shares"),
    ("assignment", "coordinator.replica:CoordinatorReplica", "teammates_ground"),
    ("assignment", "coordinator.state", "best_target"),
    ("assignment", "coordinator.state:CoordinatorState", "_wander"),
)
PHASES = ("copy", "entropy", "candidates", "planning", "assignment", "other")


def floor_plan(size_xy: tuple[float, float], voxel: float) -> np.ndarray:
    """(nx, ny) bool walls of the synthetic office floor (outer walls, rooms, doors, corridors)."""
    nx, ny = (int(round(s / voxel)) for s in size_xy)
    x = (np.arange(nx) + 0.5) * voxel
    y = (np.arange(ny) + 0.5) * voxel
    X, Y = np.meshgrid(x, y, indexing="ij")
    t = voxel * 1.5  # wall thickness
    outer = (X < t) | (Y < t) | (X > size_xy[0] - t) | (Y > size_xy[1] - t)
    rooms = (np.mod(X, ROOM[0]) < t) & (np.abs(np.mod(Y, ROOM[1]) - ROOM[1] / 2) > DOOR / 2)
    rooms |= (np.mod(Y, ROOM[1]) < t) & (np.abs(np.mod(X, ROOM[0]) - ROOM[0] / 2) > DOOR / 2)
    corridor = (np.abs(np.mod(X, CORRIDOR_EVERY[0]) - CORRIDOR_EVERY[0] / 2) < CORRIDOR / 2) | (
        np.abs(np.mod(Y, CORRIDOR_EVERY[1]) - CORRIDOR_EVERY[1] / 2) < CORRIDOR / 2
    )
    return outer | (rooms & ~corridor)


def frame_points(walls: np.ndarray, voxel: float, top: float, xy, yaw: float, reach: float) -> np.ndarray:
    """(R, 3) hit points of one camera frame at ``xy`` (m), heading ``yaw`` (rad), against the
    floor plan ``walls`` (vertical walls to ``top``), the floor (z 0) and the ceiling (``top``);
    a ray that hits nothing within ``reach`` ends there (a no-return, as far stereo returns)."""
    az = yaw + np.deg2rad(np.linspace(-FRAME_FOV_DEG[0] / 2, FRAME_FOV_DEG[0] / 2, FRAME_RAYS[0]))
    el = np.deg2rad(np.linspace(-FRAME_FOV_DEG[1] / 2, FRAME_FOV_DEG[1] / 2, FRAME_RAYS[1]))
    A, E = (v.ravel() for v in np.meshgrid(az, el, indexing="ij"))
    d = np.stack([np.cos(E) * np.cos(A), np.cos(E) * np.sin(A), np.sin(E)], axis=-1)
    t_plane = np.full(len(d), reach * 1.2)
    down, up = d[:, 2] < 0, d[:, 2] > 0
    t_plane[down] = np.minimum(t_plane[down], CAMERA_HEIGHT / -d[down, 2])
    t_plane[up] = np.minimum(t_plane[up], (top - voxel - CAMERA_HEIGHT) / d[up, 2])
    steps = np.arange(1, int(reach * 1.2 / (voxel / 2)) + 1) * (voxel / 2)
    px = xy[0] + d[:, 0:1] * steps[None, :]
    py = xy[1] + d[:, 1:2] * steps[None, :]
    ix = np.clip((px / voxel).astype(np.int64), 0, walls.shape[0] - 1)
    iy = np.clip((py / voxel).astype(np.int64), 0, walls.shape[1] - 1)
    hit = walls[ix, iy]
    first = np.where(hit.any(axis=1), steps[np.argmax(hit, axis=1)], np.inf)
    t = np.minimum(first, t_plane)
    origin = np.array([xy[0], xy[1], CAMERA_HEIGHT])
    return origin + d * t[:, None]


class Walkers:
    """The robots' walks: straight steps of STEP_M, a new random heading when a wall is near."""

    def __init__(self, walls: np.ndarray, voxel: float, n: int, rng: np.random.Generator) -> None:
        from scipy import ndimage

        self.walls, self.voxel, self.rng = walls, voxel, rng
        self.clear = ndimage.distance_transform_edt(~walls) * voxel  # m to the nearest wall
        free = np.argwhere(self.clear > 0.6)
        pick = free[rng.choice(len(free), n, replace=False)]
        self.xy = (pick + 0.5) * voxel
        self.yaw = rng.uniform(-math.pi, math.pi, n)

    def step(self, r: int) -> None:
        for _ in range(16):
            nxt = self.xy[r] + STEP_M * np.array([math.cos(self.yaw[r]), math.sin(self.yaw[r])])
            i, j = (nxt / self.voxel).astype(int)
            if 0 <= i < self.clear.shape[0] and 0 <= j < self.clear.shape[1] and self.clear[i, j] > 0.5:
                self.xy[r] = nxt
                return
            self.yaw[r] = self.rng.uniform(-math.pi, math.pi)


def bench_mission(robots: int, size: tuple[float, float, float], voxel: float):
    """The benchmark's mission: ``robots`` robots (r01, ...) on a workspace of ``size`` (m)."""
    return mission_from_dict(
        {
            "mission": "benchcoord",
            "workspace": {"lo": [0.0, 0.0, 0.0], "hi": list(size), "voxel": voxel},
            "robots": [{"id": f"r{k + 1:02d}"} for k in range(robots)],
            "rig": {"camera_height": CAMERA_HEIGHT, "hfov_deg": FRAME_FOV_DEG[0]},
            "sensor": {"sigma_min": 0.06, "zeta": 0.0375, "tau": 2.0, "max_range": 5.0},
            "exploration": {"radius": 1.5},
        }
    )


class Team:
    """The robots' frames fused into deltas and applied to a coordinator's team map."""

    def __init__(self, state: CoordinatorState, walls: np.ndarray, walkers: Walkers) -> None:
        self.state, self.walls, self.walkers = state, walls, walkers
        self.grid = state.team.grid
        self.sensor = state.team.map.sensor
        self.reach = self.sensor.reach
        self.seq = defaultdict(int)
        self.ids = list(state.mission.robot_ids)
        self.fuse_s = 0.0

    def frame(self, r: int, look: float = 0.0) -> None:
        """Robot ``r`` steps once and its frame's delta reaches the coordinator."""
        t0 = time.perf_counter()
        w = self.walkers
        w.step(r)
        top = float(self.grid.hi[2])
        pts = frame_points(self.walls, self.grid.voxel, top, w.xy[r], w.yaw[r] + look, self.reach)
        origin = np.array([w.xy[r][0], w.xy[r][1], CAMERA_HEIGHT])
        delta = batch_information(self.grid, self.sensor, origin, pts).delta
        rid = self.ids[r]
        self.seq[rid] += 1
        msg = DeltaMessage(rid, 1, self.seq[rid], 0.0, self.grid, delta.idx, delta.dlam, delta.deta)
        if len(delta.idx):
            self.state.team.apply_message(msg)
        self.fuse_s += time.perf_counter() - t0

    def pose(self, r: int) -> Pose:
        w = self.walkers
        return Pose((float(w.xy[r][0]), float(w.xy[r][1]), CAMERA_HEIGHT), (float(w.yaw[r]), 0.0, 0.0))


@contextmanager
def phase_timer(totals: dict[str, float]):
    """Wrap PHASE_HOOKS so that each call adds its own time (minus nested hooks) to ``totals``."""
    import importlib

    stack: list[float] = []  # nested time per open call

    def wrap(phase, fn):
        def timed(*args, **kwargs):
            t0 = time.perf_counter()
            stack.append(0.0)
            try:
                return fn(*args, **kwargs)
            finally:
                inner = stack.pop()
                spent = time.perf_counter() - t0
                totals[phase] += spent - inner
                if stack:
                    stack[-1] += spent

        return timed

    with ExitStack() as undo:
        for phase, owner, attr in PHASE_HOOKS:
            module, _, cls = owner.partition(":")
            target = importlib.import_module(module)
            if cls:
                target = getattr(target, cls)
            raw = target.__dict__.get(attr) if isinstance(target, type) else getattr(target, attr, None)
            if raw is None:
                continue
            if isinstance(raw, classmethod):
                new = classmethod(wrap(phase, raw.__func__))
            elif isinstance(raw, staticmethod):
                new = staticmethod(wrap(phase, raw.__func__))
            else:
                new = wrap(phase, raw)
            setattr(target, attr, new)
            undo.callback(setattr, target, attr, raw)
        yield


def run(
    robots: int,
    size: tuple[float, float, float] = (80.0, 48.0, 2.2),
    voxel: float = 0.1,
    explore_frames: int = 60,
    rounds: int = 2,
    frames_between: int = 1,
    seed: int = 0,
    profile: bool = False,
) -> dict:
    """Figures of one mission (module doc): ``explore_frames`` frames per robot first, then
    ``rounds`` requests per robot, ``frames_between`` frames (of the robots in turn) applied
    before each request. Answer times in seconds."""
    rng = np.random.default_rng(seed)
    mission = bench_mission(robots, size, voxel)
    walls = floor_plan(size[:2], voxel)
    state = CoordinatorState(mission)
    team = Team(state, walls, Walkers(walls, voxel, robots, rng))
    t0 = time.perf_counter()
    for k in range(explore_frames):
        for r in range(robots):
            team.frame(r, look=(k % 3 - 1) * math.radians(60.0))
    explore_s = time.perf_counter() - t0
    state.answer(AssignRequest(team.ids[0], team.pose(0)), now=0.0)  # loads the compiled kernels
    known = float(np.count_nonzero(state.team.map.known_mask())) / state.team.grid.size
    before = _cache_counts(state, None)
    times: list[float] = []
    phases: dict[str, float] = defaultdict(float)
    outcomes = defaultdict(int)
    profiler = cProfile.Profile() if profile else None
    turn = 0
    with phase_timer(phases):
        for _ in range(rounds):
            for r in range(robots):
                for _ in range(frames_between):
                    team.frame(turn % robots)
                    turn += 1
                request = AssignRequest(team.ids[r], team.pose(r))
                if profiler is not None:
                    profiler.enable()
                t = time.perf_counter()
                answer = state.answer(request, now=float(turn))
                times.append(time.perf_counter() - t)
                if profiler is not None:
                    profiler.disable()
                outcomes[
                    "assigned" if answer.candidate is not None else "wander" if answer.wander else "none"
                ] += 1
    total = sum(times)
    phases["other"] = max(total - sum(v for k, v in phases.items() if k != "other"), 0.0)
    top = None
    if profiler is not None:
        out = io.StringIO()
        pstats.Stats(profiler, stream=out).sort_stats("tottime").print_stats(30)
        top = out.getvalue()
    return {
        "robots": robots,
        "voxels": state.team.grid.size,
        "size": size,
        "known": known,
        "explore_s": explore_s,
        "times": np.array(times),
        "phases": dict(phases),
        "outcomes": dict(outcomes),
        "maxrss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0,
        "cache": _cache_counts(state, before),
        "profile": top,
    }


def format_figures(figures: dict) -> str:
    t = np.sort(figures["times"]) * 1e3
    total = t.sum() or 1.0
    p = lambda q: t[min(len(t) - 1, max(0, math.ceil(q * len(t)) - 1))]  # noqa: E731 (nearest rank)
    x, y, z = figures["size"]
    lines = [
        f"{figures['robots']} robots, {x:g} m x {y:g} m x {z:g} m ({figures['voxels'] / 1e6:.1f} M voxels), "
        f"{figures['known'] * 100:.1f}% of the voxels known (explored in {figures['explore_s']:.0f} s)",
        f"  answers: {len(t)}  p50 {p(0.5):7.1f} ms  p95 {p(0.95):7.1f} ms  max {t[-1]:7.1f} ms  "
        f"({', '.join(f'{k} {v}' for k, v in sorted(figures['outcomes'].items()))})",
        "  per answer: "
        + ", ".join(_phase(k, figures["phases"].get(k, 0.0) * 1e3, len(t), total) for k in PHASES),
        f"  peak memory (ru_maxrss): {figures['maxrss_mb']:.0f} MB",
    ]
    cache = figures.get("cache")
    if cache:
        n = len(t)
        lines.insert(
            3,
            f"  per answer: {cache['tiles'] / n:.1f} tiles of eq. 35 fields redone, standing cells "
            f"{cache['stands'] / n:.1f} searched and {cache['memo'] / n:.1f} from the memo",
        )
    if figures.get("profile"):
        lines.append(figures["profile"])
    return "\n".join(lines)


def _phase(name: str, ms: float, answers: int, total_ms: float) -> str:
    return f"{name} {ms / answers:.1f} ms ({ms / total_ms:.0%})"


def _cache_counts(state: CoordinatorState, before: dict | None) -> dict | None:
    """The target cache's counts (tiles redone, standing cells searched / remembered) since
    ``before``; None for a coordinator without the cache."""
    slabs = getattr(getattr(state, "targets", None), "_slabs", None)
    if slabs is None:
        return None
    now = {k: sum(c.counts[k] for c in slabs.values()) for k in ("tiles", "stands", "memo")}
    return now if before is None else {k: now[k] - before[k] for k in now}
