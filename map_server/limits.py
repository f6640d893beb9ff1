"""How much information a robot can honestly add, derived from its rig and the sensor model
(pure, no I/O); docs/protocol.md, "Bounded information", gives the derivation.

One ray of range d <= max_range R (the agent drops farther points) updates the voxels it
crosses and the one behind its hit, at most ``sqrt(3) d / voxel + 5`` voxels; each gets
``lam = exp(2 excess / tau) / sigma_s(d)^2`` (eq. 14 in information form) with
``excess <= max(d, sqrt(3) voxel)``. Hence one ray adds at most

    I_ray = max over d in [0, R] of (sqrt(3) d / voxel + 5) exp(2 max(d, sqrt(3) voxel) / tau)
            / (sigma_min + zeta d)^2

and one frame at most ``I_frame = width * height * I_ray`` (one ray per pixel). A robot whose
deltas so far span ``[t_lo, t_hi]`` seconds of its clock has taken at most
``floor((t_hi - t_lo) / frame_period) + 1`` frames since the first of them, plus the frames
before it that its first delta may hold and the shutdown flush: ``slack_frames``. The sum of
``dlam`` over every delta of the robot may not exceed ``I_frame`` times that many frames.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from swarm.config import Mission
from swarm.map.sensor_model import SensorModel

#: Frames allowed beyond the span of a robot's deltas (the frames before its first delta
#: and the shutdown flush; the agent shares at its first frame, and flushes once).
SLACK_FRAMES = 20


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
    """The most information one robot's deltas may carry: ``per_frame`` per frame taken, one
    frame every ``frame_period_s`` of its clock, ``slack_frames`` beyond the span of its deltas."""

    per_frame: float
    frame_period_s: float
    slack_frames: int = SLACK_FRAMES

    def allowed(self, span_s: float) -> float:
        """The information of every delta of a robot whose deltas span ``span_s`` seconds
        (infinite when the span in frames overflows a float: ``t`` is the sender's own word,
        and two finite ``t`` far apart span ``inf`` seconds)."""
        frames = max(span_s, 0.0) / self.frame_period_s
        if not math.isfinite(frames):
            return math.inf
        return self.per_frame * (math.floor(frames) + 1 + self.slack_frames)


def mission_bounds(mission: Mission, slack_frames: int = SLACK_FRAMES) -> dict[str, InformationBound]:
    """The information bound of each robot of ``mission`` (its own rig, the mission's sensor
    model, voxel and frame period ``sim.frame_period_s``)."""
    sensor = mission.sensor.model()
    voxel = mission.workspace.grid().voxel
    per_ray = ray_information_bound(sensor, voxel)
    out = {}
    for rid in mission.robot_ids:
        rig = mission.rig_for(rid)
        out[rid] = InformationBound(
            rig.width * rig.height * per_ray, mission.sim.frame_period_s, slack_frames
        )
    return out


@dataclass
class RobotBudget:
    """What one robot has added so far (this server process): the span of its deltas' ``t``
    and the sum of their ``dlam`` (float64)."""

    t_lo: float = math.inf
    t_hi: float = -math.inf
    used: float = 0.0

    def check(self, bound: InformationBound, t: float, information: float) -> str | None:
        """None when a delta at ``t`` carrying ``information`` fits the bound, else why not."""
        lo, hi = min(self.t_lo, t), max(self.t_hi, t)
        allowed = bound.allowed(hi - lo)
        if self.used + information > allowed:
            return (
                f"{information:.3g} of information on top of {self.used:.3g} exceeds the rig's bound "
                f"{allowed:.3g} for deltas spanning {hi - lo:.3g} s"
            )
        return None

    def charge(self, t: float, information: float) -> None:
        self.t_lo, self.t_hi = min(self.t_lo, t), max(self.t_hi, t)
        self.used += information

    def refund(self, information: float) -> None:
        self.used = max(self.used - information, 0.0)
