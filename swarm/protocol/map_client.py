"""Client side of the map server's queries (``map/stats``, ``map/acks``, ``map/snapshot``,
``map/region``), used by ``swarm map stats|get|export`` and by any role that reads the team map.

``MapClient.connect(endpoints, mission)`` opens its own Zenoh session; ``MapClient(session,
mission)`` borrows one. Every query raises :class:`MapServerUnavailable` (a
``ConnectionError``) naming the endpoint when nothing answers in time, and
:class:`MapQueryError` when the server answers with an error, or when more than one replier
answers and the answers differ (:class:`ConflictingMapReplies`: someone besides the server is
answering; see docs/security.md).
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
import zenoh

from swarm.formats.shown_numbers import shown
from swarm.map.coverage_map import CoverageMap
from swarm.map.sensor_model import SensorModel
from swarm.protocol import bus
from swarm.protocol.map_chunks import REGION_KIND, SNAPSHOT_KIND, WINDOW
from swarm.protocol.map_stream import Progress, StreamFailed, fetch_stream
from swarm.protocol.replies import Answers, ConflictingReplies, ask, ask_all
from swarm.protocol.wire import Region, Snapshot

DEFAULT_TIMEOUT_S = 5.0


class MapServerUnavailable(ConnectionError):
    """No map server answered in time; the text names the key and endpoint."""


#: What a map server's error reply says when it takes no more queries for now (map_server.query_gate).
BUSY = ": busy: "
BUSY_PAUSE_S = 0.2


class MapQueryError(RuntimeError):
    """The map server answered a query with an error, or with a reply that cannot be read."""


class ConflictingMapReplies(MapQueryError):
    """Several repliers answered one map query with different answers; none was taken."""


class MapClient:
    """Queries to the map server of ``mission`` over a Zenoh session."""

    def __init__(
        self,
        session: zenoh.Session,
        mission: str = "default",
        timeout: float = DEFAULT_TIMEOUT_S,
        endpoint: str = "the Zenoh network",
        owns_session: bool = False,
    ) -> None:
        self.session = session
        self.mission = mission
        self.timeout = float(timeout)
        self.endpoint = endpoint
        self._owns = owns_session
        #: chunks asked per query of a streamed answer (each window within ``timeout``)
        self.window = WINDOW

    @classmethod
    def connect(
        cls,
        endpoints: list[str] | None = None,
        mission: str = "default",
        timeout: float = DEFAULT_TIMEOUT_S,
        zenoh_config: str | Path | None = None,
    ) -> MapClient:
        """Open a client session to ``endpoints`` within ``timeout``.

        Without endpoints: the ``zenoh_config`` file's (else ``$ZENOH_CONFIG``'s), else
        tcp/127.0.0.1:7447. Raises ``ValueError`` for a bad config file.
        """
        _conf, _listen, endpoints = bus.session_config([], endpoints, config_file=zenoh_config)
        where = ", ".join(endpoints)
        try:
            session = bus.open_session(connect=endpoints, wait_s=timeout, config_file=zenoh_config)
        except ConnectionError as exc:
            raise MapServerUnavailable(f"no map server reachable at {where} within {timeout:g} s") from exc
        return cls(session, mission, timeout, where, owns_session=True)

    def close(self) -> None:
        if self._owns:
            self.session.close()

    def __enter__(self) -> MapClient:
        return self

    def __exit__(self, *_exc) -> None:
        self.close()

    # -- queries -------------------------------------------------------------------------
    def stats(self) -> dict:
        """The ``map/stats`` JSON object."""
        return self._json("stats")

    def acks(self) -> dict[str, dict[int, int]]:
        """``{robot: {epoch: last contiguous seq}}`` of durable, applied deltas."""
        raw = self._json("acks")
        return {r: {int(e): int(s) for e, s in by_epoch.items()} for r, by_epoch in raw.items()}

    def snapshot(self, progress: Progress | None = None) -> Snapshot:
        """The whole team map (prior included) and the deltas it holds (acks and the seqs above
        them), as one consistent state of the server's map: streamed in chunks
        (``swarm.protocol.map_stream``); ``progress(received, chunks)`` after each chunk."""
        return self._stream("snapshot", SNAPSHOT_KIND, "", progress).snapshot()

    def team_snapshot(self, progress: Progress | None = None) -> Snapshot:
        """The team map's snapshot: :meth:`snapshot` (as ``ShardedMapClient.team_snapshot``)."""
        return self.snapshot(progress)

    def region(self, lo, hi, progress: Progress | None = None) -> Region:
        """Beliefs of the voxels the box [lo, hi] (world metres) touches, streamed in chunks."""
        params = f"lo={_vec(lo)};hi={_vec(hi)}"
        return self._stream("region", REGION_KIND, params, progress).region()

    def point(self, p) -> Region:
        """The belief of the voxel holding point ``p`` (empty outside the grid)."""
        return self.region(p, p)

    # -- plumbing ------------------------------------------------------------------------
    def _json(self, part: str):
        payload = self._get(part)
        try:
            return json.loads(payload)
        except ValueError as exc:
            raise MapQueryError(f"map/{part}: the reply is not JSON: {exc}") from exc

    def _stream(self, part: str, kind: str, first: str, progress: Progress | None):
        """The assembled stream of ``map/<part>`` (each window of chunks within ``timeout``)."""
        try:
            return fetch_stream(lambda params: self._window(part, params), kind, first, self.window, progress)
        except StreamFailed as exc:
            key = bus.key(self.mission, "map", part)
            raise MapQueryError(str(exc) if str(exc).startswith(key) else f"{key}: {exc}") from exc

    def _get(self, part: str, parameters: str = "") -> bytes:
        return self._answered(part, parameters, False).ok

    def _window(self, part: str, parameters: str) -> Answers:
        """The replies to one query of a stream: chunks, or the error (not "busy") to resume from."""
        return self._answered(part, parameters, True)

    def _answered(self, part: str, parameters: str, many: bool):
        key = bus.key(self.mission, "map", part)
        selector = f"{key}?{parameters}" if parameters else key
        deadline = time.monotonic() + self.timeout
        while True:
            # A query that no queryable matches yet (a server still starting, or one whose
            # declarations have not reached this session) ends at once with no reply: ask again.
            left = max(deadline - time.monotonic(), 0.05)
            try:
                answer = ask_all(self.session, selector, left) if many else ask(self.session, selector, left)
            except ConflictingReplies as exc:
                raise ConflictingMapReplies(str(exc)) from exc
            if answer is not None:
                if answer.error is None or (many and answer.ok):
                    return answer
                # the server takes few whole-map queries at once: ask again while time is left
                if BUSY not in str(answer.error) or time.monotonic() + BUSY_PAUSE_S >= deadline:
                    if many:
                        return answer
                    raise MapQueryError(str(answer.error))
                time.sleep(BUSY_PAUSE_S)
                continue
            if time.monotonic() >= deadline:
                break
            time.sleep(0.05)
        raise MapServerUnavailable(
            f"no map server answered {key} at {self.endpoint} within {self.timeout:g} s "
            f"(is 'swarm server' running for mission {self.mission!r}?)"
        )


