"""``swarm bench coordinator``: the coordinator's answer time for a large team on a large site."""

from __future__ import annotations

import argparse

from swarm.cli.common import at_least, fail


def register(bsub: argparse._SubParsersAction) -> None:
    """Add ``coordinator`` to ``swarm bench``'s subcommands ``bsub``."""
    coord = bsub.add_parser(
        "coordinator",
        help="coordinator: answer time (p50/p95/max) for 16 and 64 robots on a large office floor",
        description="A coordinator's team map of a synthetic office floor (rooms off corridors, "
        "default 80 m x 48 m x 2.2 m at 0.1 m) partly explored by --robots robots walking and fusing "
        "camera frames (the project's fusion), then every robot asks for a target in turn while new "
        "frames keep arriving between requests. Prints the answer time p50/p95/max, its phases "
        "(team-map copy, entropy, candidates, planning, assignment) and the peak memory "
        "(swarm.bench.coordinator); --profile adds cProfile's slowest functions.",
    )
    coord.add_argument(
        "--robots", type=at_least(1), nargs="+", default=[16, 64], help="team sizes (default 16 64)"
    )
    coord.add_argument(
        "--size",
        type=float,
        nargs=3,
        default=[80.0, 48.0, 2.2],
        metavar=("X", "Y", "Z"),
        help="workspace (m, default 80 48 2.2; e.g. 160 96 2.2 for a larger site)",
    )
    coord.add_argument("--voxel", type=float, default=0.1, help="voxel edge (default 0.1 m)")
    coord.add_argument(
        "--explore-frames", type=at_least(0), default=60, help="frames per robot before timing (default 60)"
    )
    coord.add_argument("--rounds", type=at_least(1), default=2, help="requests per robot (default 2)")
    coord.add_argument(
        "--frames-between", type=at_least(0), default=1, help="frames applied before each request (default 1)"
    )
    coord.add_argument("--seed", type=int, default=0, help="seed of the walks (default 0)")
    coord.add_argument("--profile", action="store_true", help="also print cProfile's slowest functions")
    coord.set_defaults(run=_run_bench_coordinator)


def _run_bench_coordinator(args: argparse.Namespace) -> int:
    from swarm.bench import coordinator

    if not (args.voxel > 0 and all(s > 4 * args.voxel for s in args.size)):
        return fail("--voxel must be > 0 and each --size side more than 4 voxels")
    for robots in args.robots:
        figures = coordinator.run(
            robots,
            tuple(args.size),
            args.voxel,
            args.explore_frames,
            args.rounds,
            args.frames_between,
            args.seed,
            args.profile,
        )
        print(coordinator.format_figures(figures), flush=True)
    return 0
