"""``swarm replay asl|bag``: recorded stereo through the real map server and agent (docs/recordings.md)."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", type=Path, required=True, help="run folder to write")
    p.add_argument(
        "--config", type=Path, help="mission YAML (default: a box 3 m around the trajectory, 0.1 m voxels)"
    )
    p.add_argument(
        "--robot", default="r1", help="robot id (default r1; with --config, its first robot if absent)"
    )
    p.add_argument("--start", type=int, default=0, help="first pair to replay (default 0)")
    p.add_argument("--frames", type=int, help="number of pairs to replay (default: all)")
    p.add_argument(
        "--realtime",
        action="store_true",
        help="publish at the recorded rate (default: lockstep with the agent)",
    )
    p.add_argument(
        "--ros2",
        action="store_true",
        help="play the recording as a ROS 2 robot's topics (raw images, CameraInfo, tf; rmw_zenoh) and run "
        "the agent on its ROS 2 path (swarm agent --ros2; docs/ros2.md)",
    )
    p.add_argument("--connect", help="join a running Zenoh router and map server at this endpoint")
    p.add_argument(
        "--zenoh-config",
        type=Path,
        metavar="FILE",
        help="with --connect: Zenoh config of the replay itself, the robot's frame source (e.g. "
        "source-r1/zenoh.json5 of swarm security init; docs/security.md). Default: $ZENOH_CONFIG",
    )
    p.add_argument(
        "--agent-zenoh-config",
        type=Path,
        metavar="FILE",
        help="with --connect: Zenoh config of the agent the replay starts (e.g. agent-r1/zenoh.json5)",
    )


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "replay",
        help="replay a recorded stereo dataset (ASL/EuRoC folder, ROS 1/2 bag) through the agent",
        description="Publish a recording's rectified stereo pairs on robot/<id>/frame, with the rectified "
        "left camera's pose, to a real agent and map server, and write the run folder (map.npz, the "
        "pictures top_view.png, map_3d.png and slices/, per-frame timings, stereo valid fraction, entropy).",
    )
    rsub = p.add_subparsers(dest="replay_command", required=True, metavar="FORMAT")
    asl = rsub.add_parser(
        "asl",
        help="an ASL / EuRoC dataset folder",
        description="Replay mav0/cam0 + mav0/cam1 (data.csv, data/*.png, sensor.yaml) with the poses of "
        "mav0/cam0_groundtruth/data.csv (world-to-camera quaternions) or of "
        "mav0/state_groundtruth_estimate0/data.csv combined with cam0's T_BS.",
    )
    asl.add_argument("folder", type=Path, help="dataset folder (holding mav0/)")
    asl.add_argument(
        "--tolerance", type=float, default=0.005, help="time matching tolerance, s (default 0.005)"
    )
    _common(asl)
    asl.set_defaults(run=_run_asl)
    bag = rsub.add_parser(
        "bag",
        help="a ROS 1 .bag or ROS 2 bag (.db3/.mcap), read with rosbags (no ROS install)",
        description="Replay two image topics (sensor_msgs/Image or CompressedImage), or one of side-by-side "
        "pairs, with the left camera's "
        "pose (geometry_msgs/PoseStamped or PoseWithCovarianceStamped, nav_msgs/Odometry, "
        "geometry_msgs/TransformStamped, or /tf with --child-frame, whose chain of transforms from the "
        "world (with /tf_static's) is composed; the pose of the left camera's optical frame in a z-up "
        "world). Calibration from files (--calib-left/--calib-right) "
        "or from CameraInfo topics (--left-info/--right-info).",
    )
    bag.add_argument("bag", type=Path, help="a .bag file, or a ROS 2 bag folder / its .db3 or .mcap file")
    bag.add_argument("--left", help="left image topic")
    bag.add_argument("--right", help="right image topic")
    bag.add_argument(
        "--side-by-side",
        metavar="TOPIC",
        help="in place of --left and --right: one image topic of side-by-side pairs (double-width "
        "images, the left camera's in the left half, as ZED and USB stereo cameras send them)",
    )
    bag.add_argument(
        "--pose", required=True, help="pose topic (PoseStamped, Odometry, TransformStamped, or /tf)"
    )
    bag.add_argument(
        "--child-frame",
        help="the child_frame_id of the left camera (its optical frame): needed with --pose /tf, a "
        "filter for Odometry and TransformStamped",
    )
    bag.add_argument(
        "--world-frame",
        help="with --pose /tf: the frame the camera's pose is in, one of its ancestors (default: the "
        "root of its tree, e.g. map or odom)",
    )
    bag.add_argument(
        "--tf-static",
        metavar="TOPIC",
        help="with --pose /tf: the static transforms' topic (default /tf_static, when in the bag)",
    )
    bag.add_argument("--left-info", help="left sensor_msgs/CameraInfo topic")
    bag.add_argument("--right-info", help="right sensor_msgs/CameraInfo topic")
    bag.add_argument("--calib-left", type=Path, help="calibration file (any form of docs/stereo.md)")
    bag.add_argument(
        "--calib-right",
        type=Path,
        help="the second file of two-file forms: the right camera's (camera_info, sensor.yaml), or "
        "extrinsics.yml beside --calib-left intrinsics.yml (OpenCV's stereo_calib sample)",
    )
    bag.add_argument(
        "--calib-units",
        choices=("m", "cm", "mm"),
        help="the unit of the calibration file's translation or baseline, when it is not the form's own "
        "(metres; Middlebury's millimetres); see docs/stereo.md",
    )
    bag.add_argument(
        "--tolerance", type=float, default=0.01, help="time matching tolerance, s (default 0.01)"
    )
    _common(bag)
    bag.set_defaults(run=_run_bag)


def _fail(message: str) -> int:
    for line in str(message).splitlines() or [""]:  # one prefixed line per problem
        print(f"swarm replay: error: {line}", file=sys.stderr)
    return 2


def _open_asl(args: argparse.Namespace):
    from replay.asl import AslRecording

    return AslRecording(args.folder, args.tolerance)


def _open_bag(args: argparse.Namespace):
    import functools

    from replay.bag import BagRecording
    from swarm.formats.calibration_formats import load_stereo_calibration
    from swarm.formats.stereo_calibration import CalibrationError

    calib = None
    units = getattr(args, "calib_units", None)  # Namespaces built by hand may leave it out
    if units is not None and args.calib_left is None:
        raise CalibrationError(
            f"--calib-units {units}: declares the unit of a --calib-left file; CameraInfo "
            "topics are in metres"
        )
    if args.calib_left is not None:
        if args.left_info or args.right_info:  # which calibration would be meant is anyone's guess
            raise CalibrationError(
                "give the calibration either as files (--calib-left, --calib-right) or as CameraInfo "
                "topics (--left-info, --right-info), not both"
            )
        # loaded once the bag's image size is known (its third argument, image_size), for a file
        # that states none (stereo_calib's)
        calib = functools.partial(load_stereo_calibration, args.calib_left, args.calib_right, units=units)
    return BagRecording(
        args.bag, args.left, args.right, args.pose, calib, args.left_info, args.right_info, args.child_frame,
        args.tolerance, world_frame=args.world_frame, tf_static=args.tf_static,
        side_by_side=args.side_by_side,
    )  # fmt: skip


def _run_asl(args: argparse.Namespace) -> int:
    return _replay(args, _open_asl)


def _run_bag(args: argparse.Namespace) -> int:
    return _replay(args, _open_bag)


def _replay(args: argparse.Namespace, opener) -> int:
    from swarm.config import ConfigError, load_mission
    from swarm.formats.errors import RecordingError
    from swarm.formats.stereo_calibration import CalibrationError
    from swarm.mission.replay_run import ReplayOptions, default_mission, run_replay

    if args.frames is not None and args.frames < 1:
        return _fail(f"--frames {args.frames}: must be at least 1 (leave it out for all pairs)")
    if args.start < 0:
        return _fail(f"--start {args.start}: must be 0 or more (the first pair is 0)")
    if not args.tolerance > 0:
        return _fail(f"--tolerance {args.tolerance:g}: must be > 0 (seconds)")
    try:
        recording = opener(args)
        if len(recording) == 0:
            return _fail(f"no pair left after matching ({recording.matched.describe()})")
        if args.start >= len(recording):
            return _fail(
                f"--start {args.start}: the recording has {len(recording)} pairs after matching "
                f"(0 to {len(recording) - 1})"
            )
        robot = args.robot
        if args.config is not None:
            mission = load_mission(args.config)
            robot = robot if robot in mission.robot_ids else mission.robot_ids[0]
        else:
            mission = default_mission(recording, robot)
    except (RecordingError, CalibrationError, ConfigError, ValueError) as exc:
        return _fail(str(exc))
    calib = recording.calibration
    calib.print_notes()
    frames = getattr(recording, "pose_frames", None)
    if frames:
        print(f"poses: {frames}", flush=True)
    interpolated = getattr(recording, "interpolated_poses", 0)
    if interpolated:
        print(f"{interpolated} poses interpolated between the recorded ones", flush=True)
    bits = getattr(recording, "pixel_bits", None)
    if bits is not None:
        print(f"16-bit images: {bits} significant bits (scaled to 8 bits by {2 ** (bits - 8)})", flush=True)
    print(
        f"{len(recording)} pairs ({recording.matched.describe()}); rectified {calib.image_size[0]}x"
        f"{calib.image_size[1]}, fx {calib.fx:.1f} px, baseline {calib.baseline:.4f} m",
        flush=True,
    )
    options = ReplayOptions(
        args.out, robot, args.start, args.frames, args.realtime, args.connect,
        zenoh_config=args.zenoh_config, agent_zenoh_config=args.agent_zenoh_config, ros2=args.ros2,
    )  # fmt: skip
    from swarm.mission.console import surviving_stdout
    from swarm.mission.interrupts import INTERRUPTED_EXIT, Interrupts, say
    from swarm.mission.role_processes import kill_started_roles

    def at_once() -> None:
        say(f"swarm replay: killed {kill_started_roles()} role process(es); {args.out}/ is incomplete")

    with surviving_stdout(), Interrupts(at_once, "the replay", "") as interrupts:
        try:
            metrics = run_replay(recording, mission, options, interrupts)
        except KeyboardInterrupt:
            say(f"swarm replay: interrupted: every role was stopped; {args.out}/ has no metrics.json")
            return INTERRUPTED_EXIT
    print(json.dumps(metrics, indent=2))
    print(f"wrote {args.out}")
    return 0
