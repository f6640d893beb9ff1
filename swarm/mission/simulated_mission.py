"""``swarm sim run``: load the mission, run it, evaluate against ground truth, write the run folder."""

from __future__ import annotations

import argparse
import json
import signal
import sys
import time
from pathlib import Path

import numpy as np

from swarm.config import ConfigError, Mission, load_mission, mission_from_map
from swarm.formats.map_file import save_map
from swarm.map.entropy_cache import EntropyCache
from swarm.map.entropy_table import default_table
from swarm.mission import evaluation

#: The most voxels a simulated mission's workspace may hold. The map server, the coordinator
#: and every agent each hold the whole map (8 bytes of belief per voxel, and more in the
#: agents' caches), and the observable-voxel rays of H_th grow with the floor area: Nav2's
#: depot (1.0 million voxels, 393 m^2 of reachable floor) takes 12 s of them on 2 cores,
#: a 200 m x 200 m map at 0.1 m (75 million voxels) took more than 6 minutes before its
#: first frame. 20 million voxels is about 9,000 m^2 of floor at 0.1 m and 2.2 m of height.
MAX_SIM_VOXELS = 20_000_000


def check_simulation_size(mission: Mission) -> None:
    """Raise ConfigError naming the numbers when the workspace is too large to simulate here."""
    grid = mission.workspace.grid()
    if grid.size <= MAX_SIM_VOXELS:
        return
    ws = mission.workspace
    nx, ny, nz = grid.shape
    raise ConfigError(
        f"{mission.source or '<mission>'}: workspace: x [{ws.lo[0]:g}, {ws.hi[0]:g}], y [{ws.lo[1]:g}, "
        f"{ws.hi[1]:g}], z [{ws.lo[2]:g}, {ws.hi[2]:g}] m at {ws.voxel:g} m voxels is {nx:,} x {ny:,} x "
        f"{nz:,} = {grid.size:,} voxels, more than the {MAX_SIM_VOXELS:,} a simulated mission takes "
        f"(the map server, the coordinator and each agent would hold {8 * grid.size / 1e9:.1f} GB of "
        "beliefs each, and setting up H_th would take many minutes); crop the map to the part to "
        "explore (its image and origin), or write a mission with a smaller workspace or a coarser "
        "workspace.voxel"
    )


def confined_robots(mission: Mission, share: float = 0.5) -> list[str]:
    """Warnings for robots that start in a pocket of a ROS map's floor: a free region (where the
    robot's body fits, ``robot.radius`` from every wall and unknown cell) of less than ``share``
    of the largest one, cut off by passages narrower than the robot (SLAM maps draw doors
    narrower than they are). Then one for floor where the body fits, in the robots' regions,
    that their planner never reaches (1 m^2 or more). Empty for other floor plans."""
    from scipy import ndimage

    plan = mission.load_floor_plan()
    ros_map = getattr(plan, "ros_map", None)
    if ros_map is None:
        return []
    fits = ros_map.clearance() > mission.robot.radius
    labels, count = ndimage.label(fits, structure=np.ones((3, 3), dtype=bool))
    if count == 0:
        return []
    cell_area = ros_map.resolution**2
    areas = np.bincount(labels.ravel()) * cell_area
    areas[0] = 0.0
    largest = float(areas.max())
    out = []
    for robot in mission.robots:
        row, col = ros_map.to_cell(np.array([robot.start.x, robot.start.y]))
        inside = 0 <= row < fits.shape[0] and 0 <= col < fits.shape[1]
        area = float(areas[labels[row, col]]) if inside else 0.0
        if area < share * largest:
            out.append(
                f"warning: {robot.id} starts in a free region of {area:.1f} m^2 where its body fits, cut off "
                f"from the largest ({largest:.1f} m^2) by passages narrower than the robot "
                f"({2 * mission.robot.radius:g} m across): it will map only its own region"
            )
    behind, pieces = _floor_the_planner_never_reaches(mission, labels, ros_map)
    if behind >= 1.0:
        where = ", ".join(f"{area:.1f} m^2 around ({x:.1f}, {y:.1f})" for area, (x, y) in pieces[:3])
        out.append(
            f"warning: {behind:.1f} m^2 of floor where the robots fit lies behind passages "
            f"their planner does not take (it keeps {mission.robot.radius:g} m + half a voxel "
            "from every voxel a wall touches, so doors narrower than about "
            f"{2 * mission.robot.radius + mission.workspace.voxel:.2f}-"
            f"{2 * mission.robot.radius + 2 * mission.workspace.voxel:.2f} m, by where the walls fall "
            "on the voxels, stay shut): "
            "no robot will go there, and H_th does not count what only that floor sees; "
            f"the largest parts, in map coordinates (m): {where}"
        )
    return out


