"""The roles run by hand, as on real robots: real `swarm` processes
over real Zenoh loopback sessions, against a map server of the lab mission.

Each role says where it connects and what it waits for (endpoint, key), reports progress
periodically, prints its final figures after its shutdown flush, and a role or tool whose
mission is not the server's stops with an error naming both missions.
"""

from __future__ import annotations

import os
import queue
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import yaml

from swarm.config import load_mission
from tests.support.map_server_mission import running_server
from tests.support.paths import ROOT

pytestmark = pytest.mark.slow  # whole missions: every role a process

LAB = ROOT / "configs" / "lab.yaml"


class Role:
    """A `swarm` process whose output lines are collected as they come."""

    def __init__(self, *args: str) -> None:
        env = {**os.environ, "PYTHONUNBUFFERED": "1", "PYTHONPATH": str(ROOT)}
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "swarm.cli", *args],
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            env=env,
            cwd=ROOT,
        )
        self.lines: list[str] = []
        self._new: queue.Queue = queue.Queue()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        for line in self.proc.stdout:
            self.lines.append(line.rstrip("\n"))
            self._new.put(line)

    @property
    def text(self) -> str:
        return "\n".join(self.lines)

    def wait_for(self, words: str, timeout: float = 120.0) -> str:
        """The first line holding ``words`` (waiting for it up to ``timeout`` s)."""
        deadline = time.monotonic() + timeout
        while True:
            for line in self.lines:
                if words in line:
                    return line
            if self.proc.poll() is not None and self._new.empty():
                time.sleep(0.2)  # let the reader take the last lines
                found = [line for line in self.lines if words in line]
                assert found, f"exited {self.proc.returncode} without {words!r}:\n{self.text}"
                return found[0]
            assert time.monotonic() < deadline, f"no {words!r} within {timeout} s:\n{self.text}"
            try:
                self._new.get(timeout=0.5)
            except queue.Empty:
                pass

    def stop(self, timeout: float = 60.0) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
        try:
            code = self.proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            raise
        time.sleep(0.2)
        return code

    def finish(self, timeout: float = 120.0) -> int:
        try:
            return self.proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            pytest.fail(f"still running after {timeout} s:\n{self.text}")


@pytest.fixture(scope="module")
def lab_server(tmp_path_factory):
    """A map server of the lab mission on a free loopback port (the endpoint)."""
    store = tmp_path_factory.mktemp("lab") / "store"
    with running_server(load_mission(LAB), store) as (_server, endpoint):
        yield endpoint


def other_mission_config(folder: Path, name: str) -> Path:
    """The lab mission under another name (its floor plan path made absolute)."""
    data = yaml.safe_load(LAB.read_text())
    data["mission"] = name
    data["floor_plan"] = str(LAB.parent / data["floor_plan"])
    path = folder / f"{name}.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def test_world_and_agent_by_hand_say_what_they_wait_for_and_report_progress(lab_server, capsys):
    endpoint = lab_server
    world = Role("sim", "world", str(LAB), "--connect", endpoint, "--max-ticks", "24",
                 "--progress-every", "1")  # fmt: skip
    agent = None
    try:
        assert endpoint in world.wait_for("connecting to")
        world.wait_for("waiting up to 120 s for an agent on each of swarm/lab/robot/<id>/frame (robots r1)")
        agent = Role("agent", "--id", "r1", "--config", str(LAB), "--connect", endpoint,
                     "--coordination", "none", "--progress-every", "1")  # fmt: skip
        world.wait_for("still waiting for the agents of r1")
        assert endpoint in agent.wait_for("r1: connecting to")
        agent.wait_for("r1: waiting for frames on swarm/lab/robot/r1/frame")
        assert world.finish() == 0, world.text
        assert "max_ticks: 24 frames" in world.text and "frame " in world.wait_for("frames/s")
        progress = agent.wait_for("frames fused")
        assert (
            "deltas sent" in progress and "acked by the map server" in progress and "map entropy" in progress
        )
        # case 7: the map tools find the server's mission (lab) without being told
        from swarm import cli

        assert cli.main(["map", "stats", "--connect", endpoint, "--timeout", "20"]) == 0
        assert capsys.readouterr().out.startswith("mission lab: ")
    finally:
        world.stop()
        if agent is not None:
            assert agent.stop() == 0, agent.text
    flush = agent.wait_for("r1: shutdown flush:")
    final = agent.wait_for("r1: final, after the shutdown flush:")
    assert "24 frames fused" in final, final
    assert agent.lines.index(final) > agent.lines.index(flush)


