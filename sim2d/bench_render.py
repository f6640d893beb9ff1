"""Renderer throughput: ``python -m sim2d.bench_render [--plan P] [--seconds S] [--repeats N]``.

Prints frames rendered per second (one frame = a stereo pair, or one depth image in range
mode) for 1 and 4 robots at 160x120 and 640x480, and simulator ticks per second (all
robots rendered once): the best of ``--repeats`` measurements of ``--seconds`` each, wall
clock, so that a busy machine disturbs the figure less; and the process CPU time per frame
(all threads; the least of the measurements). ``--plan``: office (default), depot
or lab. Robots move a little between frames, as in a run. The first line gives the
machine's load average and ``--threads``, the renderer's threads per stereo pair (2, the
default, renders the right view beside the left; see ``sim2d.render.Renderer``).
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

from sim2d.render import Renderer, camera_pose
from swarm.config import RigConfig, load_mission

CONFIGS = Path(__file__).resolve().parent.parent / "configs"


def bench(
    mission, rig: RigConfig, robots: int, seconds: float, threads: int = 2
) -> tuple[float, float, float]:
    """(frames per second, ticks per second, CPU ms per frame) rendering ``robots`` robots with ``rig``."""
    renderer = Renderer(mission.load_floor_plan(), rig.camera(), seed=0, threads=threads)
    starts = [(p.x, p.y, p.yaw) for p in mission.start_poses()]
    starts = (starts * robots)[:robots]
    rng = np.random.default_rng(0)
    frames = ticks = 0
    begin, cpu = time.perf_counter(), time.process_time()
    while time.perf_counter() - begin < seconds or ticks < 2:
        for x, y, yaw in starts:
            pose = camera_pose(x, y, yaw + 0.05 * ticks, rig.camera_height)
            if rig.mode == "range":
                renderer.depth_image(pose, rig.range_noise, rig.max_range, rng)
            else:
                renderer.stereo_pair(pose, rig.noise_std, rng)
            frames += 1
        ticks += 1
    elapsed, cpu = time.perf_counter() - begin, time.process_time() - cpu
    return frames / elapsed, ticks / elapsed, 1e3 * cpu / frames


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--plan", default="office", choices=["lab", "office", "depot"])
    parser.add_argument("--seconds", type=float, default=2.0, help="time per measurement (default 2)")
    parser.add_argument("--repeats", type=int, default=3, help="measurements per line; the best is printed")
    parser.add_argument("--threads", type=int, default=2, choices=[1, 2], help="threads per stereo pair")
    args = parser.parse_args(argv)
    if args.seconds <= 0 or args.repeats < 1:
        parser.error("--seconds must be > 0 and --repeats >= 1")
    mission = load_mission(CONFIGS / f"{args.plan}.yaml")
    plan = mission.load_floor_plan()
    load = ", ".join(f"{x:.1f}" for x in os.getloadavg())
    print(f"plan {args.plan}: {plan.count} obstacles; best of {args.repeats} x {args.seconds:g} s per line; "
          f"load average {load}; {args.threads} thread(s) per stereo pair")  # fmt: skip
    print(f"{'size':>8} {'mode':>7} {'robots':>6} {'frames/s':>9} {'ticks/s':>8} {'CPU ms/frame':>12}")
    for width, height in ((160, 120), (640, 480)):
        for mode in ("stereo", "range"):
            rig = RigConfig(width=width, height=height, mode=mode, noise_std=1.0)
            for robots in (1, 4):
                bench(mission, rig, robots, 0.0, args.threads)  # warm up: compiled kernels, texture
                runs = [bench(mission, rig, robots, args.seconds, args.threads) for _ in range(args.repeats)]
                fps, tps, _ = max(runs)
                cpu = min(run[2] for run in runs)
                line = f"{width}x{height:<4} {mode:>7} {robots:>6} {fps:>9.1f} {tps:>8.1f} {cpu:>12.1f}"
                print(line, flush=True)


if __name__ == "__main__":
    main()
