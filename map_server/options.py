"""The map server's options: compaction thresholds, group commits, progress logging and the
limits of docs/protocol.md ("Limits"), with the default bound on a delta's payload size.
"""

from __future__ import annotations

from dataclasses import dataclass

from map_server.admission import QUARANTINE_AFTER
from map_server.epochs import MAX_LIVE_EPOCHS
from map_server.limits import BURST_S
from map_server.query_gate import MAX_QUERIES, MAX_QUERIES_PER_REQUESTER, QUERY_WORKERS
from map_server.snapshot_stream import IDLE_S, MAX_STREAMS, MAX_STREAMS_PER_REQUESTER
from map_server.store import LOG_RESERVE_BYTES
from swarm.config import Mission
from swarm.map.grid import Grid
from swarm.protocol.map_chunks import CHUNK_BYTES
from swarm.protocol.message_size import PATTERN_ROBOTS, frame_bytes, message_limit

#: Robot ids ``--robot-pattern`` admits at most (first come): each costs the server 8 bytes
#: per voxel (its contribution, map_server.contributions), a queue, a budget and ledger rows.
MAX_PATTERN_ROBOTS = PATTERN_ROBOTS


@dataclass(frozen=True)
class ServerOptions:
    """Tuning of the server: compaction thresholds, group-commit size, progress interval, and
    the limits of docs/protocol.md ("Limits"): payload size (None: derived from the grid),
    inbox per robot, which robots may send (None: the mission's), the information bound, and
    the whole-map queries taken on at once (map_server.query_gate), the largest message its
    Zenoh session takes from a link (None: :func:`message_limit_for`), and the room a
    compaction leaves for the log."""

    compact_bytes: int = 256 << 20
    compact_records: int = 20_000
    max_batch: int = 64
    log_every_s: float = 10.0
    fsync: bool = True
    max_payload_bytes: int | None = None
    inbox_messages: int = 256
    inbox_bytes: int | None = None
    robots: tuple[str, ...] | None = None
    robot_pattern: str | None = None
    max_pattern_robots: int = MAX_PATTERN_ROBOTS
    information_bound: bool = True
    #: seconds of the rig's maximum information rate a robot's budget holds (map_server.limits)
    burst_s: float = BURST_S
    #: breaches of the information budget after which a robot is quarantined (0: never)
    quarantine_after: int = QUARANTINE_AFTER
    #: live epochs per robot (map_server.epochs)
    max_epochs: int = MAX_LIVE_EPOCHS
    quarantine: tuple[str, ...] = ()
    max_queries: int = MAX_QUERIES
    max_queries_per_requester: int = MAX_QUERIES_PER_REQUESTER
    query_workers: int = QUERY_WORKERS
    max_message_bytes: int | None = None
    #: streamed answers (map_server.snapshot_stream): voxel bytes per chunk, streams held, of
    #: one requester, their bytes in all (None: 4 copies of the map, at least 64 MiB), idle expiry
    chunk_bytes: int = CHUNK_BYTES
    max_streams: int = MAX_STREAMS
    max_streams_per_requester: int = MAX_STREAMS_PER_REQUESTER
    max_stream_bytes: int | None = None
    stream_idle_s: float = IDLE_S
    #: free bytes a compaction leaves for the log (it is put off otherwise; map_server.store)
    log_reserve_bytes: int = LOG_RESERVE_BYTES


def max_payload_for(grid: Grid) -> int:
    """The default largest delta payload: every voxel once (12 bytes each) plus 64 KiB of fields."""
    return 12 * grid.size + (64 << 10)


def message_limit_for(mission: Mission, options: ServerOptions, max_payload: int) -> int:
    """The largest message (bytes) the server's Zenoh session takes from a link: twice the
    largest it must take (a delta of ``max_payload`` bytes, or a frame of one of the mission's
    rigs that it forwards as the router), at least 64 MiB; ``options.max_message_bytes`` if set."""
    if options.max_message_bytes is not None:
        return options.max_message_bytes
    rigs = (mission.rig_for(rid) for rid in mission.robot_ids)
    return message_limit(max_payload, *(frame_bytes(rig.width, rig.height) for rig in rigs))
