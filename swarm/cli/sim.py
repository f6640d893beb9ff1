"""``swarm sim``: a whole simulated mission, or the simulated world / renderer alone."""

from __future__ import annotations

import argparse
from pathlib import Path

from swarm.navigation.strategies import STRATEGIES

# -- swarm sim ----------------------------------------------------------------------------
SIM_COMMANDS = {"run", "render", "world", "-h", "--help"}
DEFAULT_MISSION = "configs/office.yaml"


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "sim",
        help="simulated missions: run one, render a view, or run the world alone",
        description="Simulated missions. 'swarm sim [CONFIG]' is short for 'swarm sim run [CONFIG]'.",
    )
    ssub = p.add_subparsers(dest="sim_command", required=True, metavar="COMMAND")
    run = ssub.add_parser(
        "run",
        help="run a whole mission: world, map server, coordinator and one agent per robot over Zenoh",
        description="Run a mission on this machine: the simulated world, the map server, the "
        "coordinator and one agent per robot, each a separate process talking Zenoh over loopback. "
        "Shows progress, stops at the entropy threshold H_th or --max-time, and writes the run "
        "folder (metrics.json, map.npz, server_map.npz, entropy.png, top_view.png, map_3d.png, slices/, "
        "config.yaml, logs). Ctrl-C stops the roles within seconds and writes the run folder from the "
        "map server's map (metrics.json says interrupted); a second Ctrl-C stops at once. "
        f"Default mission: {DEFAULT_MISSION} (4 robots).",
    )
    run.add_argument("config", nargs="?", type=Path, help=f"mission YAML (default {DEFAULT_MISSION})")
    run.add_argument("--map", type=Path, help="a ROS map_server map.yaml to explore instead of a mission")
    run.add_argument("--robots", type=int, help="number of robots (default: the mission's, 1 with --map)")
    run.add_argument("--out", type=Path, help="run folder (default runs/<mission>-<strategy>-s<seed>)")
    run.add_argument(
        "--strategy",
        choices=STRATEGIES,
        default="entropy",
        help="exploration: entropy gradient (the paper, default), nearest frontier, or random",
    )
    run.add_argument("--seed", type=int, default=0, help="random seed of the world and agents (default 0)")
    run.add_argument("--max-time", type=float, help="simulated seconds at most (default: the mission's)")
    run.add_argument(
        "--coordination",
        choices=["coordinator", "none"],
        default="coordinator",
        help="coordinator (default): targets from swarm coordinator; none: each robot chooses alone "
        "(eq. 35 on the shared map)",
    )
    run.add_argument(
        "--share-min-bits",
        type=float,
        help="override sharing.share_min_bits (0 shares every voxel: the utility filter off)",
    )
    run.add_argument(
        "--kill-coordinator-at",
        type=float,
        metavar="SIM_S",
        help="fault injection: SIGKILL the coordinator at this simulated time, in seconds "
        "(agents must carry on alone)",
    )
    run.add_argument(
        "--view",
        nargs="?",
        const="window",
        metavar="RUN.rrd",
        help="follow the mission with swarm view (rerun, pip install '.[view]'): a viewer window "
        "(with no display: one warning line, and the mission runs without it), or with a file name "
        "a recording to open later with `rerun RUN.rrd`",
    )
    run.add_argument(
        "--observable-threshold",
        type=float,
        metavar="F",
        help="H_th = entropy of the voxels no sensor can ever observe + F x the observable prior "
        "(F = 0.16 is the paper's end point; the default of --map missions); replaces the mission's H_th",
    )
    run.add_argument(
        "--secure",
        action="store_true",
        help="mutual TLS and access control: a fresh CA and one certificate per role in <out>/security; "
        "the map server is the TLS router and enforces who may put and answer what (docs/security.md)",
    )
    run.add_argument(
        "--ros2",
        action="store_true",
        help="every robot a ROS 2 robot over rmw_zenoh: the world publishes each robot's camera topics, "
        "CameraInfo, tf and /clock and takes cmd_vel; the agents take frames and give commands only there "
        "(docs/ros2.md)",
    )
    run.add_argument("--quiet", action="store_true", help="no progress lines")
    run.set_defaults(run=_run_sim_mission)
    render = ssub.add_parser(
        "render",
        help="write what a robot sees (left/right images, true depth) as PNGs",
        description="Render robot ROBOT's first view of a mission config (or of a ROS map with "
        "--map) and write left.png, right.png, depth.npy (float32 metres, NaN = no return) and "
        "depth.png (near red, far blue, black = no return, with a colour bar in metres) to --out.",
    )
    world = ssub.add_parser(
        "world",
        help="run the simulated world alone: frames out, commands in, over Zenoh",
        description="Run the lockstep pymunk world of a mission: publish every robot's frames on "
        "swarm/<mission>/robot/<rid>/frame and advance when every live agent has answered with a "
        "cmd. Agents (swarm agent) are started separately and connect to --listen. Stops at the "
        "mission's max time, on SIGINT/SIGTERM, when the map server announces the end of the mission "
        "(mission/done), and with an error (exit 1) when no robot's agent came within --startup-timeout.",
    )
    render.defer(_render_arguments)
    world.defer(_world_arguments)


def _render_arguments(render: argparse.ArgumentParser) -> None:
    from sim2d.commands import add_render_arguments, run_render

    add_render_arguments(render)
    render.set_defaults(run=run_render, default_config=DEFAULT_MISSION)


def _world_arguments(world: argparse.ArgumentParser) -> None:
    from sim2d.commands import add_run_arguments, run_sim

    add_run_arguments(world)
    world.set_defaults(run=run_sim, default_config=DEFAULT_MISSION)


def _run_sim_mission(args: argparse.Namespace) -> int:
    from swarm.mission.simulated_mission import run_sim_mission

    return run_sim_mission(args, DEFAULT_MISSION)
