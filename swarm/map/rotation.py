"""Body orientation from yaw, pitch and roll (the ``ypr`` of poses on the wire)."""

from __future__ import annotations

import math

import numpy as np


def rotation_zyx(yaw: float, pitch: float, roll: float) -> np.ndarray:
    """world_R_body = Rz(yaw) Ry(pitch) Rx(roll): body x forward, y left, z up."""
    cz, sz = math.cos(yaw), math.sin(yaw)
    cy, sy = math.cos(pitch), math.sin(pitch)
    cx, sx = math.cos(roll), math.sin(roll)
    rz = np.array([[cz, -sz, 0.0], [sz, cz, 0.0], [0.0, 0.0, 1.0]])
    ry = np.array([[cy, 0.0, sy], [0.0, 1.0, 0.0], [-sy, 0.0, cy]])
    rx = np.array([[1.0, 0.0, 0.0], [0.0, cx, -sx], [0.0, sx, cx]])
    return rz @ ry @ rx
