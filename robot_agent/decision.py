"""What a robot's explorer decides each frame: the drive command, its state and target."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass
class Decision:
    """What the robot does this frame."""

    v: float
    omega: float
    state: str
    target: tuple[float, float] | None = None
    tilt: float | None = None  # camera head tilt (rad, positive down); None: no tilt head
