"""Hearing the end of a mission: a subscriber to ``mission/done`` (the message is
:class:`swarm.protocol.mission_messages.MissionDone`) that calls back once."""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable

import zenoh

from swarm.protocol import bus
from swarm.protocol.mission_messages import MissionDone
from swarm.protocol.wire import WireError

log = logging.getLogger("swarm.mission")


class MissionDoneListener:
    """Calls ``on_done`` with the first well-formed ``mission/done`` of ``mission`` (from a Zenoh
    thread: keep it short, e.g. set an event); malformed ones are logged and counted."""

    def __init__(self, session: zenoh.Session, mission: str, on_done: Callable[[MissionDone], None]) -> None:
        self.on_done = on_done
        self.done: MissionDone | None = None
        self.rejected = 0
        self._lock = threading.Lock()
        self._sub = bus.subscribe(session, bus.key(mission, "mission", "done"), self._on_sample)

    def _on_sample(self, _key: str, payload: bytes) -> None:
        try:
            done = MissionDone.decode(payload)
        except WireError as exc:
            self.rejected += 1
            if self.rejected == 1:
                log.warning("ignored a malformed mission/done: %s", exc)
            return
        with self._lock:
            if self.done is not None:
                return
            self.done = done
        self.on_done(done)

    def close(self) -> None:
        self._sub.undeclare()