def _floor_the_planner_never_reaches(
    mission: Mission, labels: np.ndarray, ros_map
) -> tuple[float, list[tuple[float, tuple[float, float]]]]:
    """Area (m^2) of the ROS map's cells in the robots' body-fit regions (``labels``) and in the
    workspace that lie farther than 1.5 voxel edges from every column the planner reaches from
    a start on a perfect map (``sim2d.observability.planner_floor``, the rule of H_th's
    reachable floor), and its 8-connected parts as (area m^2, (x, y) of their centroid in map
    coordinates), largest first. Floor outside the workspace (a mission cut to part of a map)
    is no part of the mission, and floor within radius + half a voxel of the workspace's edge
    is floor no robot's centre may stand on whatever the passages (the planner counts the
    outside of its grid as blocked): neither is counted."""
    from scipy import ndimage

    from sim2d.observability import planner_floor

    starts = np.array([[r.start.x, r.start.y] for r in mission.robots])
    cells = ros_map.to_cell(starts)
    inside = (
        (cells[:, 0] >= 0)
        & (cells[:, 0] < labels.shape[0])
        & (cells[:, 1] >= 0)
        & (cells[:, 1] < labels.shape[1])
    )
    keep = {int(labels[r, c]) for r, c in cells[inside]} - {0}
    if not keep:
        return 0.0, []
    grid = mission.workspace.grid()
    rig = mission.rig_for(mission.robot_ids[0])
    planned = planner_floor(mission.load_floor_plan(), grid, starts, mission.robot.radius, rig.camera_height)
    near = ndimage.distance_transform_edt(~planned) * grid.voxel <= 1.5 * grid.voxel
    rows, cols = np.nonzero(np.isin(labels, list(keep)))
    xy = ros_map.to_world(cols + 0.5, rows + 0.5)
    ij = np.floor((xy - grid.lo[:2]) / grid.voxel).astype(int)
    margin = mission.robot.radius + grid.voxel / 2
    ok = np.all((xy >= grid.lo[:2] + margin) & (xy <= grid.hi[:2] - margin), axis=1)
    reached = np.zeros(len(ij), dtype=bool)
    reached[ok] = near[ij[ok, 0], ij[ok, 1]]
    never = np.zeros(labels.shape, dtype=bool)
    never[rows[ok & ~reached], cols[ok & ~reached]] = True
    parts, count = ndimage.label(never, structure=np.ones((3, 3), dtype=bool))
    cell_area = ros_map.resolution**2
    pieces = []
    for k, sl in enumerate(ndimage.find_objects(parts), start=1):
        r, c = np.nonzero(parts[sl] == k)
        centre = ros_map.to_world(c.mean() + sl[1].start + 0.5, r.mean() + sl[0].start + 0.5)
        pieces.append((len(r) * cell_area, (float(centre[0]), float(centre[1]))))
    pieces.sort(key=lambda piece: -piece[0])
    return float(np.count_nonzero(never)) * cell_area, pieces


def stereo_only(mission: Mission) -> None:
    """Raise ConfigError unless every robot's rig is a stereo pair (what a ROS 2 robot publishes)."""
    for i, robot in enumerate(mission.robots):
        if mission.rig_for(robot.id).mode != "stereo":
            raise ConfigError(
                f"{mission.source or '<mission>'}: robots[{i}].rig: mode range: the simulated ROS 2 robots "
                'publish stereo pairs only (docs/ros2.md, "Not supported")'
            )


def resolve_mission(args: argparse.Namespace, default_config: str) -> Mission:
    """The mission of ``swarm sim run``: CONFIG, or --map, or the bundled default; --robots applied;
    refused when too large to simulate (``check_simulation_size``)."""
    mission = _resolve_mission(args, default_config)
    check_simulation_size(mission)
    return mission


def _resolve_mission(args: argparse.Namespace, default_config: str) -> Mission:
    if args.config and args.map:
        raise ConfigError("give either a mission CONFIG or --map MAP.yaml, not both")
    if args.map:
        if args.robots is not None and args.robots < 1:
            raise ConfigError(f"--robots {args.robots}: must be at least 1")
        return mission_from_map(args.map, robots=args.robots or 1)
    path = args.config or Path(default_config)
    if not path.exists():
        raise ConfigError(f"{path}: no such mission file (run from the project folder, or give CONFIG)")
    mission = load_mission(path)
    if args.robots is not None:
        if not 1 <= args.robots <= len(mission.robots):
            raise ConfigError(
                f"{path}: robots: --robots {args.robots} asks for more robots than the "
                f"{len(mission.robots)} the mission places (or fewer than 1)"
            )
        mission = mission.model_copy(update={"robots": mission.robots[: args.robots]})
    return mission


