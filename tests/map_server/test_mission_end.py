"""The end of a mission without the simulator's runner: the map server decides it (H <= H_th, or
every robot still heard from has nothing left) and announces it on ``mission/done``, over real
loopback Zenoh sessions; the message's wire form; the world that no agent ever came to."""

from __future__ import annotations

import subprocess
import sys
import threading
import time

import pytest

from map_server import mission_end
from map_server.mission_end import MissionEnd
from swarm.protocol import bus
from swarm.protocol.mission_listener import MissionDoneListener
from swarm.protocol.mission_messages import MissionDone
from swarm.protocol.wire import Pose, Status, WireError
from tests.support.paths import ROOT


@pytest.fixture
def sessions():
    endpoint = bus.tcp_endpoint(bus.free_port())
    server = bus.open_session(listen=[endpoint])
    client = bus.open_session(connect=[endpoint])
    yield server, client
    client.close()
    server.close()


def _status(robot: str, state: str) -> bytes:
    return Status(robot, 1.0, Pose((1.0, 2.0, 0.4), (0.0, 0.0, 0.0)), None, state, 0).encode()


def _stats(entropy: float) -> dict:
    return {"entropy_bits": entropy, "known_fraction": 0.5, "deltas_applied": 12}


def _heard(end: MissionEnd, robots: list[str], timeout: float = 5.0) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        done, busy = end.robots_done()
        if set(done) | set(busy) >= set(robots):
            return
        time.sleep(0.02)
    raise AssertionError(f"statuses of {robots} never arrived")


def test_the_team_maps_threshold_ends_the_mission_and_everyone_hears_it(sessions) -> None:
    server, client = sessions
    heard = threading.Event()
    got: list[MissionDone] = []
    listener = MissionDoneListener(client, "m", lambda done: (got.append(done), heard.set()))
    end = MissionEnd(server, "m", frozenset({"r1", "r2"}), threshold_bits=1000.0)
    publisher = bus.reliable_publisher(server, bus.key("m", "mission", "done"))
    assert bus.wait_for_subscribers([publisher], timeout=5.0)
    publisher.undeclare()
    assert end.check(_stats(1000.5)) is None  # above H_th: not done
    done = end.check(_stats(999.0))
    assert done is not None and done.reason == "threshold" and done.entropy_bits == 999.0
    assert heard.wait(5.0)
    assert got[0].reason == "threshold" and got[0].threshold_bits == 1000.0 and got[0].deltas == 12
    assert "H = 999 bits <= H_th 1,000 bits" in got[0].describe()
    # once done, always done, whatever the entropy does later (a flush, a quarantine)
    assert end.check(_stats(5000.0)) is done
    listener.close()
    end.close()


def test_nothing_left_means_every_robot_still_heard_from_is_done(sessions, monkeypatch) -> None:
    server, client = sessions
    end = MissionEnd(server, "m", frozenset({"r1", "r2", "r3", "r4"}), threshold_bits=None)
    r1 = bus.reliable_publisher(client, bus.key("m", "robot", "r1", "status"))
    r2 = bus.reliable_publisher(client, bus.key("m", "robot", "r2", "status"))
    stranger = bus.reliable_publisher(client, bus.key("m", "robot", "x9", "status"))
    assert bus.wait_for_subscribers([r1, r2, stranger], timeout=5.0)
    r1.put(_status("r1", "done"))
    r2.put(_status("r2", "drive"))
    stranger.put(_status("x9", "done"))  # not one of the mission's robots: it decides nothing
    _heard(end, ["r1", "r2"])
    assert end.check(_stats(1e9)) is None  # r2 still explores (r3 and r4 never came: not counted)
    r2.put(_status("r2", "done"))
    deadline = time.monotonic() + 5.0
    while end.check(_stats(1e9)) is None and time.monotonic() < deadline:
        time.sleep(0.05)
    assert end.done is not None and end.done.reason == "nothing left"
    assert end.done.robots_done == ["r1", "r2"] and end.done.threshold_bits is None
    end.close()
    # a robot not heard from for STALE_STATUS_S no longer holds the mission open
    late = MissionEnd(server, "m", frozenset({"r1", "r2"}), threshold_bits=None)
    now = time.monotonic()
    late._states = {"r1": ("done", now), "r2": ("drive", now - mission_end.STALE_STATUS_S - 1)}
    assert late.robots_done(now) == (["r1"], [])
    assert late.check(_stats(1e9)).reason == "nothing left"
    late.close()


def test_the_mission_done_message_round_trips_and_refuses_what_it_does_not_know() -> None:
    done = MissionDone("nothing left", 1.7e9, 12.5, None, 0.25, 3, ["r1"])
    assert MissionDone.decode(done.encode()) == done
    assert "robots done: r1" in done.describe() and "(no H_th)" in done.describe()
    from swarm.protocol.codec import pack

    with pytest.raises(WireError, match="reason must be one of"):
        MissionDone.decode(pack("mission_done", {**_fields(done), "reason": "bored"}))
    with pytest.raises(WireError):
        MissionDone.decode(b"not msgpack")


def _fields(done: MissionDone) -> dict:
    names = ("reason", "t", "entropy_bits", "threshold_bits", "known_fraction", "deltas", "robots_done")
    return {name: getattr(done, name) for name in names}


@pytest.mark.slow
def test_a_world_that_no_agent_comes_to_ends_with_an_error_naming_the_robots(tmp_path) -> None:
    endpoint = bus.tcp_endpoint(bus.free_port())
    lab = ROOT / "configs" / "lab.yaml"
    proc = subprocess.run(
        [sys.executable, "-m", "swarm.cli", "sim", "world", str(lab), "--listen", endpoint,
         "--startup-timeout", "1", "--progress-every", "0.5"],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert "swarm: error: no agent came for any of the robots r1 within 1 s" in proc.stderr, proc.stderr
    assert "swarm/lab/robot/<id>/frame" in proc.stderr and "swarm agent --id ROBOT" in proc.stderr
