"""Streams of ray batches for the map benchmarks: what robots' sensors would deliver, frame by frame.

- ``office_frames``: range-camera frames (sim2d's renderer, the mission's rig and noise) from
  poses that cover a mission's free floor, every ``spacing`` metres, four headings in turn;
- ``campus_plan`` and ``street_frames``: a 200 m x 100 m campus (building blocks between
  streets) and the frames of robots driving its streets, interleaved in time as a team's;
- ``euroc_frames``: the real stereo clouds of the EuRoC excerpt placed with its ground-truth
  camera poses.

A frame is (sensor origin (3,), world points (N, 3)), metres.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from robot_agent.stereo import points_from_depth
from sim2d.render import Renderer, camera_pose
from swarm.formats.floor_plan import FloorPlan
from swarm.streams.poses import quaternion_matrix

Frame = tuple[np.ndarray, np.ndarray]
#: Range noise of the rendered frames (std per metre of depth), as a mission's range camera.
NOISE_PER_M = 0.01


def free_floor(plan: FloorPlan, spacing: float, clearance: float) -> np.ndarray:
    """(N, 2) points of a ``spacing`` lattice over the plan's floor whose disc of ``clearance``
    (sampled at 8 points and the centre) is free of obstacles, in boustrophedon order."""
    xs = np.arange(plan.lo[0] + spacing / 2, plan.hi[0], spacing)
    ys = np.arange(plan.lo[1] + spacing / 2, plan.hi[1], spacing)
    gx, gy = np.meshgrid(xs, ys, indexing="ij")
    gy[1::2] = gy[1::2, ::-1]  # every other column walked backwards
    points = np.stack([gx.ravel(), gy.ravel()], axis=-1)
    angles = np.linspace(0, 2 * math.pi, 8, endpoint=False)
    ring = np.concatenate([[[0.0, 0.0]], clearance * np.stack([np.cos(angles), np.sin(angles)], axis=-1)])
    heights = plan.height_at(points[:, None, :] + ring[None, :, :])
    return points[np.all(heights == 0, axis=1)]


def render_frames(
    renderer: Renderer, rig, poses: list[tuple[float, float, float]], seed: int = 0
) -> list[Frame]:
    """Range frames of ``rig`` (a RigConfig) at floor poses (x, y, yaw), with range noise."""
    camera = renderer.camera
    rng = np.random.default_rng(seed)
    frames = []
    for x, y, yaw in poses:
        pose = camera_pose(x, y, yaw, rig.camera_height)
        depth = renderer.depth_image(pose, NOISE_PER_M, None, rng)
        points = points_from_depth(depth, camera.fx, camera.fy, camera.cx, camera.cy, pose.xyz, pose.ypr)
        frames.append((np.asarray(pose.xyz, dtype=np.float64), points))
    return frames


def office_frames(mission, spacing: float = 1.0) -> list[Frame]:
    """Frames of the mission's first robot's rig (as a range camera) over the mission's free floor."""
    rig = mission.rig_for(mission.robot_ids[0])
    plan = mission.load_floor_plan()
    floor = free_floor(plan, spacing, mission.robot.radius + 0.1)
    yaws = (np.arange(len(floor)) % 4) * (math.pi / 2)
    renderer = Renderer(plan, rig.camera(), seed=0, threads=1)
    return render_frames(renderer, rig, [(x, y, yaw) for (x, y), yaw in zip(floor, yaws, strict=True)])


# -- the campus ---------------------------------------------------------------------------
#: Campus layout: building blocks of BUILDING m a side on a PITCH m lattice, HEIGHT m tall.
SITE = (200.0, 100.0, 5.0)
BUILDING, PITCH, HEIGHT = 18.0, 25.0, 4.0
#: Length of a robot's street run (m).
RUN = 97.0


def campus_plan() -> FloorPlan:
    """The campus: 8 x 4 building blocks, streets of PITCH - BUILDING = 7 m between them."""
    quads, heights = [], []
    for cx in np.arange(PITCH / 2, SITE[0], PITCH):
        for cy in np.arange(PITCH / 2, SITE[1], PITCH):
            h = BUILDING / 2
            quads.append([[cx - h, cy - h], [cx + h, cy - h], [cx + h, cy + h], [cx - h, cy + h]])
            heights.append(HEIGHT)
    return FloorPlan(np.array(quads), np.array(heights), np.zeros(2), np.array(SITE[:2]), name="campus")


def street_paths(robots: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """(start (2,), unit direction (2,)) of ``robots`` of the campus's RUN m street runs: the
    streets' centre lines (x and y multiples of PITCH, 1.5 m in from the site's edge), those along
    x in two halves; a fixed draw of ``robots`` of the 19 runs."""
    runs = []
    for y in np.arange(0.0, SITE[1] + 1, PITCH):
        for x0 in (1.5, SITE[0] / 2 + 1.5):
            runs.append((np.array([x0, min(max(y, 1.5), SITE[1] - 1.5)]), np.array([1.0, 0.0])))
    for x in np.arange(0.0, SITE[0] + 1, PITCH):
        runs.append((np.array([min(max(x, 1.5), SITE[0] - 1.5), 1.5]), np.array([0.0, 1.0])))
    if robots > len(runs):
        raise ValueError(f"the campus has {len(runs)} street runs, fewer than {robots} robots")
    chosen = np.random.default_rng(1).permutation(len(runs))[:robots]
    return [runs[i] for i in sorted(chosen)]


def street_frames(rig, robots: int, step: float = 1.0) -> list[list[Frame]]:
    """Per time step, the frames of ``robots`` robots each driving its street run at ``step`` m per
    frame, looking ahead and 45 degrees to either side in turn (the facades and the street)."""
    plan = campus_plan()
    renderer = Renderer(plan, rig.camera(), seed=0, threads=1)
    paths = street_paths(robots)
    steps = int(RUN / step) + 1
    turns = (0.0, math.pi / 4, -math.pi / 4)
    out = []
    for s in range(steps):
        poses = []
        for start, direction in paths:
            x, y = start + direction * (s * step)
            poses.append((x, y, math.atan2(direction[1], direction[0]) + turns[s % 3]))
        out.append(render_frames(renderer, rig, poses, seed=s))
    return out


# -- EuRoC ---------------------------------------------------------------------------------
def euroc_frames(root: Path) -> list[Frame]:
    """The excerpt's stereo clouds (``swarm.bench.fusion.euroc_stereo_cloud``, rectified left
    camera) placed by the ground-truth pose of cam0 at each pair (the rectified camera is taken
    as cam0: they differ by the rectification's rotation, under a degree)."""
    from swarm.bench.fusion import euroc_stereo_cloud  # noqa: PLC0415 (opencv: only when asked)

    rows = np.loadtxt(root / "mav0" / "cam0_groundtruth" / "data.csv", delimiter=",", comments="#")
    frames = []
    for n, row in enumerate(np.atleast_2d(rows)):
        camera_to_world = quaternion_matrix(*row[4:8]).T  # the file's rotation is world -> camera
        cloud = euroc_stereo_cloud(root, n)
        frames.append((row[1:4].copy(), cloud @ camera_to_world.T + row[1:4]))
    return frames
