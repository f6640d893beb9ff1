"""``swarm bench agent``: time per frame of the agent's stages, stereo, fusion and planning.

Frames are rendered by sim2d from the office mission (a robot in the corridor). Stereo is
OpenCV SGBM plus depth and world points; fusion is one batch into the local map, under both
information models (one measurement per ray; ``weighted``: one per end voxel carrying its
rays' information; ``discretize``: one per end voxel, as OctoMap);
planning is a traversability grid from the map, a Dijkstra cost map and one path.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np

from robot_agent.stereo import matcher_for_rig, points_from_depth
from sim2d.render import Renderer, camera_pose
from swarm.bench import best_cpu_seconds, best_seconds, timed_seconds
from swarm.config import load_mission
from swarm.map.coverage_map import CoverageMap
from swarm.map.fusion import batch_information
from swarm.navigation.planner import GridPlanner, nearest_free_cell
from swarm.navigation.traversability import build_traversability


def look_around_map(mission, rid: str, views: int = 16) -> CoverageMap:
    """The map a robot builds turning once on the spot at its start (range frames, 160x120)."""
    start = mission.start_of(rid)  # the bench renders at the robot's start
    rig = mission.rig_for(rid)
    camera = rig.model_copy(update={"width": 160, "height": 120}).camera()
    renderer = Renderer(mission.load_floor_plan(), camera, seed=0)
    cmap = CoverageMap(mission.workspace.grid(), mission.sensor.model())
    for yaw in start.yaw + np.linspace(0, 2 * math.pi, views, endpoint=False):
        pose = camera_pose(start.x, start.y, yaw, rig.camera_height)
        depth = renderer.depth_image(pose, 0.0, None, np.random.default_rng(0))
        points = points_from_depth(depth, camera.fx, camera.fy, camera.cx, camera.cy, pose.xyz, pose.ypr, 5.0)
        cmap.integrate(np.asarray(pose.xyz), points)
    return cmap


def measure(mission, rid: str, width: int, height: int, repeat: int) -> dict:
    """Seconds per frame of each stage at one image size, best of ``repeat``."""
    start = mission.start_of(rid)  # the bench renders at the robot's start
    rig = mission.rig_for(rid).model_copy(update={"width": width, "height": height, "mode": "stereo"})
    camera = rig.camera()
    renderer = Renderer(mission.load_floor_plan(), camera, seed=0)
    pose = camera_pose(start.x, start.y, start.yaw, rig.camera_height, math.radians(rig.pitch_deg))
    left, right = renderer.stereo_pair(pose)
    matcher = matcher_for_rig(rig)
    max_range = mission.sensor.max_range

    def stereo() -> np.ndarray:
        depth = matcher.depth(left, right, camera)
        return points_from_depth(
            depth, camera.fx, camera.fy, camera.cx, camera.cy, pose.xyz, pose.ypr, max_range
        )

    points = stereo()
    cmap = look_around_map(mission, rid)
    origin = np.asarray(pose.xyz)
    # the agent's sensor model at this size (information model and the rig's hit range), and the three models
    default = mission.sensor_model_of(rig)
    per_ray = replace(default, discretize=False, weighted=False)
    weighted = replace(default, discretize=True, weighted=True)
    per_voxel = replace(default, discretize=True, weighted=False)

    def fuse(sensor, cloud: np.ndarray = points) -> None:
        cmap.apply(batch_information(cmap.grid, sensor, origin, cloud).delta)

    def plan() -> None:
        trav = build_traversability(cmap, robot_radius=mission.robot.radius, swept=origin[None, :2])
        cell = nearest_free_cell(trav, tuple(int(c) for c in trav.cell_of(origin[:2])))
        planner = GridPlanner(trav)
        cost = planner.cost_map(cell)
        reachable = np.argwhere(np.isfinite(cost))
        goal = trav.centre(reachable[np.argmax(cost[np.isfinite(cost)])])  # the farthest reachable cell
        planner.plan(trav.centre(np.array(cell)), goal)

    def frame() -> None:
        fuse(default, stereo())
        plan()

    return {
        "size": f"{width}x{height}",
        "disparities": matcher.num_disparities,
        "default_model": model_name(default),
        "frame_s": best_seconds(frame, repeat),
        "points": len(points),
        "stereo_s": best_seconds(stereo, repeat),
        # (best, median) wall seconds
        "fusion_s": timed_seconds(lambda: fuse(per_ray), repeat),
        "weighted_fusion_s": timed_seconds(lambda: fuse(weighted), repeat),
        "discretized_fusion_s": timed_seconds(lambda: fuse(per_voxel), repeat),
        "measurements": batch_information(cmap.grid, per_voxel, origin, points).measurements,
        "planning_s": timed_seconds(plan, repeat),
        "fusion_cpu_s": best_cpu_seconds(lambda: fuse(per_ray), repeat),
        "weighted_fusion_cpu_s": best_cpu_seconds(lambda: fuse(weighted), repeat),
        "discretized_fusion_cpu_s": best_cpu_seconds(lambda: fuse(per_voxel), repeat),
        "planning_cpu_s": best_cpu_seconds(plan, repeat),
        "voxels": cmap.grid.size,
    }


def model_name(sensor) -> str:
    """The information model of ``sensor`` as the table names it."""
    if not sensor.discretize:
        return "one per ray"
    return "weighted" if sensor.weighted else "discretize"


def run(config: Path, sizes: list[tuple[int, int]], repeat: int = 5) -> list[dict]:
    """Per-stage seconds per frame for each image size, on the first robot of ``config``."""
    mission = load_mission(config)
    return [measure(mission, mission.robot_ids[0], w, h, repeat) for w, h in sizes]


_MODELS = ("fusion", "weighted_fusion", "discretized_fusion")  # one per ray, weighted, discretize


def format_table(rows: list[dict]) -> str:
    lines = [
        "| image | points | stereo ms | fusion ms, one per ray | us/ray | fusion ms, weighted "
        "| fusion ms, discretize | end voxels | planning ms | fusion + planning ms, per ray "
        "| fusion + planning ms, weighted | fusion + planning ms, discretize | map voxels | disparities "
        "| whole frame ms (default model) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        keys = [*_MODELS, "planning"]
        wall = [r[f"{k}_s"][0] * 1e3 for k in keys]
        median = [r[f"{k}_s"][1] * 1e3 for k in keys]
        cpu = [r[f"{k}_cpu_s"] * 1e3 for k in keys]
        cells = [f"{w:.1f} / {m:.1f} ({c:.1f})" for w, m, c in zip(wall, median, cpu, strict=True)]
        totals = [
            f"{wall[i] + wall[3]:.1f} / {median[i] + median[3]:.1f} ({cpu[i] + cpu[3]:.1f})" for i in range(3)
        ]
        lines.append(
            f"| {r['size']} | {r['points']:,} | {r['stereo_s'] * 1e3:.1f} | {cells[0]} "
            f"| {cpu[0] * 1e3 / max(r['points'], 1):.3f} | {cells[1]} | {cells[2]} | {r['measurements']:,} "
            f"| {cells[3]} | {totals[0]} | {totals[1]} | {totals[2]} | {r['voxels']:,} | {r['disparities']} "
            f"| {r['frame_s'] * 1e3:.1f} ({r['default_model']}) |"
        )
    lines.append(
        "\nms: best / median wall time of the repeats (in parentheses: best CPU time of the thread, which "
        "a shared machine disturbs less; totals add the stages' figures); us/ray from the CPU time. "
        "Models: one measurement per ray; weighted: one per end voxel with its rays' information; "
        "discretize: one per end voxel (OctoMap's). Whole frame: stereo, fusion with the agent's "
        "default information model at that size (sensor.discretize: auto) and planning, timed as one call."
    )
    return "\n".join(lines)
