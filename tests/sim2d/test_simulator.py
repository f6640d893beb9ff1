"""The lockstep simulator over a real Zenoh loopback session (explicit endpoint, scouting off)."""

from __future__ import annotations

import math
import queue
import threading
import time

import pytest

from sim2d.simulator import Simulator
from swarm.config import ConfigError, Mission, mission_from_dict
from swarm.protocol import bus
from swarm.protocol.wire import Cmd, Frame, TruthPoses
from tests.support.paths import CONFIGS


def small_mission(agent_timeout_s: float, r1_rig: dict | None = None) -> Mission:
    data = {
        "mission": "simtest",
        "workspace": {"lo": [0, 0, 0], "hi": [4, 2, 2]},
        "floor_plan": "plans/lab.yaml",
        "robots": [
            {"id": "r1", "start": {"x": 0.6, "y": 1.0, "yaw": 0.0}, "rig": r1_rig},
            {"id": "r2", "start": {"x": 0.6, "y": 0.5, "yaw": 0.0}, "rig": {"mode": "range"}},
        ],
        "rig": {"width": 64, "height": 48},
        "sim": {"dt": 0.1, "frame_period_s": 0.5, "agent_timeout_s": agent_timeout_s},
    }
    return mission_from_dict(data, base_dir=CONFIGS)


class Responder:
    """A stand-in for the agents: answers each frame of the robots in ``answer`` with a command."""

    def __init__(self, session, mission: str, answer: set[str], speed: float = 0.2, tilt=None):
        self.answer = answer
        self.speed = speed
        self.tilt = tilt
        self.gates = {rid: threading.Event() for rid in ("r1", "r2")}
        for gate in self.gates.values():
            gate.set()
        self.frames: queue.Queue = queue.Queue()
        self.truth: queue.Queue = queue.Queue()
        self._todo: queue.Queue = queue.Queue()
        self._pubs = {
            rid: bus.reliable_publisher(session, bus.key(mission, "robot", rid, "cmd")) for rid in self.gates
        }
        self._subs = [
            bus.subscribe(session, bus.key_pattern(mission, "robot", "*", "frame"), self._on_frame),
            bus.subscribe(session, bus.key(mission, "sim", "truth"),
                          lambda _k, p: self.truth.put(TruthPoses.decode(p))),
        ]  # fmt: skip
        self._worker = threading.Thread(target=self._reply, daemon=True)
        self._worker.start()

    def _on_frame(self, _key: str, payload: bytes) -> None:
        frame = Frame.decode(payload)
        self.frames.put(frame)
        self._todo.put(frame)

    def _reply(self) -> None:
        while (frame := self._todo.get()) is not None:
            if frame.robot in self.answer:
                self.gates[frame.robot].wait()
                cmd = Cmd(frame.robot, frame.seq, frame.t, self.speed, 0.0, self.tilt)
                self._pubs[frame.robot].put(cmd.encode())

    def send_raw(self, robot: str, payload: bytes) -> None:
        assert bus.wait_for_subscribers([self._pubs[robot]], timeout=5.0)
        self._pubs[robot].put(payload)

    def close(self) -> None:
        for gate in self.gates.values():
            gate.set()
        self._todo.put(None)
        self._worker.join(timeout=2)
        for sub in self._subs:
            sub.undeclare()


@pytest.fixture
def sessions():
    endpoint = bus.tcp_endpoint(bus.free_port())
    sim_side = bus.open_session(listen=[endpoint])
    agent_side = bus.open_session(connect=[endpoint])
    yield sim_side, agent_side
    agent_side.close()
    sim_side.close()


def test_clock_advances_only_when_every_agent_answered(sessions):
    sim_side, agent_side = sessions
    mission = small_mission(agent_timeout_s=5.0)
    responder = Responder(agent_side, "simtest", {"r1", "r2"})
    sim = Simulator(mission, sim_side)
    try:
        assert sim.wait_for_agents(timeout=5.0) == []
        responder.gates["r1"].clear()  # r1's agent is slow
        done = []
        ticking = threading.Thread(target=lambda: done.append(sim.tick()))
        ticking.start()
        frames = {f.robot: f for f in (responder.frames.get(timeout=5), responder.frames.get(timeout=5))}
        assert frames["r1"].seq == frames["r2"].seq == 1 and frames["r1"].t == 0.0
        assert frames["r1"].left.shape == (48, 64) and frames["r1"].right.shape == (48, 64)
        assert frames["r2"].is_depth and frames["r2"].depth.shape == (48, 64)
        assert frames["r1"].pose.xyz == pytest.approx((0.6, 1.0, 0.4))

        time.sleep(0.4)  # r2 has answered, r1 has not: the clock must wait
        assert ticking.is_alive() and sim.time == 0.0
        assert sim.world.pose("r1")[:2] == pytest.approx((0.6, 1.0))

        responder.gates["r1"].set()
        ticking.join(timeout=5)
        assert not ticking.is_alive() and done == [True]
        assert sim.time == pytest.approx(0.5)
        assert sim.world.pose("r1")[0] == pytest.approx(0.6 + 0.2 * 0.5, abs=0.002)
        truth = responder.truth.get(timeout=5)
        assert truth.t == pytest.approx(0.5) and truth.dead == []
        assert truth.poses["r2"][:2] == pytest.approx(sim.world.pose("r2")[:2])

        assert sim.tick()
        assert sim.seq == 2 and sim.time == pytest.approx(1.0)
        assert not sim.dead and sim.rejected == 0
    finally:
        sim.close()
        responder.close()


