"""What a map server starts from: the team map, the ledger and the epochs its store holds
(docs/protocol.md, "Store layout"): the snapshot's map, ledger, contributions and counters,
then the log's deltas replayed (they were checked when they were logged: epochs, MACs,
budgets), then ``epochs.json``.
"""

from __future__ import annotations

import logging

from map_server.contributions import Contributions
from map_server.epochs import EpochFileError, EpochRegistry
from map_server.ledger import Ledger, Rejected, validate_delta
from map_server.store import Recovered, Store
from map_server.store_files import StoreFiles
from map_server.team_map import MergedMap
from map_server.wal_file import StoreError
from swarm.map.grid import Grid
from swarm.map.sensor_model import SensorModel
from swarm.protocol.codec import DELTA_VERSION

log = logging.getLogger("swarm.server")


def recover(
    store: Store,
    recovered: Recovered,
    grid: Grid,
    sensor: SensorModel,
    max_epochs: int,
    files: StoreFiles,
) -> tuple[MergedMap, EpochRegistry, tuple[int, int, int]]:
    """The team map and the epoch registry of ``store``, and (deltas from the snapshot, deltas
    replayed from the log, torn bytes cut). Raises StoreError for unreadable contents."""
    ledger = Ledger.from_json(recovered.ledger_json)
    ledger.restore_compaction(recovered.counters.get("ledger", {}))
    try:
        contributions = Contributions.from_arrays(recovered.arrays, grid.size)
    except ValueError as exc:
        raise StoreError(f"{store.path}: snapshot contributions unreadable: {exc}") from exc
    team = MergedMap(
        grid,
        sensor,
        recovered.lam,
        recovered.eta,
        ledger,
        contributions=contributions,
        quarantined=recovered.counters.get("quarantined", []),
    )
    if team.repaired:
        log.error("%d voxels of the stored map held impossible values: reset to the prior", team.repaired)
    team.updates.update(recovered.counters.get("updates", {}))
    from_snapshot = len(team.ledger)
    for payload in recovered.wal_payloads:  # a store written before v2 holds v1 deltas
        try:
            msg = validate_delta(payload, grid, increments=False, versions=(1, DELTA_VERSION))
            if team.admit(msg):
                team.apply(msg)
        except Rejected as exc:
            log.warning("WAL record refused on replay (%s): %s", exc.kind, exc)
    team.duplicates = 0
    team.rejected.clear()
    try:
        registry = EpochRegistry.load(
            store.path,
            files,
            max_epochs,
            used=team.ledger.used(),
            counters=recovered.counters.get("epochs", {}),
        )
    except EpochFileError as exc:
        raise StoreError(str(exc)) from exc
    return team, registry, (from_snapshot, len(team.ledger) - from_snapshot, recovered.torn_bytes)
