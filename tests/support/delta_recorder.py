"""A bus observer for multi-host tests: ``python -m tests.support.delta_recorder CONFIG ENDPOINT
ZENOH_CONFIG OUT.npz`` subscribes to every map server shard's ``delta/*`` through ENDPOINT and
applies each delta once (a ``TeamMonitor``: the central fusion of what the robots sent), until
SIGTERM; then it writes the map it holds (lam, eta; the team grid) to OUT.npz."""

from __future__ import annotations

import signal
import sys
import threading

import numpy as np

from swarm.config import load_mission
from swarm.mission.team_monitor import TeamMonitor
from swarm.protocol import bus


def main(config: str, endpoint: str, zenoh_config: str, out: str) -> None:
    mission = load_mission(config)
    layout = mission.shard_layout()
    monitor = TeamMonitor(mission)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    session = bus.open_session(connect=[endpoint], config_file=zenoh_config)
    subs = [
        bus.subscribe(
            session,
            bus.key_pattern(bus.shard_mission(mission.mission, k, layout.count), "delta", "*"),
            lambda key, payload, k=k: monitor.on_delta(key, payload, k),
        )
        for k in range(layout.count)
    ]
    print("recording deltas", flush=True)
    while not stop.wait(0.5):
        print(f"recorded {monitor.applied} deltas", flush=True)
    for sub in subs:
        sub.undeclare()
    np.savez(out, lam=monitor.cmap.lam, eta=monitor.cmap.eta, applied=monitor.applied)
    session.close()
    print(f"wrote {out}: {monitor.applied} deltas", flush=True)


if __name__ == "__main__":
    main(*sys.argv[1:5])
