"""A mission that starts from a previous map (``prior_map:`` in the mission file).

The paper's initial belief p(c | M0) is the uninformative prior "unless there is a previous
map of the environment" (section II.C.1). A previous map is a ``map.npz`` (from
``swarm map import map.bt`` or an earlier run) or an OctoMap ``.bt`` read directly (with the
beliefs of :mod:`swarm.formats.octomap_map`).

Resampling: each voxel of the mission grid takes the belief of the previous map's voxel
that holds its centre (nearest-centre lookup); voxels outside the previous map, or still at
its prior, keep the mission's prior. Coarser mission voxels thus sample one fine voxel each.

The belief enters the mission as information: a voxel given N(mu_p, sigma_p) gets
(1/sigma_p^2 - lam0, mu_p/sigma_p^2 - eta0) added to the mission prior (lam0, eta0), so it
ends at exactly N(mu_p, sigma_p). The runner publishes it as ``delta/prior`` deltas before
any robot starts, so the map server, the agents and any monitor hold it as they hold the
robots' information.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from swarm.formats.errors import InputError
from swarm.map.coverage_map import CoverageMap, prior_information
from swarm.map.delta import Delta
from swarm.map.grid import Grid
from swarm.map.sensor_model import SensorModel

#: the robot id of the deltas that carry a previous map
PRIOR_SOURCE = "prior"
#: voxels per ``delta/prior`` message
CHUNK_VOXELS = 250_000


class PriorMapError(InputError):
    """A previous map that cannot be used; names the file."""


def load_previous_map(path: str | Path, sensor: SensorModel | None = None) -> CoverageMap:
    """A previous map from a ``.npz`` map file or an OctoMap ``.bt`` / ``.ot``; raises PriorMapError."""
    from swarm.formats.map_file import MapFileError, load_map
    from swarm.formats.octomap_file import OctomapFileError, read_octree
    from swarm.formats.octomap_map import leaves_to_states, states_to_prior

    path = Path(path)
    if not path.exists():
        raise PriorMapError(f"{path}: no such file")
    try:
        if path.suffix.lower() in (".bt", ".ot"):
            grid, states = leaves_to_states(read_octree(path))
            return states_to_prior(grid, states, sensor)
        return load_map(path)
    except (MapFileError, OctomapFileError, ValueError) as exc:
        raise PriorMapError(f"{path}: {exc}" if str(path) not in str(exc) else str(exc)) from exc


def prior_delta(grid: Grid, sensor: SensorModel, previous: CoverageMap) -> Delta:
    """The information that takes the mission prior on ``grid`` to ``previous``'s beliefs.

    Only voxels where the previous map knows more than the mission prior contribute.
    """
    lam0, eta0 = prior_information(sensor)
    centres = grid.centres().reshape(-1, 3)
    src = previous.grid.index_of(centres)
    inside = np.flatnonzero(previous.grid.contains_index(src))
    src_flat = previous.grid.flat(src[inside])
    lam = previous.lam[src_flat].astype(np.float64)
    eta = previous.eta[src_flat].astype(np.float64)
    useful = (lam > lam0 * (1.0 + 1e-5)) & previous.known_mask()[src_flat]
    idx = inside[useful]
    dlam = lam[useful] - lam0
    deta = eta[useful] - eta0
    return Delta(idx.astype(np.uint32), dlam.astype(np.float32), deta.astype(np.float32))


def chunks(delta: Delta, size: int = CHUNK_VOXELS) -> list[Delta]:
    """The delta cut into pieces of at most ``size`` voxels (messages of bounded size)."""
    return [
        Delta(delta.idx[a : a + size], delta.dlam[a : a + size], delta.deta[a : a + size])
        for a in range(0, len(delta), size)
    ]
