"""The single-robot mission (MISSION, its floor plan PLAN) of the end-to-end tests."""

from __future__ import annotations

PLAN = """
name: tiny
wall_height: 1.0
wall_thickness: 0.1
walls:
  - points: [[-0.05, -0.05], [2.45, -0.05], [2.45, 2.45], [-0.05, 2.45]]
    closed: true
boxes:
  - {centre: [1.7, 1.6], size: [0.4, 0.4], height: 0.6}
"""


# 24 x 24 x 8 voxels, 32,256 bits at first. Turning on the spot at the start brings the
# entropy to about 11,000 bits; 8,000 needs the robot to drive and look behind the box.
MISSION = """
mission: tiny
workspace: {lo: [0.0, 0.0, 0.0], hi: [2.4, 2.4, 0.8], voxel: 0.1}
floor_plan: plan.yaml
robots:
  - id: r1
    start: {x: 0.6, y: 0.6, yaw: 0.0}
rig: {mode: range, camera_height: 0.4, width: 80, height: 60}
stop: {entropy_threshold_bits: 8000, max_time_s: 400}
sim: {agent_timeout_s: 30}
"""
