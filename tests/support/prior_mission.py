"""The mission that starts from a previous map, shared by the prior-map and secured-mission tests."""

from __future__ import annotations

MISSION = """
mission: prior
workspace: {lo: [0.0, 0.0, 0.0], hi: [2.4, 2.4, 0.8], voxel: 0.1}
prior_map: previous.bt
robots:
  - id: r1
    start: {x: 0.6, y: 0.6, yaw: 0.0}
rig: {mode: range, camera_height: 0.4, width: 40, height: 30}
stop: {max_time_s: 3}
sim: {agent_timeout_s: 30}
"""
