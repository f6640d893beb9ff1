"""The simulator role on Zenoh: a lockstep clock over the pymunk world and the renderer.

Each tick the simulator publishes one frame per robot on ``robot/<rid>/frame`` (seq 1, 2,
3, ... shared by all robots), then waits until every live agent has answered with a
``robot/<rid>/cmd`` carrying the same seq (or, with ``sim2d.ros2_robots``, each robot's ROS 2
images, CameraInfo and tf, answered by a velocity command stamped with the images' stamp).
Only then does it apply the commands, advance the world by ``sim.frame_period_s`` (in ``sim.dt``
physics steps) and publish the true poses on ``sim/truth``. So runs are reproducible and as fast
as the agents allow. A command's optional ``tilt`` points the robot's camera head (clamped to the rig's
``tilt_range_deg``; a fixed rig stays level) from the next frame on.

An agent that has not answered within ``sim.agent_timeout_s`` (wall clock) is declared
dead: its robot stops and the clock no longer waits for it. Dead robots still get frames;
a dead agent that answers the current or previous frame is alive again from then on.
Agents must answer each seq once and ignore a frame seq they have already processed.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from dataclasses import dataclass, field

import numpy as np
import zenoh

from sim2d.render import Renderer, camera_pose, warm_up_kernels
from sim2d.robot_link import RobotLink, WireRobots
from sim2d.world import World
from swarm.compile_progress import compile_progress
from swarm.config import Mission, RigConfig
from swarm.formats.floor_plan import FloorPlan
from swarm.protocol import bus
from swarm.protocol.wire import Frame, TruthPoses

log = logging.getLogger(__name__)


@dataclass
class SimSummary:
    """What a run did: ticks, sim and wall time, dead agents, distances, rejected messages."""

    ticks: int
    sim_time_s: float
    wall_time_s: float
    reason: str
    dead: list[str] = field(default_factory=list)
    distance_m: dict[str, float] = field(default_factory=dict)
    rejected: int = 0

    @property
    def real_time_factor(self) -> float:
        return self.sim_time_s / self.wall_time_s if self.wall_time_s > 0 else math.inf


class Simulator:
    """Lockstep simulator of a mission's robots, talking Zenoh through ``session``.

    Each robot starts at its ``start`` pose: a mission with a robot without one is refused
    with a ConfigError naming the file and ``robots[i].start`` (``Mission.start_poses``)."""

    def __init__(
        self,
        mission: Mission,
        session: zenoh.Session,
        *,
        encoding: str = "raw8",
        plan: FloorPlan | None = None,
        link: RobotLink | None = None,
    ):
        self.mission = mission
        self.session = session
        self.encoding = encoding
        self.plan = plan if plan is not None else mission.load_floor_plan()
        if self.plan is None:
            raise ValueError("the simulator needs a mission with a floor plan")
        starts = mission.start_poses()  # ConfigError naming robots[i].start when one has none
        body = mission.robot
        self.world = World(self.plan, body.radius, body.max_speed, body.max_turn_rate)
        self.robot_ids = mission.robot_ids
        for rid, start in zip(self.robot_ids, starts, strict=True):
            self.world.add_robot(rid, start.x, start.y, start.yaw)
        self.seq = 0
        self.dead: set[str] = set()
        self._renderers: dict[str, Renderer] = {}
        self._tilt: dict[str, float] = {}  # robot -> camera head tilt (rad) from commands
        self._rngs = {
            rid: np.random.default_rng([mission.sim.seed, i]) for i, rid in enumerate(self.robot_ids)
        }
        self._stop = threading.Event()
        self._stop_reason: str | None = None
        self.progress_every_s = 10.0  # seconds between progress lines of run()
        #: frames out, commands in: our protocol, or each robot's ROS 2 topics
        self.link = link if link is not None else WireRobots(session, mission)
        self._truth_pub = bus.reliable_publisher(session, bus.key(mission.mission, "sim", "truth"))

    # -- state ----------------------------------------------------------------------------
    @property
    def time(self) -> float:
        """Simulated time (s)."""
        return self.world.time

    @property
    def rejected(self) -> int:
        """Commands refused (malformed, of another robot, ahead of the frame)."""
        return self.link.rejected

    @property
    def live(self) -> list[str]:
        return [rid for rid in self.robot_ids if rid not in self.dead]

    def request_stop(self, reason: str = "stopped") -> None:
        """Ask a running loop to stop after the current wait (thread-safe); ``reason`` is the
        summary's (the first asked for)."""
        self._stop_reason = self._stop_reason or reason
        self._stop.set()

    def finished(self) -> str | None:
        """Why the run is over, or None while it goes on."""
        if self._stop.is_set():
            return self._stop_reason or "stopped"
        if self.time >= self.mission.stop.max_time_s - 1e-9:
            return "max_time"
        if not self.live:
            return "all_agents_dead"
        return None

    # -- rendering ----------------------------------------------------------------------
    def renderer(self, rig: RigConfig) -> Renderer:
        """The renderer of a rig (one per distinct rig)."""
        cache_key = rig.model_dump_json()
        if cache_key not in self._renderers:
            self._renderers[cache_key] = Renderer(self.plan, rig.camera(), seed=self.mission.sim.seed)
        return self._renderers[cache_key]

    def make_frame(self, robot_id: str) -> Frame:
        """Render what a robot's rig sees now, as a wire frame with the current seq."""
        rig = self.mission.rig_for(robot_id)
        x, y, yaw = self.world.pose(robot_id)
        pitch = math.radians(rig.pitch_deg) + self._tilt.get(robot_id, 0.0)
        pose = camera_pose(x, y, yaw, rig.camera_height, pitch)
        renderer = self.renderer(rig)
        rng = self._rngs[robot_id]
        frame = Frame(robot_id, self.seq, self.time, pose, renderer.camera, self.encoding)
        if rig.mode == "range":
            frame.depth = renderer.depth_image(pose, rig.range_noise, rig.max_range, rng)
        else:
            frame.left, frame.right = renderer.stereo_pair(pose, rig.noise_std, rng)
        return frame

    def warm_up(self) -> None:
        """Render each robot's first view once, with a throwaway noise generator, so that the
        rendering kernels are loaded (a first run: compiled, with a progress line per kernel)
        before the first frame; the frames the agents get are unchanged by it."""
        with compile_progress(warm_up_kernels(), log.info):
            for rid in self.robot_ids:
                rig = self.mission.rig_for(rid)
                x, y, yaw = self.world.pose(rid)
                pose = camera_pose(x, y, yaw, rig.camera_height, math.radians(rig.pitch_deg))
                rng = np.random.default_rng(0)
                if rig.mode == "range":
                    self.renderer(rig).depth_image(pose, rig.range_noise, rig.max_range, rng)
                else:
                    self.renderer(rig).stereo_pair(pose, rig.noise_std, rng)

    # -- the lockstep loop --------------------------------------------------------------
    def wait_for_agents(self, timeout: float | None = None) -> list[str]:
        """Wait until every robot's frame key has a subscriber; return those still missing."""
        timeout = self.mission.sim.agent_timeout_s if timeout is None else timeout
        deadline = time.monotonic() + timeout
        report = time.monotonic() + self.progress_every_s
        while True:
            missing = self.link.missing()
            if not missing or time.monotonic() >= deadline or self._stop.is_set():
                return missing
            if time.monotonic() >= report:
                log.info("still waiting for the agents of %s", ", ".join(missing))
                report = time.monotonic() + self.progress_every_s
            time.sleep(0.02)

    def tick(self) -> bool:
        """Publish frames, wait for every live agent's command, advance one frame period.

        Returns False once the run is over (stop requested, time limit, all agents dead).
        """
        if self.finished():
            return False
        self.seq += 1
        self.link.publish({rid: self.make_frame(rid) for rid in self.robot_ids}, self.time)
        waiting = set(self.live)
        self._collect(waiting)
        for rid in sorted(waiting):
            if self._stop.is_set():
                break
            log.warning("agent %s did not answer frame %d in %.1f s: declared dead",
                        rid, self.seq, self.mission.sim.agent_timeout_s)  # fmt: skip
            self.dead.add(rid)
            self.world.command(rid, 0.0, 0.0)
        if self._stop.is_set():
            return False
        sim = self.mission.sim
        steps = max(1, round(sim.frame_period_s / sim.dt))
        for _ in range(steps):
            self.world.step(sim.frame_period_s / steps)
        truth = TruthPoses(self.time, self.world.poses(), sorted(self.dead))
        self._truth_pub.put(truth.encode())
        return self.finished() is None

    def _collect(self, waiting: set[str]) -> None:
        """Take commands for the current seq until ``waiting`` is empty or the timeout passes."""
        deadline = time.monotonic() + self.mission.sim.agent_timeout_s
        while waiting and not self._stop.is_set():
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return
            cmd = self.link.take(timeout=min(remaining, 0.1))
            if cmd is None:
                continue
            if cmd.robot in self.dead and cmd.seq >= self.seq - 1:
                log.info("agent %s answered again: alive", cmd.robot)
                self.dead.discard(cmd.robot)
            if cmd.seq == self.seq:
                self.world.command(cmd.robot, cmd.v, cmd.omega)
                if cmd.tilt is not None:
                    limit = math.radians(self.mission.rig_for(cmd.robot).tilt_range_deg)
                    self._tilt[cmd.robot] = min(max(cmd.tilt, -limit), limit)
                waiting.discard(cmd.robot)

    def run(self, max_ticks: int | None = None, startup_timeout: float | None = None) -> SimSummary:
        """Wait for the agents, then tick until the run is over or ``max_ticks`` ticks.

        When no robot's agent has come within ``startup_timeout`` s the run does not start:
        the summary's reason is ``no_agents`` (robots whose agent came only later are declared
        dead at the first frame, and come alive when they answer)."""
        self.warm_up()
        start = time.monotonic()
        wait = self.mission.sim.agent_timeout_s if startup_timeout is None else startup_timeout
        log.info(
            "waiting up to %g s for an agent on each of %s (robots %s)",
            wait,
            self.link.where,
            ", ".join(self.robot_ids),
        )
        missing = self.wait_for_agents(startup_timeout)
        if missing and len(missing) == len(self.robot_ids) and not self._stop.is_set():
            return SimSummary(0, 0.0, time.monotonic() - start, "no_agents", sorted(missing))
        if missing:
            log.warning("no agent subscribed for %s; starting anyway", ", ".join(missing))
        else:
            log.info("every robot's agent is there: running")
        ticks = 0
        report = (time.monotonic(), 0)
        while max_ticks is None or ticks < max_ticks:
            ticks += 1
            if not self.tick():
                break
            now = time.monotonic()
            if now - report[0] >= self.progress_every_s:
                self._log_progress(ticks - report[1], now - report[0])
                report = (now, ticks)
        if ticks > report[1]:  # the last stretch, however short (a run may end within a second)
            self._log_progress(ticks - report[1], time.monotonic() - report[0])
        return SimSummary(
            ticks=self.seq,
            sim_time_s=self.time,
            wall_time_s=time.monotonic() - start,
            reason=self.finished() or "max_ticks",
            dead=sorted(self.dead),
            distance_m={rid: s.distance for rid, s in self.world.robots.items()},
            rejected=self.rejected,
        )

    def _log_progress(self, ticks: int, seconds: float) -> None:
        """One progress line: frames, simulated time, the rate, and who is live or dead."""
        log.info(
            "frame %d, sim t = %.1f s (%.1f frames/s, x%.1f real time); live %s; dead %s; "
            "%d commands rejected",
            self.seq,
            self.time,
            ticks / max(seconds, 1e-9),
            ticks * self.mission.sim.frame_period_s / max(seconds, 1e-9),
            ", ".join(self.live) or "none",
            ", ".join(sorted(self.dead)) or "none",
            self.rejected,
        )

    def close(self) -> None:
        """Undeclare the simulator's publishers and subscribers (the session stays open)."""
        self.link.close()
        self._truth_pub.undeclare()