def run_sim_mission(args: argparse.Namespace, default_config: str) -> int:
    """``swarm sim run``: the mission, then its run folder. A SIGTERM or Ctrl-C stops every role
    it started and leaves no ``metrics.json`` (``swarm study --resume`` takes one as a finished
    run); the command then exits with 130 and one line."""
    previous = signal.signal(signal.SIGTERM, _interrupt)
    try:
        return _run_sim_mission(args, default_config)
    except KeyboardInterrupt:
        print(
            "swarm: interrupted: every role was stopped; the run folder has no metrics.json", file=sys.stderr
        )
        return 130
    finally:
        signal.signal(signal.SIGTERM, previous)


def _interrupt(signum, frame) -> None:
    raise KeyboardInterrupt  # unwinds through run_mission's clean-up, as Ctrl-C does


def _run_sim_mission(args: argparse.Namespace, default_config: str) -> int:
    from sim2d.ground_truth import coverage as true_coverage_of
    from swarm.mission.run_report import RunRecord, compute_metrics, write_run_folder
    from swarm.mission.runner import MissionOptions, run_mission
    from swarm.mission.team_monitor import NEVER
    from swarm.mission.threshold import resolve_threshold

    try:
        mission = resolve_mission(args, default_config)
    except ConfigError as exc:
        print(f"swarm: error: {exc}", file=sys.stderr)
        return 2
    for warning in confined_robots(mission):
        print(warning, file=sys.stderr, flush=True)
    out = args.out or Path("runs") / f"{mission.mission}-{args.strategy}-s{args.seed}"
    if args.seed:
        mission = mission.model_copy(update={"sim": mission.sim.model_copy(update={"seed": args.seed})})
    if args.share_min_bits is not None:
        if not args.share_min_bits >= 0:
            print(f"swarm: error: --share-min-bits must be >= 0 (got {args.share_min_bits})", file=sys.stderr)
            return 2
        sharing = mission.sharing.model_copy(update={"share_min_bits": args.share_min_bits})
        mission = mission.model_copy(update={"sharing": sharing})
    try:
        if args.seed < 0:
            raise ConfigError(f"--seed {args.seed}: must be 0 or more")
        if getattr(args, "ros2", False) and args.secure:
            raise ConfigError(
                "--ros2 with --secure: the team's access rules admit only swarm/<mission>/ keys, and a ROS 2 "
                'robot\'s topics travel on its own rmw_zenohd router (docs/ros2.md, "With TLS")'
            )
        if getattr(args, "ros2", False):
            stereo_only(mission)
        if args.max_time is not None and not args.max_time > 0:
            raise ConfigError(f"--max-time {args.max_time:g}: must be > 0 (simulated seconds)")
        fraction = getattr(args, "observable_threshold", None)
        if fraction is not None and not 0.0 <= fraction <= 1.0:
            raise ConfigError(f"--observable-threshold must be in [0, 1] (got {fraction})")
        mission, threshold_parts, sensor_observable = resolve_threshold(mission, fraction)
    except ConfigError as exc:
        print(f"swarm: error: {exc}", file=sys.stderr)
        return 2
    if threshold_parts is not None:
        print(
            f"H_th by the observable rule: {threshold_parts.unobservable_bits:,.0f} bits never observable "
            f"({threshold_parts.unobservable_voxels:,} voxels) + {threshold_parts.fraction:.0%} of "
            f"{threshold_parts.observable_prior_bits:,.0f} observable ({threshold_parts.seconds:.1f} s)",
            flush=True,
        )
    coordination = args.coordination if len(mission.robots) > 1 and args.strategy == "entropy" else "none"
    options = MissionOptions(
        out=out,
        strategy=args.strategy,
        seed=args.seed,
        max_time_s=args.max_time,
        quiet=args.quiet,
        coordination=coordination,
        kill_coordinator_at_s=args.kill_coordinator_at,
        view=getattr(args, "view", None),
        secure=args.secure,
        ros2=getattr(args, "ros2", False),
    )
    print(
        f"mission {mission.mission}: robots {', '.join(mission.robot_ids)}, strategy {args.strategy}, "
        f"coordination {coordination}, seed {args.seed}, H_th {mission.threshold_bits():,.0f} bits"
        f"{', mutual TLS and access control' if args.secure else ''}"
        f"{', frames and commands over ROS 2 (rmw_zenoh)' if options.ros2 else ''} -> {out}",
        flush=True,
    )
    monitor, facts = run_mission(mission, options)

    t0 = time.monotonic()
    grid = mission.workspace.grid()
    plan = mission.load_floor_plan()
    truth = true_coverage_of(plan, grid) if plan is not None else None
    workspace = (mission.workspace.lo, mission.workspace.hi)
    record = RunRecord(
        config=str(args.config or args.map or default_config),
        robots=mission.robot_ids,
        strategy=args.strategy,
        coordination=coordination,
        seed=args.seed,
        threshold_bits=facts["threshold_bits"],
        initial_entropy_bits=monitor.curve[0][1],
        entropy_curve=[[t, h] for t, h in monitor.curve],
        trajectories={r: [list(p) for p in pts] for r, pts in monitor.trajectories.items()},
        bytes_shared=dict(monitor.bytes_shared),
        sim_time_s=monitor.sim_time,
        wall_time_s=facts["wall_time_s"],
        workspace=workspace,
        floor_plan=plan,
        height_band=(0.1, mission.rig.camera_height + 0.1),
    )
    first_delta = monitor.first_delta_copy()  # one snapshot for the overlaps and observed_by.npz
    observed_by = {r: n != NEVER for r, n in first_delta.items()}
    metrics = compute_metrics(record, monitor.cmap, truth, observed_by, sensor_observable)
    metrics["threshold_parts"] = None if threshold_parts is None else threshold_parts.as_dict()
    metrics["stop_reason"] = facts["reason"]
    metrics["robot_link"] = "ros2" if options.ros2 else "swarm"
    metrics["max_time_s"] = mission.stop.max_time_s if args.max_time is None else float(args.max_time)
    metrics["share_min_bits"] = mission.sharing.share_min_bits
    metrics["max_held_bits"] = mission.sharing.max_held_bits
    coordinator_stats = facts.get("coordinator_stats")
    metrics["coordinator_answer_ms"] = (
        None if coordinator_stats is None else coordinator_stats.get("answer_ms")
    )
    metrics.update(
        evaluation.overlaps_during_mission(first_delta, metrics["entropy_curve"], metrics["threshold_bits"])
    )
    server_map = facts["server_map"]
    if server_map is not None:
        # The server merged the same deltas the monitor saw: its map must be the same.
        diff = float(np.max(np.abs(server_map.lam - monitor.cmap.lam) / monitor.cmap.lam))
        metrics["server_map_max_rel_diff"] = diff
        metrics["server_final_entropy_bits"] = float(EntropyCache.from_information(
            server_map.lam, server_map.eta, table=default_table()).total)  # fmt: skip
    try:
        write_run_folder(out, metrics, monitor.cmap, mission.to_yaml(), record)
        if server_map is not None:
            save_map(out / "server_map.npz", server_map)
        curve_t = np.array([t for t, _h in monitor.curve])
        arrays = {}
        for r, n in first_delta.items():
            arrays[f"first_delta_{r}"] = n
            arrays[f"first_seen_{r}"] = evaluation.first_seen_times(n, curve_t, never=NEVER)
        np.savez_compressed(out / "observed_by.npz", **arrays)
    except BaseException:  # a run folder cut short is not a finished run
        (out / "metrics.json").unlink(missing_ok=True)
        raise
    keys = (
        "reached_threshold",
        "mission_time_s",
        "sim_time_s",
        "final_entropy_bits",
        "occupancy_f1",
        "explored_fraction",
        "distance_m",
    )
    print(final_line(metrics, facts), flush=True)
    answers = metrics["coordinator_answer_ms"]
    if answers:
        print(
            f"coordinator: {answers['count']} answers, {answers['mean']:.1f} ms mean, "
            f"{answers['p95']:.1f} ms p95, {answers['max']:.1f} ms max (coord/stats)",
            flush=True,
        )
    print(json.dumps({k: _rounded(metrics.get(k)) for k in keys}, default=str))
    print(f"stopped: {facts['reason']}; evaluation {time.monotonic() - t0:.1f} s; wrote {out}/")
    return 0


def final_line(metrics: dict, facts: dict) -> str:
    """The run's last figures, after the agents' shutdown flush, as metrics.json holds them,
    and what the flush did since the last progress line."""
    stop = facts["at_stop"]
    flushed = stop["deltas_after_flush"] - stop["deltas"]
    h, h_stop = metrics["final_entropy_bits"], stop["entropy_bits"]
    server = metrics.get("server_final_entropy_bits")
    return (
        f"final, after the shutdown flush: H={h:,.0f} bits (H_th {metrics['threshold_bits']:,.0f}), "
        f"sim t={metrics['sim_time_s']:.1f} s; the flush brought {flushed} more delta(s) "
        f"({h - h_stop:+,.0f} bits since the last progress line, H={h_stop:,.0f}); "
        + (f"the map server's map: H={server:,.0f} bits" if server is not None else "no map from the server")
    )


def _rounded(value):
    """Floats to 6 decimals, in dicts too: the summary line shows 306.0, not the sum of 612 frame
    periods (306.0000000000011)."""
    if isinstance(value, float):
        return round(value, 6)
    if isinstance(value, dict):
        return {k: _rounded(v) for k, v in value.items()}
    return value
