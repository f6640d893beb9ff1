"""The largest message a role may receive from Zenoh, derived from the mission (pure, but for
:func:`bound_received_messages`); docs/protocol.md, "Message sizes".

Zenoh cuts a message larger than a batch (64 KiB) into fragments and the receiving link puts
them together again before anyone sees the message, up to ``transport/link/rx/max_message_size``
bytes: 1 GiB by default. So a stranger who can reach the router could make it hold a gigabyte
per link before the map server's own size check ever ran. The map server and the coordinator
set that bound to twice the largest message the protocol lets them receive, and at least
:data:`MIN_MESSAGE_BYTES`, which any camera frame a driver sends through the router fits in.
"""

from __future__ import annotations

import json

import zenoh

from swarm.map.grid import Grid

#: Zenoh's own default for ``transport/link/rx/max_message_size``; a config file that sets
#: another value keeps it.
ZENOH_DEFAULT_MAX_MESSAGE = 1 << 30
#: The smallest bound set: a 4K camera's f32 depth frame is 33 MB, a 4K stereo pair 17 MB.
MIN_MESSAGE_BYTES = 64 << 20
#: msgpack fields, Zenoh's headers and the key expression around the arrays, generously.
ENVELOPE_BYTES = 64 << 10
#: Seqs the map server keeps above a gap per (robot, epoch), epochs per robot (map_server.ledger),
#: and the msgpack bytes of one seq (a uint64).
_ABOVE_SEQS, _EPOCHS, _SEQ_BYTES = 16384, 4, 9
CONFIG_KEY = "transport/link/rx/max_message_size"
#: Robot ids the map server accepts beyond the mission's by default (``--robot-pattern``,
#: map_server.options.MAX_PATTERN_ROBOTS): each may have acks in a snapshot.
PATTERN_ROBOTS = 64


def sources_of_deltas(listed_robots: int) -> int:
    """How many sources may have deltas on a mission's map: its ``listed_robots``, the
    PATTERN_ROBOTS more a map server may take (``--robot-pattern``) and the previous map
    (``delta/prior``). Replicas track per-robot state for at most this many."""
    return listed_robots + PATTERN_ROBOTS + 1


def delta_bytes(grid: Grid) -> int:
    """The largest delta payload the map server takes by default: every voxel once, 12 bytes each
    (``idx`` uint32, ``dlam`` and ``deta`` float32)."""
    return 12 * grid.size + ENVELOPE_BYTES


def snapshot_bytes(grid: Grid, robots: int) -> int:
    """The largest ``map/snapshot`` reply: ``lam`` and ``eta`` (8 bytes per voxel) and, for each of
    ``robots`` robots, 4 epochs of acks with up to 16,384 seqs each above a gap."""
    return 8 * grid.size + robots * _EPOCHS * (_ABOVE_SEQS * _SEQ_BYTES + 64) + ENVELOPE_BYTES


def frame_bytes(width: int, height: int) -> int:
    """The largest frame of a ``width`` x ``height`` camera: an f32 depth image, or a stereo pair
    (raw8 or PNG, which deflate may make a little larger than raw), whichever is larger."""
    return 4 * width * height + ENVELOPE_BYTES


def message_limit(*largest: int, floor: int = MIN_MESSAGE_BYTES) -> int:
    """Twice the largest of ``largest`` (bytes), and at least ``floor``."""
    return max(floor, 2 * max(largest, default=0))


def bound_received_messages(conf: zenoh.Config, limit: int) -> int:
    """Set ``transport/link/rx/max_message_size`` of ``conf`` to ``limit`` bytes, unless the
    config (a user's file) already sets another value than Zenoh's default; returns the bound
    in force."""
    current = json.loads(conf.get_json(CONFIG_KEY))
    if current != ZENOH_DEFAULT_MAX_MESSAGE:
        return int(current)
    conf.insert_json5(CONFIG_KEY, json.dumps(int(limit)))
    return int(limit)
