"""``swarm stereo``: depth from your own rig's stereo pair."""

from __future__ import annotations

import argparse


# -- swarm stereo -------------------------------------------------------------------------
def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "stereo",
        help="stereo tools for checking a rig",
        description="Stereo tools for checking a rig on real images.",
    )
    ssub = p.add_subparsers(dest="stereo_command", required=True, metavar="COMMAND")
    depth = ssub.add_parser(
        "depth",
        help="depth in metres from a rectified or calibrated stereo pair",
        description="Match LEFT and RIGHT with OpenCV SGBM and write depth in metres (NaN where "
        "unknown, same size as the input) to --out, and optionally a colour PNG.",
    )
    depth.defer(_depth_arguments)


def _depth_arguments(depth: argparse.ArgumentParser) -> None:
    from robot_agent.stereo_command import add_arguments

    add_arguments(depth)