# -- which mission's server answers --------------------------------------------------------


class MissionMismatch(MapQueryError):
    """A map server answers, but for other missions than the one asked for (both are named)."""


def missions_answering(session: zenoh.Session, timeout: float = DEFAULT_TIMEOUT_S) -> list[str]:
    """Names of the missions whose map server answers ``swarm/*/map/stats`` within ``timeout`` s.

    Asks again until one answers or the time is up (a session just opened may not know the
    servers' queryables yet); returns the sorted names, empty when none answers.
    """
    # an unsharded mission's server, and the shards of sharded ones (docs/sharding.md)
    patterns = (f"{bus.ROOT}/*/map/stats", f"{bus.ROOT}/*/shard/*/map/stats")
    deadline = time.monotonic() + timeout
    while True:
        names = set()
        for pattern in patterns:
            for reply in session.get(pattern, timeout=max(deadline - time.monotonic(), 0.05)):
                if (name := _mission_named(reply)) is not None:
                    names.add(name)
        if names or time.monotonic() >= deadline:
            return sorted(names)
        time.sleep(0.05)


def _mission_named(reply) -> str | None:
    """The mission a ``map/stats`` reply is about: a shard's says so in ``shard.mission``."""
    if reply.ok is None:
        return None
    try:  # the name is in the stats (older servers replied on the query's pattern, not their key)
        stats = json.loads(reply.ok.payload.to_bytes())
        shard = stats.get("shard")
        name = shard.get("mission") if isinstance(shard, dict) else stats.get("mission")
    except (ValueError, AttributeError):
        return None
    return name if isinstance(name, str) and name else None


