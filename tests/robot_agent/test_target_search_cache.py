"""The agent's own target search reads the slab's eq. 32-35 fields and its traversability from
per-tile caches: the same decisions, frame after frame, as the passes over the whole map."""

from __future__ import annotations

import numpy as np

from robot_agent.explorer import Explorer
from swarm.config import mission_from_dict
from swarm.map.delta import Delta
from swarm.protocol.wire import Frame, Pose

MISSION = {
    "mission": "cache",
    "workspace": {"lo": [0.0, 0.0, 0.0], "hi": [9.6, 7.0, 2.0], "voxel": 0.1},
    "robots": [{"id": "r1", "start": {"x": 2.0, "y": 3.0}}],
    "rig": {"mode": "range", "width": 48, "height": 32, "range_noise": 0.0},
    "stop": {"entropy_threshold_bits": 1.0},
}


def depth_frame(explorer: Explorer, seq: int, x: float, y: float, yaw: float, rng) -> Frame:
    """A range frame of a room with walls at random distances per image column."""
    cam = explorer.rig.camera()
    walls = rng.uniform(0.8, 4.5, cam.width).astype(np.float32)
    depth = np.broadcast_to(walls, (cam.height, cam.width)).copy()
    depth[: cam.height // 3] = np.float32(np.nan)  # above the walls: nothing in range
    return Frame("r1", seq, 0.5 * seq, Pose((x, y, 0.4), (yaw, 0.0, 0.0)), cam, "f32", depth=depth)


def teammate_delta(explorer: Explorer, rng) -> Delta:
    """What a teammate saw: a patch of floor and wall voxels somewhere on the map."""
    nx, ny, nz = explorer.grid.shape
    i0, j0 = rng.integers(0, nx - 20), rng.integers(0, ny - 20)
    ii, jj, kk = np.meshgrid(np.arange(i0, i0 + 20), np.arange(j0, j0 + 20), np.arange(nz), indexing="ij")
    idx = np.unique(np.ravel_multi_index((ii.ravel(), jj.ravel(), kk.ravel()), (nx, ny, nz)))
    dlam = rng.lognormal(1.0, 1.5, idx.size).astype(np.float32)
    mean = np.where((idx % nz) < 2, 0.05, rng.uniform(0, 1, idx.size))
    return Delta(idx.astype(np.uint32), dlam, (dlam * mean).astype(np.float32))


def test_cached_and_uncached_searches_decide_alike_frame_after_frame() -> None:
    mission = mission_from_dict(MISSION)
    robots = [Explorer(mission, "r1", seed=3), Explorer(mission, "r1", seed=3)]
    robots[1].search.cached = False  # the reference: whole-map passes at every decision
    robots[1].ground.floor = None
    rng_frames, rng_team = np.random.default_rng(11), np.random.default_rng(12)
    x, y, yaw = 2.0, 3.0, 0.0
    targets = set()
    for seq in range(80):
        frame = depth_frame(robots[0], seq, x, y, yaw, rng_frames)
        team = teammate_delta(robots[0], rng_team) if seq % 3 == 1 else None
        decisions = []
        for robot in robots:
            if team is not None:  # as the team replica applies a merged delta
                robot.map.apply_received(team)
                robot.local.apply_entropy(team)
            robot.fuse(frame)
            decisions.append(robot.decide(x, y, yaw, frame.t))
        cached, whole = decisions
        assert (cached.state, cached.v, cached.omega, cached.target) == (
            whole.state,
            whole.v,
            whole.omega,
            whole.target,
        ), seq
        targets.add(cached.target)
        # move as commanded (0.5 s a frame), inside the room
        yaw += 0.5 * cached.omega
        x = float(np.clip(x + 0.5 * cached.v * np.cos(yaw), 0.5, 9.0))
        y = float(np.clip(y + 0.5 * cached.v * np.sin(yaw), 0.5, 6.5))
    assert len(targets) >= 4  # the robot chose several targets: the cache was read and redone
    # tiles were redone after the first full pass, and fewer than a full pass per decision
    whole = int(np.prod(robots[0].local.changes.tiles))
    redone = sum(s.counts["tiles"] for s in robots[0].local.targets._slabs.values())
    assert whole < redone < whole * len(targets)
