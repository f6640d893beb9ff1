"""``swarm bench slowloris``: how long a new honest session takes to open while a stranger holds
hundreds of idle connections to the map server, and right after, over TCP and over mutual TLS.

A ``swarm server`` process listens on loopback (shared memory off, so payloads take the link);
one honest robot publishes a delta every 0.2 s and polls its acks all along. The stranger
opens ``connections`` TCP connections, some idle (they send nothing), some starting a TLS
handshake and stalling (the first bytes of a ClientHello), and reopens each one the server
closes, for ``attack_s`` seconds; then it closes them all. Figures: the time a new session
(a robot's, with its certificate over TLS) takes to open before, during (several tries) and
right after the attack, and the longest gap between two acks of the honest robot.
"""

from __future__ import annotations

import socket
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import yaml

from swarm.bench.durability import MISSION, bench_mission, deltas
from swarm.protocol import bus
from swarm.protocol.epochs import SigningPublisher
from swarm.protocol.map_client import MapClient

#: The first bytes of a TLS ClientHello: a handshake record header that promises 512 bytes.
STALLED_HELLO = b"\x16\x03\x01\x02\x00\x01\x00\x01\xfc\x03\x03"
NO_SHM = "transport/shared_memory/enabled"


@dataclass
class Attack:
    """What one run measured (seconds)."""

    transport: str
    before_s: float = 0.0
    during_s: list[float] = field(default_factory=list)
    after_s: float = 0.0
    longest_ack_gap_s: float = 0.0
    acks: int = 0
    held: int = 0


def _hold(port: int, connections: int, stop: threading.Event, held: list[int]) -> None:
    """Keep ``connections`` open to ``port`` (half idle, half a stalled TLS hello), reopening
    each one the server closes, until ``stop``; then close them all."""
    socks: list[socket.socket | None] = [None] * connections
    while not stop.is_set():
        for i, s in enumerate(socks):
            if s is not None:
                try:
                    closed = s.recv(1, socket.MSG_DONTWAIT) == b""
                except BlockingIOError:
                    closed = False
                except OSError:
                    closed = True
                if not closed:
                    continue
                s.close()
            s = socket.socket()
            try:
                s.settimeout(1.0)
                s.connect(("127.0.0.1", port))
                if i % 2:
                    s.sendall(STALLED_HELLO)
                socks[i] = s
            except OSError:
                s.close()
                socks[i] = None
        held[0] = sum(s is not None for s in socks)
        stop.wait(0.1)
    for s in socks:
        if s is not None:
            s.close()


def _time_to_open(endpoint: str, config: Path | None, limit_s: float) -> float:
    """Seconds a new process takes to open a session (retrying as a robot's process does, its
    start not counted); inf past ``limit_s``. (A process of its own: sessions opened and closed
    beside the honest robot's, in its process, would disturb it.)"""
    cmd = [sys.executable, "-m", "swarm.bench.slowloris", endpoint, str(config or ""), str(limit_s)]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=limit_s + 60)
    return float(done.stdout.strip().splitlines()[-1])


def _open_once(endpoint: str, config: str, limit_s: float) -> float:
    import zenoh

    t0 = time.monotonic()
    while time.monotonic() - t0 < limit_s:
        conf, _, _ = bus.session_config([], [endpoint], config_file=config or None)
        conf.insert_json5(NO_SHM, "false")
        try:
            zenoh.open(conf).close()
            return time.monotonic() - t0
        except zenoh.ZError:
            time.sleep(0.2)
    return float("inf")


