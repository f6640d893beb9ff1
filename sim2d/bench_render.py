"""Renderer throughput: ``python -m sim2d.bench_render [--plan office|depot|lab] [--seconds S]``.

Prints frames rendered per second (one frame = a stereo pair, or one depth image in range
mode) for 1 and 4 robots at 160x120 and 640x480, and simulator ticks per second (all
robots rendered once). Robots move a little between frames, as in a run.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from sim2d.render import Renderer, camera_pose
from swarm.config import RigConfig, load_mission

CONFIGS = Path(__file__).resolve().parent.parent / "configs"


def bench(mission, rig: RigConfig, robots: int, seconds: float) -> tuple[float, float]:
    """(frames per second, ticks per second) rendering ``robots`` robots with ``rig``."""
    renderer = Renderer(mission.load_floor_plan(), rig.camera(), seed=0)
    starts = [(r.start.x, r.start.y, r.start.yaw) for r in mission.robots]
    starts = (starts * robots)[:robots]
    rng = np.random.default_rng(0)
    frames = ticks = 0
    begin = time.perf_counter()
    while time.perf_counter() - begin < seconds or ticks < 2:
        for x, y, yaw in starts:
            pose = camera_pose(x, y, yaw + 0.05 * ticks, rig.camera_height)
            if rig.mode == "range":
                renderer.depth_image(pose, rig.range_noise, rig.max_range, rng)
            else:
                renderer.stereo_pair(pose, rig.noise_std, rng)
            frames += 1
        ticks += 1
    elapsed = time.perf_counter() - begin
    return frames / elapsed, ticks / elapsed


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--plan", default="office", choices=["lab", "office", "depot"])
    parser.add_argument("--seconds", type=float, default=2.0, help="time per measurement")
    args = parser.parse_args(argv)
    mission = load_mission(CONFIGS / f"{args.plan}.yaml")
    plan = mission.load_floor_plan()
    print(f"plan {args.plan}: {plan.count} obstacles; {args.seconds:g} s per line")
    print(f"{'size':>8} {'mode':>7} {'robots':>6} {'frames/s':>9} {'ticks/s':>8}")
    for width, height in ((160, 120), (640, 480)):
        for mode in ("stereo", "range"):
            rig = RigConfig(width=width, height=height, mode=mode, noise_std=1.0)
            for robots in (1, 4):
                fps, tps = bench(mission, rig, robots, args.seconds)
                print(f"{width}x{height:<4} {mode:>7} {robots:>6} {fps:>9.1f} {tps:>8.1f}")


if __name__ == "__main__":
    main()
