"""``swarm bench ros2 euroc`` and ``swarm bench ros2 mission``: the same runs on our protocol and on
the ROS 2 path, as ``swarm replay`` / ``swarm sim`` processes, and what differs between them."""

from __future__ import annotations

import json
import subprocess
import time
from pathlib import Path

import numpy as np

from swarm.child_command import child_environment, swarm_argv
from swarm.formats.map_file import load_map

LINKS = ("swarm", "ros2")


def _swarm(args: list[str], log: Path) -> float:
    """Run ``swarm ARGS`` to its end, its output in ``log``; its wall time (s). Raises on failure."""
    log.parent.mkdir(parents=True, exist_ok=True)
    start = time.monotonic()
    with log.open("w") as out:
        done = subprocess.run(
            swarm_argv(*args), stdout=out, stderr=subprocess.STDOUT, env=child_environment()
        )
    if done.returncode != 0:
        raise RuntimeError(f"swarm {' '.join(args)} exited {done.returncode} (see {log})")
    return time.monotonic() - start


def map_difference(a_path: Path, b_path: Path) -> dict:
    """How two maps of one grid differ: the largest relative difference of lam and of eta (over
    the voxels where either is not zero), and the voxels one knows and the other does not."""
    a, b = load_map(a_path), load_map(b_path)
    if not a.grid.matches(b.grid):
        raise ValueError(f"{a_path} and {b_path} are on different grids")

    def rel(x: np.ndarray, y: np.ndarray) -> float:
        x, y = x.astype(np.float64), y.astype(np.float64)
        scale = np.maximum(np.abs(x), np.abs(y))
        some = scale > 0
        return float(np.max(np.abs(x - y)[some] / scale[some])) if some.any() else 0.0

    known_a, known_b = a.known_mask(), b.known_mask()
    return {
        "lam_max_rel_diff": rel(a.lam, b.lam),
        "eta_max_rel_diff": rel(a.eta, b.eta),
        "known_voxels": [int(known_a.sum()), int(known_b.sum())],
        "known_only_in_one": int(np.count_nonzero(known_a != known_b)),
    }


def euroc(folder: Path, out: Path, frames: int | None) -> int:
    """Replay ``folder`` both ways and print the maps' difference."""
    count = [] if frames is None else ["--frames", str(frames)]
    seconds = {}
    for link in LINKS:
        args = ["replay", "asl", str(folder), *count, "--out", str(out / link)]
        args += ["--ros2"] if link == "ros2" else []
        seconds[link] = _swarm(args, out / f"{link}.log")
    diff = map_difference(out / "swarm" / "map.npz", out / "ros2" / "map.npz")
    pairs = json.loads((out / "swarm" / "metrics.json").read_text())["frames"]
    ros2 = "raw images, CameraInfo from sensor.yaml, tf from the ground truth"
    print(f"{folder}: {pairs} pairs, swarm replay asl ({seconds['swarm']:.0f} s) and swarm replay asl "
          f"--ros2 ({seconds['ros2']:.0f} s: {ros2})")  # fmt: skip
    print(f"  max relative difference of the maps: lam {diff['lam_max_rel_diff']:.3g}, "
          f"eta {diff['eta_max_rel_diff']:.3g}; known voxels {diff['known_voxels'][0]:,} and "
          f"{diff['known_voxels'][1]:,}, {diff['known_only_in_one']:,} known in one only")  # fmt: skip
    (out / "difference.json").write_text(json.dumps(diff, indent=2))
    return 0


def _metrics(folder: Path) -> dict:
    return json.loads((folder / "metrics.json").read_text())


def mission(
    config: Path, out: Path, robots: int | None, seed: int, max_time: float | None, single: bool
) -> int:
    """Run the mission with the team (and alone) on both links; print the table."""
    teams = [robots] if robots else [None]
    if single:
        teams.append(1)
    rows = {}
    for team in teams:
        for link in LINKS:
            name = f"{link}-{'team' if team != 1 else '1r'}"
            args = ["sim", "run", str(config), "--seed", str(seed), "--out", str(out / name), "--quiet"]
            args += (["--robots", str(team)] if team else []) + (
                ["--max-time", str(max_time)] if max_time else []
            )
            args += ["--ros2"] if link == "ros2" else []
            print(f"running {name}: swarm {' '.join(args)}", flush=True)
            wall = _swarm(args, out / f"{name}.log")
            m = _metrics(out / name)
            rows[name] = {
                "robots": len(m["robots"]),
                "reached": m["reached_threshold"],
                "time_to_threshold_s": m["mission_time_s"],
                "sim_time_s": m["sim_time_s"],
                "surface_accuracy": m.get("surface_accuracy"),
                "surface_completeness": m.get("surface_completeness"),
                "wall_s": wall,
            }
    print(f"\n{config}, seed {seed}:")
    head = f"{'run':<12} {'robots':>6} {'H_th':>5} {'T (sim s)':>10} {'accuracy':>9} {'completeness':>13}"
    print(f"  {head} {'wall s':>7}")
    for name, r in rows.items():
        t = r["time_to_threshold_s"]
        acc, comp, t = _f(r["surface_accuracy"]), _f(r["surface_completeness"]), _f(t, ".1f")
        print(f"  {name:<12} {r['robots']:>6} {'yes' if r['reached'] else 'no':>5} "
              f"{t:>10} {acc:>9} {comp:>13} {r['wall_s']:>7.0f}")  # fmt: skip
    summary = {"runs": rows}
    for link in LINKS:
        team, alone = rows.get(f"{link}-team"), rows.get(f"{link}-1r")
        if team and alone and team["time_to_threshold_s"] and alone["time_to_threshold_s"]:
            summary[f"{link}_speedup"] = alone["time_to_threshold_s"] / team["time_to_threshold_s"]
    for key in ("time_to_threshold_s", "surface_accuracy", "surface_completeness"):
        a, b = rows["swarm-team"][key], rows["ros2-team"][key]
        if a and b:
            summary[f"ros2_vs_swarm_{key}"] = b / a - 1
    if "swarm_speedup" in summary and "ros2_speedup" in summary:
        summary["ros2_vs_swarm_speedup"] = summary["ros2_speedup"] / summary["swarm_speedup"] - 1
        print(f"  speed-up (one robot's time / the team's): ours {summary['swarm_speedup']:.2f}x, "
              f"ROS 2 {summary['ros2_speedup']:.2f}x ({summary['ros2_vs_swarm_speedup']:+.1%})")  # fmt: skip
    for key in ("time_to_threshold_s", "surface_accuracy", "surface_completeness"):
        if f"ros2_vs_swarm_{key}" in summary:
            what = key.replace("_", " ")
            print(f"  the team on ROS 2 vs ours, {what}: {summary[f'ros2_vs_swarm_{key}']:+.1%}")
    (out / "summary.json").write_text(json.dumps(summary, indent=2))
    return 0


def _f(value: float | None, form: str = ".3f") -> str:
    return "-" if value is None else format(value, form)
