"""H_th by the observable rule: what no sensor can ever observe, plus a share of the rest.

The paper stops at an absolute 3e4 bits (eq. 36; its run ended at 28,691 bits, 44% of it in
voxels no sensor could reach: an 84% decrease of the rest). An absolute figure, or a share
of the whole prior, means something different on every map: a building with thick walls and
furniture holds more never-observable voxels than an open hall. The observable rule,

    H_th = H_0 * n_unobservable + f * H_0 * n_observable,     f = 0.16 by default,

(H_0 the prior entropy of one voxel) asks the same of every map: an 84% decrease of the
entropy that can be removed, on top of what cannot. The simulator knows which voxels can be
observed (:mod:`sim2d.observability`); this module turns that into the figure and writes it
into the mission, so that every role reads H_th as plain ``stop.entropy_threshold_bits``.
"""

from __future__ import annotations

import time
from dataclasses import asdict, dataclass, replace

import numpy as np

from swarm.config import ConfigError, Mission
from swarm.map.coverage_map import prior_entropy_bits


@dataclass(frozen=True)
class ThresholdParts:
    """The two parts of an observable-rule H_th (bits), and what they count."""

    rule: str  # "observable"
    fraction: float  # f
    prior_bits_per_voxel: float  # H_0
    observable_voxels: int
    unobservable_voxels: int
    unobservable_bits: float  # H_0 * n_unobservable
    observable_prior_bits: float  # H_0 * n_observable
    threshold_bits: float  # unobservable_bits + fraction * observable_prior_bits
    seconds: float  # time spent computing the observable voxels

    def as_dict(self) -> dict:
        return asdict(self)


def observable_mask_of(mission: Mission) -> np.ndarray:
    """Voxels some robot of ``mission`` could ever observe, bool of shape ``grid.shape``.

    The sensor rays of :func:`sim2d.observability.observable_voxels` (reachable poses,
    the rigs' reach), within the workspace box and at or above the floor
    (:func:`swarm.mission.evaluation.observable_mask` of an empty world).
    """
    from sim2d.observability import ObservabilityModel, observable_voxels
    from swarm.mission.evaluation import observable_mask

    grid = mission.workspace.grid()
    plan = mission.load_floor_plan()
    starts = np.array([[p.x, p.y] for p in mission.start_poses()])
    rays = observable_voxels(plan, grid, starts, ObservabilityModel.for_mission(mission))
    box = observable_mask(
        np.zeros(grid.shape, np.float32), grid, (mission.workspace.lo, mission.workspace.hi)
    )
    return rays & box


def threshold_parts(
    mission: Mission, fraction: float, observable: np.ndarray | None = None
) -> ThresholdParts:
    """The observable-rule H_th of ``mission`` with share ``fraction`` of the observable prior.

    ``observable``: a precomputed :func:`observable_mask_of` (computed here when None).
    """
    if not 0.0 <= fraction <= 1.0:
        raise ValueError(f"fraction must be in [0, 1], got {fraction}")
    t0 = time.monotonic()
    if observable is None:
        observable = observable_mask_of(mission)
    grid = mission.workspace.grid()
    h0 = prior_entropy_bits(grid, mission.sensor.model()) / grid.size
    n_obs = int(np.count_nonzero(observable))
    n_unobs = int(grid.size - n_obs)
    return ThresholdParts(
        rule="observable",
        fraction=float(fraction),
        prior_bits_per_voxel=h0,
        observable_voxels=n_obs,
        unobservable_voxels=n_unobs,
        unobservable_bits=h0 * n_unobs,
        observable_prior_bits=h0 * n_obs,
        threshold_bits=h0 * n_unobs + fraction * h0 * n_obs,
        seconds=time.monotonic() - t0,
    )


def resolve_threshold(
    mission: Mission, fraction: float | None = None
) -> tuple[Mission, ThresholdParts | None, np.ndarray | None]:
    """The mission with H_th in bits, its parts and the observable mask (both None when fixed).

    ``fraction`` forces the observable rule with that share (``swarm sim --threshold
    observable``); else the rule applies when the mission sets ``stop.observable_fraction``
    and no ``stop.entropy_threshold_bits``. A mission whose threshold is already in bits is
    returned as it is. Raises ConfigError when the mission has no floor plan to judge by.
    """
    stop = mission.stop
    if fraction is None:
        if stop.entropy_threshold_bits is not None or stop.observable_fraction is None:
            return mission, None, None
        fraction = stop.observable_fraction
    if mission.floor_plan is None:
        raise ConfigError(
            f"{mission.source or '<mission>'}: stop.observable_fraction: the observable rule "
            "needs a floor_plan"
        )
    t0 = time.monotonic()
    observable = observable_mask_of(mission)
    parts = replace(threshold_parts(mission, fraction, observable), seconds=time.monotonic() - t0)
    new_stop = stop.model_copy(
        update={"entropy_threshold_bits": parts.threshold_bits, "observable_fraction": fraction}
    )
    return mission.model_copy(update={"stop": new_stop}), parts, observable