def test_agent_of_another_mission_stops_naming_both(lab_server, tmp_path: Path):
    config = other_mission_config(tmp_path, "elsewhere")
    agent = Role(
        "agent", "--id", "r1", "--config", str(config), "--connect", lab_server, "--coordination", "none"
    )
    code = agent.finish()
    assert code == 2, agent.text
    line = agent.wait_for("swarm: error:")
    assert f"{config}: mission:" in line and "'elsewhere'" in line and "'lab'" in line


def test_coordinator_waits_reports_and_refuses_another_mission(lab_server, tmp_path: Path):
    coordinator = Role("coordinator", "--config", str(LAB), "--connect", lab_server, "--progress-every", "1")
    try:
        assert lab_server in coordinator.wait_for("connecting to")
        coordinator.wait_for("connected; mission 'lab'")  # as an agent says it, before the slow start
        assert "swarm/lab/coord/assign" in coordinator.wait_for("waiting for requests on")
        coordinator.wait_for("assign requests answered")
    finally:
        assert coordinator.stop() == 0, coordinator.text
    assert "team map" in coordinator.wait_for("coordinator: final:")
    other = Role("coordinator", "--config", str(LAB), "--connect", lab_server, "--mission", "elsewhere",
                 "--snapshot-timeout", "1")  # fmt: skip
    assert other.finish() == 2, other.text
    line = other.wait_for("swarm: error:")
    assert "--mission" in line and "'elsewhere'" in line and "'lab'" in line


def test_a_team_without_start_poses_by_hand_takes_the_poses_from_the_frames(tmp_path: Path):
    """configs/office_robots.yaml gives no start poses (real robots): a map server, `swarm
    coordinator` and `swarm agent` run it, the test is r2's driver. The agent answers every
    frame, tells the team the pose of the frame it answered, and its deltas reach the server."""
    import math

    import numpy as np

    from swarm.protocol import bus
    from swarm.protocol.wire import Camera, Cmd, Frame, Pose, Status

    config = ROOT / "configs" / "office_robots.yaml"
    mission = load_mission(config)
    assert all(r.start is None for r in mission.robots)
    rig = mission.rig_for("r2")
    camera = Camera(
        rig.width, rig.height, rig.fx, rig.fx, (rig.width - 1) / 2, (rig.height - 1) / 2, rig.baseline
    )
    depth = np.full((rig.height, rig.width), 2.0, np.float32)
    with running_server(mission, tmp_path / "store") as (server, endpoint):
        coordinator = Role("coordinator", "--config", str(config), "--connect", endpoint)
        agent = Role("agent", "--id", "r2", "--config", str(config), "--connect", endpoint,
                     "--progress-every", "1")  # fmt: skip
        driver = bus.open_session(connect=[endpoint])
        try:
            coordinator.wait_for("waiting for requests on swarm/office_robots/coord/assign")
            agent.wait_for("r2: waiting for frames on swarm/office_robots/robot/r2/frame")
            cmd_sub, commands = bus.subscribe_queue(driver, bus.key("office_robots", "robot", "r2", "cmd"))
            status_sub, statuses = bus.subscribe_queue(
                driver, bus.key("office_robots", "robot", "r2", "status")
            )
            frames = bus.reliable_publisher(driver, bus.key("office_robots", "robot", "r2", "frame"))
            assert bus.wait_for_subscribers([frames], timeout=10.0)
            x, y, yaw, sent = 11.0, 7.0, 1.0, {}  # anywhere in the workspace: no start to agree with
            for seq in range(1, 21):
                t = 0.5 * seq
                pose = Pose((x, y, rig.camera_height), (yaw, 0.0, 0.0))
                sent[t] = pose
                frames.put(Frame("r2", seq, t, pose, camera, depth=depth).encode())
                cmd = Cmd.decode(commands.get(timeout=30.0)[1])
                assert cmd.seq == seq, (cmd, seq)
                yaw += 0.5 * cmd.omega  # the driver's robot moves as told for one frame period
                x, y = x + 0.5 * cmd.v * math.cos(yaw), y + 0.5 * cmd.v * math.sin(yaw)
            told = [Status.decode(statuses.get(timeout=10.0)[1]) for _ in range(20)]
            assert [s.pose for s in told] == [sent[s.t] for s in told]
            cmd_sub.undeclare()
            status_sub.undeclare()
        finally:
            driver.close()
            assert agent.stop() == 0, agent.text
            assert coordinator.stop() == 0, coordinator.text
        final = agent.wait_for("r2: final, after the shutdown flush:")
        assert "20 frames fused" in final, final
        # the coordinator answered it, from the poses its statuses carry (no start to begin from)
        assert re.search(r"coordinator \{[^}]*'(assigned|nothing_left)'", final), final
        assert server.team.stats()["robots"]["r2"]["deltas"] > 0, server.team.stats()
