"""What an observer of a mission's bus knows: the team map, trajectories, states and traffic.

:class:`TeamMonitor` subscribes like any client (``delta/*``, of every map server shard when
the map service is sharded; ``sim/truth``, ``robot/*/status``) and keeps a replica of the team
map from the deltas it sees (a :class:`swarm.protocol.team_replica.TeamReplica` fed the robots'
own deltas, each once): the entropy
curve (one sample per delta), the bytes each robot shared, and per robot which of its deltas
first carried each voxel (for the overlap over time). ``swarm sim`` and ``swarm replay run``
(:mod:`swarm.mission.runner`, :mod:`swarm.mission.replay_run`) watch their missions with it.
"""

from __future__ import annotations

import logging
import threading
from dataclasses import dataclass, field

import numpy as np

from swarm.config import Mission
from swarm.log_limit import LogLimiter
from swarm.map.coverage_map import CoverageMap
from swarm.map.entropy_cache import EntropyCache
from swarm.mission.prior_map import PRIOR_SOURCE
from swarm.protocol.message_size import sources_of_deltas
from swarm.protocol.team_replica import TeamReplica
from swarm.protocol.wire import DeltaMessage, TruthPoses, WireError, status_on_key

log = logging.getLogger("swarm.monitor")

NEVER = np.iinfo(np.int32).max  # first_delta of a voxel no delta of the robot carried


@dataclass
class TeamMonitor:
    """What an observer of the bus knows: the team map, trajectories, states and traffic."""

    mission: Mission
    team: TeamReplica = field(init=False)
    curve: list[tuple[float, float]] = field(default_factory=list)
    trajectories: dict[str, list[tuple[float, float, float]]] = field(default_factory=dict)
    states: dict[str, str] = field(default_factory=dict)
    bytes_shared: dict[str, int] = field(default_factory=dict)
    # robot -> per voxel, the number of the first of its deltas that carried it (NEVER: none
    # did); delta n is the one after which curve[n] was sampled, so its sim time is curve[n][0]
    first_delta: dict[str, np.ndarray] = field(default_factory=dict)
    sim_time: float = 0.0
    dead: list[str] = field(default_factory=list)
    rejected: int = 0
    applied: int = 0  # distinct deltas in the map
    prior_deltas: int = 0  # of which the previous map's (delta/prior): the starting belief
    #: robots with per-robot figures (first_delta, bytes_shared: 4 bytes per voxel each); on an
    #: open bus anyone can put deltas of invented robots: those are applied but not attributed
    max_robots: int = 0  # 0: the mission's robots, the 64 pattern robots a server may take, the prior
    unattributed: int = 0

    def __post_init__(self) -> None:
        grid, layout = self.mission.workspace.grid(), self.mission.shard_layout()
        self.team = TeamReplica(
            grid, self.mission.sensor.model(), on_applied=self._applied, name="monitor", layout=layout
        )
        self.curve.append((0.0, self.team.entropy_bits))
        self._lock = threading.Lock()
        self.max_robots = self.max_robots or sources_of_deltas(len(self.mission.robot_ids))
        self._peer_log = LogLimiter(log)  # one line per 10 s however many deltas are refused

    @property
    def cmap(self) -> CoverageMap:
        """The team map as the monitor saw it."""
        return self.team.map

    @property
    def entropy(self) -> EntropyCache:
        return self.team.entropy

    def on_delta(self, _key: str, payload: bytes, shard: int = 0) -> None:
        """A ``delta/<rid>`` payload (of map server shard ``shard``: its slab's grid): applied
        once (a resend changes nothing), else refused, counted and logged."""
        try:
            with self._lock:
                self.team.apply_payload(payload, shard)
        except (WireError, ValueError) as exc:
            self.rejected += 1
            self._peer_log.warning("rejected", "monitor: rejected delta: %s", exc)

    def _applied(self, msg: DeltaMessage, idx: np.ndarray, size: int) -> None:
        """After each new delta (under the lock): the curve, and per robot its bytes and first deltas."""
        self.applied += 1
        if msg.robot == PRIOR_SOURCE:  # the previous map: the mission's starting belief
            self.prior_deltas += 1
            self.curve[-1] = (0.0, self.team.entropy_bits)
            return
        self.curve.append((float(msg.t), self.team.entropy_bits))
        first = self.first_delta.get(msg.robot)
        if first is None and len(self.first_delta) < self.max_robots:
            first = self.first_delta[msg.robot] = np.full(self.cmap.grid.size, NEVER, np.int32)
        if first is None:  # an id beyond the bound: in the map, not in the per-robot figures
            self.unattributed += 1
            return
        first[idx] = np.minimum(first[idx], self.applied - self.prior_deltas)
        self.bytes_shared[msg.robot] = self.bytes_shared.get(msg.robot, 0) + size

    def on_truth(self, _key: str, payload: bytes) -> None:
        try:
            truth = TruthPoses.decode(payload)
        except WireError:
            self.rejected += 1
            return
        with self._lock:
            self.sim_time = truth.t
            self.dead = list(truth.dead)
            for rid, (x, y, _yaw) in truth.poses.items():
                self.trajectories.setdefault(rid, []).append((truth.t, float(x), float(y)))

    def on_status(self, key: str, payload: bytes) -> None:
        try:
            status = status_on_key(key, payload)
        except WireError:
            self.rejected += 1
            return
        self.states[status.robot] = status.state

    def first_delta_copy(self) -> dict[str, np.ndarray]:
        """Robot id -> number of the first of its deltas that carried each voxel (NEVER: none)."""
        with self._lock:
            return {r: n.copy() for r, n in self.first_delta.items()}

    @property
    def team_entropy(self) -> float:
        return self.team.entropy_bits