@pytest.mark.slow
def test_silent_agent_is_declared_dead_and_the_run_goes_on(sessions):
    sim_side, agent_side = sessions
    timeout = 1.5  # s: long beside a tick's own work, so that a loaded machine cannot blur the two
    mission = small_mission(agent_timeout_s=timeout)
    responder = Responder(agent_side, "simtest", {"r1"})  # r2's agent never answers
    sim = Simulator(mission, sim_side)
    try:
        assert sim.wait_for_agents(timeout=5.0) == []
        responder.send_raw("r1", b"not msgpack")
        start = time.monotonic()
        assert sim.tick()
        assert time.monotonic() - start >= timeout
        assert sim.dead == {"r2"} and sim.live == ["r1"]
        assert sim.rejected == 1

        start = time.monotonic()
        assert sim.tick()  # no more waiting for r2: well under the timeout
        assert time.monotonic() - start < 0.5 * timeout
        assert sim.time == pytest.approx(1.0)
        assert sim.world.pose("r2")[:2] == pytest.approx((0.6, 0.5))  # a dead robot stays put
        truths = [responder.truth.get(timeout=5) for _ in range(2)]
        assert truths[-1].dead == ["r2"]

        responder.answer.add("r2")  # the agent comes back
        for _ in range(3):
            sim.tick()
            if not sim.dead:
                break
        assert not sim.dead

        summary = sim.run(max_ticks=2, startup_timeout=1.0)
        assert summary.ticks == sim.seq and summary.reason == "max_ticks"
        assert summary.distance_m["r1"] > 0.3
    finally:
        sim.close()
        responder.close()


def test_run_stops_when_all_agents_are_dead(sessions):
    sim_side, agent_side = sessions
    mission = small_mission(agent_timeout_s=0.2)
    sim = Simulator(mission, sim_side)
    # agents that take their frames and never answer
    keys = [bus.key("simtest", "robot", r, "frame") for r in ("r1", "r2")]
    mute = [bus.subscribe(agent_side, key, lambda *_: None) for key in keys]
    try:
        summary = sim.run(startup_timeout=5.0)
        assert summary.reason == "all_agents_dead" and summary.ticks == 1
        assert summary.dead == ["r1", "r2"]
    finally:
        for sub in mute:
            sub.undeclare()
        sim.close()


def test_run_does_not_start_when_no_agent_ever_came(sessions):
    sim_side, _ = sessions
    sim = Simulator(small_mission(agent_timeout_s=0.2), sim_side)
    try:
        assert sorted(sim.wait_for_agents(timeout=0.1)) == ["r1", "r2"]  # nobody listens
        summary = sim.run(startup_timeout=0.1)
        assert summary.reason == "no_agents" and summary.ticks == 0 and summary.dead == ["r1", "r2"]
    finally:
        sim.close()


def test_a_robot_without_a_start_pose_is_refused_naming_the_field(sessions):
    """The world places each robot at its start: a mission that leaves one out (real robots'
    missions may) is refused before anything is published, naming the file and the field."""
    sim_side, _ = sessions
    data = small_mission(agent_timeout_s=1.0).model_dump(mode="json")
    data["robots"][1].pop("start")
    mission = mission_from_dict(data, source=CONFIGS / "nostart.yaml", base_dir=CONFIGS)
    with pytest.raises(ConfigError) as err:
        Simulator(mission, sim_side)
    assert str(err.value).startswith(
        f"{CONFIGS / 'nostart.yaml'}: robots[1].start: is required by the simulator"
    )


def test_tilt_head_points_the_camera_within_its_range(sessions):
    sim_side, agent_side = sessions
    mission = small_mission(agent_timeout_s=5.0, r1_rig={"tilt_range_deg": 30.0})
    responder = Responder(agent_side, "simtest", {"r1", "r2"}, speed=0.0, tilt=-1.2)  # 69 deg up
    sim = Simulator(mission, sim_side)
    try:
        assert sim.wait_for_agents(timeout=5.0) == []
        assert sim.tick() and sim.tick()
        frames = [responder.frames.get(timeout=5) for _ in range(4)]
        pitch = {(f.robot, f.seq): f.pose.ypr[1] for f in frames}
        assert pitch[("r1", 1)] == pytest.approx(0.0)  # level until the first command
        assert pitch[("r1", 2)] == pytest.approx(-math.radians(30.0))  # clamped to the head's range
        assert pitch[("r2", 2)] == pytest.approx(0.0)  # r2's rig has no tilt head
    finally:
        sim.close()
        responder.close()
