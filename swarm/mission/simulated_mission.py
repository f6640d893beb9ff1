"""``swarm sim run``: load the mission, run it, evaluate against ground truth, write the run folder."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from swarm.config import ConfigError, Mission, load_mission, mission_from_map

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
    for robot, start in zip(mission.robots, mission.start_poses(), strict=True):
        row, col = ros_map.to_cell(np.array([start.x, start.y]))
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

    starts = np.array([[p.x, p.y] for p in mission.start_poses()])
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
    refused when too large to simulate (``check_simulation_size``) or when a robot has no start
    pose (naming the file and ``robots[i].start``: the simulated world places every robot)."""
    mission = _resolve_mission(args, default_config)
    mission.start_poses()
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
    """``swarm sim run``: the mission, then its run folder.

    A first Ctrl-C, SIGTERM or SIGHUP stops the roles at once and writes the run folder from
    the map server's map as it stands (``stop_reason: interrupted``, ``interrupted: true`` in
    ``metrics.json``, which ``swarm study --resume`` does not take for a finished run), says
    where on stderr and exits with 130; a second one kills what is left and exits at once
    (:mod:`swarm.mission.interrupts`). A standard output whose reader has gone (``swarm sim |
    tee log`` after Ctrl-C) drops what is printed to it (:mod:`swarm.mission.console`).
    """
    from swarm.mission.console import surviving_stdout
    from swarm.mission.interrupts import INTERRUPTED_EXIT, Interrupts, say
    from swarm.mission.picture_style import pyplot
    from swarm.mission.role_processes import kill_started_roles

    run_folder: list[Path] = []  # the run folder, once chosen: for the last line of at_once

    def at_once() -> None:
        killed = kill_started_roles()
        left = f"; {run_folder[0]}/ has no metrics.json" if run_folder and not (
            run_folder[0] / "metrics.json").exists() else ""  # fmt: skip
        say(f"swarm: killed {killed} role process(es){left}")

    with (
        surviving_stdout(),
        Interrupts(
            at_once, "the mission", "writing its run folder from what the map server holds"
        ) as interrupts,
    ):
        pyplot()  # now, not after an interrupt: the run folder's pictures must come within seconds
        try:
            return _run_sim_mission(args, default_config, interrupts, run_folder)
        except KeyboardInterrupt:  # before the mission ran (the kernels' warm-up, the threshold)
            say("swarm: interrupted before the mission ran: every role was stopped; no run folder written")
            return INTERRUPTED_EXIT


def _run_sim_mission(args: argparse.Namespace, default_config: str, interrupts, run_folder: list) -> int:
    from swarm.mission.runner import MissionOptions, run_mission
    from swarm.mission.sim_evaluation import evaluate_and_write
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
    run_folder.append(out)
    monitor, facts = run_mission(mission, options, interrupts)
    with interrupts.held():  # a first Ctrl-C now changes nothing: the run folder is being written
        return evaluate_and_write(args, default_config, mission, monitor, facts, interrupts, out,
                         (coordination, threshold_parts, sensor_observable))  # fmt: skip