def resolve_mission(
    session: zenoh.Session, wanted: str | None, timeout: float, endpoint: str, origin: str = "--mission"
) -> str:
    """The mission to query: ``wanted`` if its server answers, else the only one that answers.

    The rule every tool and role follows: the mission name is the config's ``mission`` (or
    ``--mission``); a tool without a config takes the only mission whose server answers.
    Raises :class:`MapServerUnavailable` when no server answers, :class:`MissionMismatch`
    naming both sides when servers answer for other missions only, or for several when
    ``wanted`` is None. ``origin`` says where ``wanted`` came from, for the message.
    """
    names = missions_answering(session, timeout)
    if wanted is not None and wanted in names:
        return wanted
    if not names:
        asked = f"mission {wanted!r}" if wanted else "any mission"
        raise MapServerUnavailable(
            f"no map server answered for {asked} at {endpoint} within {timeout:g} s "
            "(is 'swarm server' running there?)"
        )
    serves = ", ".join(repr(n) for n in names)
    if wanted is not None:
        raise MissionMismatch(
            f"{origin} names mission {wanted!r}, but the map server at {endpoint} serves mission {serves}"
        )
    if len(names) > 1:
        raise MissionMismatch(
            f"map servers of several missions answer at {endpoint}: {serves}; choose one with --mission"
        )
    return names[0]


def _vec(v) -> str:
    v = np.asarray(v, dtype=np.float64).reshape(3)
    return ",".join(repr(float(x)) for x in v)


# -- what the CLI prints and writes ---------------------------------------------------------


def region_rows(region: Region) -> list[dict]:
    """One dict per voxel: index, centre, mu, sigma, expected coverage, entropy."""
    ijk = region.grid.unflat(region.idx)
    centres = region.centres()
    return [
        {
            "index": [int(v) for v in ijk[n]],
            "centre": [shown(v, 6) for v in centres[n]],
            "mu": float(region.mu[n]),
            "sigma": float(region.sigma[n]),
            "expected_coverage": float(region.expected_coverage[n]),
            "entropy_bits": float(region.entropy[n]),
        }
        for n in range(len(region))
    ]


def format_region(region: Region) -> str:
    """A table of the region's voxels."""
    if len(region) == 0:
        return "no voxels: the point or box is outside the map's workspace"
    head = ("i", "j", "k", "x", "y", "z", "mu", "sigma", "E[C]", "H bits")
    widths = (4, 4, 4, 8, 8, 8, 9, 9, 6, 6)
    lines = [" ".join(f"{h:>{w}}" for h, w in zip(head, widths, strict=True))]
    for row in region_rows(region):
        i, j, k = row["index"]
        x, y, z = row["centre"]
        lines.append(
            f"{i:4d} {j:4d} {k:4d} {x:8.3f} {y:8.3f} {z:8.3f} {row['mu']:9.4f} {row['sigma']:9.4g} "
            f"{row['expected_coverage']:6.3f} {row['entropy_bits']:6.3f}"
        )
    return "\n".join(lines)


def sensor_from_stats(stats: dict) -> SensorModel:
    """The server's sensor model (it defines the prior) from ``map/stats``; defaults if absent."""
    values = stats.get("sensor")
    return SensorModel(**values) if isinstance(values, dict) else SensorModel()


def export_map(client: MapClient, out: str | Path, threshold: float = 0.5, **options) -> str:
    """Fetch the team map and write ``out`` (.npz, .ply or .bt; see
    :func:`swarm.formats.map_export.export_coverage_map`, which takes ``options``).
    Returns what was written."""
    from swarm.formats.map_export import SUFFIXES, export_coverage_map

    if Path(out).suffix.lower() not in SUFFIXES:
        raise ValueError(
            f"{out}: the output must end in .npz (map file), .ply (occupied voxels) or .bt (OctoMap)"
        )
    snap = client.team_snapshot()  # a sharded client's: the slabs side by side
    cmap = CoverageMap(snap.grid, sensor_from_stats(client.stats()), snap.lam, snap.eta)
    return export_coverage_map(out, cmap, threshold, **options)
