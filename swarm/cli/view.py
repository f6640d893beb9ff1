"""``swarm view``: a live 3-D view of a running mission's team map (rerun)."""

from __future__ import annotations

import argparse
import signal
import threading
from pathlib import Path

from swarm.child_command import stop_signals
from swarm.cli.common import fail
from swarm.protocol import bus


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "view",
        help="live 3-D view of a running mission with rerun (pip install '.[view]')",
        description="Follow a running mission over Zenoh (its merged deltas and every robot's status, "
        "as any client would) and draw it with the rerun viewer: occupied voxels as boxes coloured "
        "by E[C], per-voxel entropy and the known/unknown boundary as separate entities, each "
        "robot's position, path and target, and the map entropy over sim time. The view only "
        "listens: a slow viewer draws fewer frames, the mission never waits. --save writes a "
        "recording to open later with `rerun run.rrd`; without --save a viewer window is spawned.",
    )
    p.add_argument(
        "--connect",
        action="append",
        metavar="ENDPOINT",
        help="Zenoh endpoint of the mission's router (default tcp/127.0.0.1:7447); repeatable",
    )
    bus.add_zenoh_config_argument(p)
    p.add_argument("--mission", default="default", help="mission name, the key prefix (default: default)")
    p.add_argument("--save", type=Path, metavar="RUN.rrd", help="write a rerun recording instead of a window")
    p.add_argument("--spawn", action="store_true", help="with --save, also spawn a viewer window")
    p.add_argument("--period", type=float, default=1.0, help="seconds between map frames (default 1)")
    p.add_argument(
        "--duration", type=float, help="stop after this many seconds (default: at Ctrl-C / SIGTERM)"
    )
    p.set_defaults(run=_run_view)


def _run_view(args: argparse.Namespace) -> int:
    try:
        from swarm.view.live import missing_display, run_view
        from swarm.view.scene import require_rerun

        require_rerun()
    except ImportError as exc:
        return fail(str(exc))
    if not args.period > 0:
        return fail(f"--period must be > 0, got {args.period}")
    stop = threading.Event()
    for sig in stop_signals():  # SIGTERM, and SIGINT unless a runner started it (swarm.child_command)
        signal.signal(sig, lambda *_: stop.set())
    spawn = args.save is None or args.spawn
    no_window = missing_display() if spawn else None
    if no_window:
        drop = "drop --spawn" if args.save is not None else "record with --save RUN.rrd"
        return fail(f"{no_window}: {drop} and open the recording where there is one with `rerun RUN.rrd`")
    try:
        view = run_view(
            args.connect, args.mission, args.save, spawn, args.period, args.duration, stop, args.zenoh_config
        )
    except (ConnectionError, ValueError) as exc:
        return fail(str(exc))
    where = f" to {args.save}" if args.save else ""
    print(f"view: {view.deltas} merged deltas, {view.frames} map frames{where}", flush=True)
    return 0