def attack(transport: str, connections: int = 300, attack_s: float = 15.0, limit_s: float = 90.0) -> Attack:
    """One run over ``transport`` (``tcp`` or ``tls``); see the module docstring."""
    from swarm.security.team_setup import init_team

    mission = bench_mission()
    out = Attack(transport)
    with tempfile.TemporaryDirectory(prefix="swarm-slowloris-") as tmp:
        tmp = Path(tmp)
        (tmp / "mission.yaml").write_text(yaml.safe_dump(MISSION))
        port = bus.free_port()
        endpoint = f"{transport}/127.0.0.1:{port}"
        server_conf = tmp / "server.json5"
        robot_conf: Path | None = None
        if transport == "tls":
            team = init_team(mission.mission, mission.robot_ids, tmp / "team", hosts=["127.0.0.1"])
            server_conf = team.configs["server"]
            robot_conf = team.configs["agent-r1"]
            text = server_conf.read_text().replace(
                '"transport": {', '"transport": {"shared_memory": {"enabled": false}, ', 1
            )
            server_conf.write_text(text)
        else:
            server_conf.write_text('{"transport": {"shared_memory": {"enabled": false}}}')
        cmd = [sys.executable, "-m", "swarm.cli", "server", "--config", str(tmp / "mission.yaml")]
        cmd += ["--store", str(tmp / "store"), "--listen", endpoint, "--zenoh-config", str(server_conf)]
        log = open(tmp / "server.log", "w")
        proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT)
        try:
            out.before_s = _time_to_open(endpoint, robot_conf, limit_s)
            conf, _, _ = bus.session_config([], [endpoint], config_file=robot_conf)
            conf.insert_json5(NO_SHM, "false")
            import zenoh

            session = zenoh.open(conf)
            try:
                client = MapClient(session, mission.mission, timeout=2.0, endpoint=endpoint)
                pub = SigningPublisher(session, mission.mission, "r1")
                pub.renew()
                payloads = [
                    p for r, _, p in deltas(mission, 400, seed=2, rays=20, epoch=pub.epoch) if r == "r1"
                ]
                stop, held, done = threading.Event(), [0], threading.Event()
                gaps: list[float] = []

                def robot() -> None:  # publishes and polls its acks all through the run
                    last_ack, last_t, n = 0, time.monotonic(), 0
                    while not done.is_set() and n < len(payloads):
                        pub.put(payloads[n])
                        n += 1
                        try:
                            acked = client.acks().get("r1", {})
                            top = max(acked.values(), default=0)
                        except (ConnectionError, ValueError):
                            top = last_ack
                        if top > last_ack:
                            gaps.append(time.monotonic() - last_t)
                            last_ack, last_t = top, time.monotonic()
                        done.wait(0.2)
                    gaps.append(time.monotonic() - last_t)
                    out.acks = last_ack

                # a delta put before the server's subscription is known here is lost, and the
                # server acks the contiguous prefix only: wait for it, as an agent does
                if not bus.wait_for_subscribers([pub], timeout=limit_s):
                    raise ConnectionError(f"no map server subscribed to deltas at {endpoint}")
                robot_thread = threading.Thread(target=robot)
                robot_thread.start()
                holder = threading.Thread(target=_hold, args=(port, connections, stop, held))
                holder.start()
                t_end = time.monotonic() + attack_s
                while time.monotonic() < t_end - 1:
                    time.sleep(min(3.0, max(0.0, t_end - time.monotonic() - 1)))
                    out.during_s.append(_time_to_open(endpoint, robot_conf, limit_s))
                out.held = held[0]
                stop.set()
                holder.join()
                out.after_s = _time_to_open(endpoint, robot_conf, limit_s)
                done.set()
                robot_thread.join()
                out.longest_ack_gap_s = max(gaps, default=0.0)
            finally:
                session.close()
        finally:
            proc.terminate()
            proc.wait(timeout=60)
            log.close()
    return out


def run(connections: int = 300, attack_s: float = 20.0) -> int:
    """Print the figures of a TCP and a TLS run."""
    for transport in ("tcp", "tls"):
        a = attack(transport, connections, attack_s)
        during = ", ".join(f"{t:.2f}" for t in a.during_s)
        print(
            f"{transport}: {a.held} of {connections} connections held; a new session opens in "
            f"{a.before_s:.2f} s before, [{during}] s during, {a.after_s:.2f} s right after; "
            f"honest robot: {a.acks} deltas acked, longest gap between acks {a.longest_ack_gap_s:.2f} s"
        )
    return 0


if __name__ == "__main__":  # one session's opening time, for _time_to_open
    print(_open_once(sys.argv[1], sys.argv[2], float(sys.argv[3])))
