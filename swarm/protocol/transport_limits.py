"""Zenoh's transport limits set for a robot team (docs/security.md, "Transport limits").

Zenoh 1.10's defaults let a few hundred idle TCP connections keep every new session out: a
link waits up to ``accept_timeout`` (10 s) for its Zenoh handshake, at most
``accept_pending`` (100) links wait at once and any further one is closed at once, so a
stranger who holds 100 connections and reopens each one closed wins nearly every race for a
slot. Every role's session gets the values below, unless its ``--zenoh-config`` file sets
another (a file's own value wins, as for ``transport/link/rx/max_message_size``):

- ``accept_pending`` 2048: more waiting links than one source holds without trying hard (each
  costs the router a socket and a task; the server raises its open-files limit to the hard
  limit at start);
- ``accept_timeout`` 5 s and ``open_timeout`` 5 s: a Zenoh handshake over the team's radio
  takes well under a second; an idle link is dropped twice as fast;
- ``max_sessions``: the sessions a mission's router keeps at once (two per robot, the robots
  ``--robot-pattern`` may add, the coordinator, the world, tools), :func:`max_sessions_for`;
- ``lease`` 5 s (a keep-alive every 1.25 s): a robot gone from the radio is noticed in 5 s;
- a link's queue of data 16 batches (Zenoh's default 2; at most 64 KiB each): the map server
  sends ``merged`` with congestion control DROP, and a link whose queue is full for 1 ms loses
  the sample, so with 2 batches a burst of deltas (robots flushing together, resends after an
  outage) was lost on a busy machine though every subscriber drained; 16 batches (1 MiB a link)
  hold such a burst, and only a subscriber that stops draining loses samples;
- on a listening ``tls/`` endpoint, ``tls_handshake_timeout_ms`` 60 s: Zenoh's TLS listener
  pauses 100 ms after every failed handshake, so N idle connections that time out every T s
  cost it N x 0.1 / T of its time; at 60 s, 300 idle connections take half of it, at Zenoh's
  10 s they took three times all of it and no one else got in.

Zenoh has no per-source connection limit; a firewall gives one (docs/security.md).
"""

from __future__ import annotations

import json

import zenoh

from swarm.protocol.message_size import sources_of_deltas

ACCEPT_PENDING = 2048
ACCEPT_TIMEOUT_MS = 5000
OPEN_TIMEOUT_MS = 5000
LEASE_MS = 5000
#: batches of a link's data queue (Zenoh's default 2)
DATA_QUEUE_BATCHES = 16
TLS_HANDSHAKE_TIMEOUT_MS = 60_000
#: Sessions beside the robots' that a router keeps: coordinator, world, operator, tools, viewers.
OTHER_SESSIONS = 32
HANDSHAKE_OPTION = "tls_handshake_timeout_ms"


def max_sessions_for(robots: int) -> int:
    """The sessions a mission of ``robots`` listed robots needs on its router: an agent and a
    frame source per robot that may send deltas (``sources_of_deltas``) and OTHER_SESSIONS."""
    return 2 * sources_of_deltas(robots) + OTHER_SESSIONS


def team_limits(max_sessions: int) -> dict[str, object]:
    """The limits as ``{config key: value}`` (keys as ``zenoh.Config.insert_json5`` takes them)."""
    return {
        "transport/unicast/accept_pending": ACCEPT_PENDING,
        "transport/unicast/accept_timeout": ACCEPT_TIMEOUT_MS,
        "transport/unicast/open_timeout": OPEN_TIMEOUT_MS,
        "transport/unicast/max_sessions": max_sessions,
        "transport/link/tx/lease": LEASE_MS,
        "transport/link/tx/queue/size/data": DATA_QUEUE_BATCHES,
    }


def apply_team_limits(conf: zenoh.Config, max_sessions: int) -> dict[str, object]:
    """Set each of :func:`team_limits` on ``conf`` unless it holds another value than Zenoh's
    default (a user's file); returns the values in force."""
    defaults = zenoh.Config()
    in_force = {}
    for key, value in team_limits(max_sessions).items():
        current = json.loads(conf.get_json(key))
        if current == json.loads(defaults.get_json(key)):
            conf.insert_json5(key, json.dumps(value))
            current = value
        in_force[key] = current
    return in_force


def with_handshake_timeout(endpoint: str) -> str:
    """A listening ``tls/`` endpoint with ``#tls_handshake_timeout_ms=`` (unless it names one);
    other endpoints unchanged. Zenoh takes this option only on the endpoint itself."""
    if not endpoint.startswith("tls/") or HANDSHAKE_OPTION in endpoint:
        return endpoint
    joiner = ";" if "#" in endpoint else "#"
    return f"{endpoint}{joiner}{HANDSHAKE_OPTION}={TLS_HANDSHAKE_TIMEOUT_MS}"
