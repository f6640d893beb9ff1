"""How much information a robot can honestly add, derived from its rig and the sensor model
(pure, no I/O); docs/protocol.md, "Bounded information", gives the derivation.

One ray of range d <= max_range R (the agent drops farther points) updates the voxels it
crosses and the one behind its hit, at most ``sqrt(3) d / voxel + 5`` voxels; each gets
``lam = exp(2 excess / tau) / sigma_s(d)^2`` (eq. 14 in information form) with
``excess <= max(d, sqrt(3) voxel)``. Hence one ray adds at most

    I_ray = max over d in [0, R] of (sqrt(3) d / voxel + 5) exp(2 max(d, sqrt(3) voxel) / tau)
            / (sigma_min + zeta d)^2

and one frame at most ``I_frame = width * height * I_ray`` (one ray per pixel). A robot takes one
frame every ``frame_period`` seconds, so it gathers at most ``I_frame / frame_period`` per second.

The budget runs on the server's own clock, never on the sender's ``t``: a token bucket per
robot (:class:`InformationBucket`) refilled at that rate per second of the server's monotonic
clock, holding at most ``rate * burst_s`` (``BURST_S`` by default) and full when the server
starts. A delta's ``sum(dlam)`` is charged when it is admitted (after de-duplication) and given
back when it cannot be made durable; a delta that does not fit is refused.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from swarm.config import Mission
from swarm.map.sensor_model import SensorModel

#: Seconds of the rig's maximum rate a robot's bucket holds. An honest robot's deltas carry a
#: few percent of I_frame per frame (2.6% at most in the office mission), so a full bucket holds
#: the outbox an honest robot gathers in hours of outage, and its resend after a server restart.
BURST_S = 300.0


def ray_information_bound(sensor: SensorModel, voxel: float) -> float:
    """I_ray: the largest sum of lam one ray of range <= sensor.max_range adds (see module doc)."""
    d = np.linspace(0.0, sensor.max_range, 4001)
    excess = np.maximum(d, math.sqrt(3.0) * voxel)
    voxels = math.sqrt(3.0) * d / voxel + 5.0
    lam = np.exp(2.0 * excess / sensor.tau) / (sensor.sigma_min + sensor.zeta * d) ** 2
    # the grid's step in d is far below the functions' scale; 1% covers the sampling
    return float(np.max(voxels * lam)) * 1.01


@dataclass(frozen=True)
class InformationBound:
    """The most information one robot may add: ``per_frame`` per frame, one frame every
    ``frame_period_s``, at most ``burst_s`` seconds' worth at once."""

    per_frame: float
    frame_period_s: float
    burst_s: float = BURST_S

    @property
    def rate(self) -> float:
        """Information per second (the bucket's refill)."""
        return self.per_frame / self.frame_period_s

    @property
    def capacity(self) -> float:
        """The most a full bucket holds: ``rate * burst_s``."""
        return self.rate * self.burst_s


def mission_bounds(mission: Mission, burst_s: float = BURST_S) -> dict[str, InformationBound]:
    """The information bound of each robot of ``mission`` (its own rig, the mission's sensor
    model, voxel and frame period ``sim.frame_period_s``)."""
    sensor = mission.sensor.model()
    voxel = mission.workspace.grid().voxel
    per_ray = ray_information_bound(sensor, voxel)
    out = {}
    for rid in mission.robot_ids:
        rig = mission.rig_for(rid)
        out[rid] = InformationBound(rig.width * rig.height * per_ray, mission.sim.frame_period_s, burst_s)
    return out


class InformationBucket:
    """One robot's token bucket of information; ``now`` is the server's monotonic clock (s)."""

    def __init__(self, bound: InformationBound, now: float) -> None:
        self.bound = bound
        self.tokens = bound.capacity
        self._at = now

    def _refill(self, now: float) -> None:
        if now > self._at:
            self.tokens = min(self.bound.capacity, self.tokens + self.bound.rate * (now - self._at))
            self._at = now

    def refusal(self, information: float, now: float) -> str | None:
        """None when ``information`` fits the bucket now, else why not (nothing is charged)."""
        self._refill(now)
        if information <= self.tokens:
            return None
        return (
            f"{information:.3g} of information over the {self.tokens:.3g} its budget holds now (the rig "
            f"adds at most {self.bound.rate:.3g}/s, {self.bound.capacity:.3g} at once)"
        )

    def charge(self, information: float) -> None:
        self.tokens -= information

    def refund(self, information: float) -> None:
        self.tokens = min(self.bound.capacity, self.tokens + information)
