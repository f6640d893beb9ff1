"""A ROS 2 stereo robot written with ``zenoh-ros2-sdk`` alone, an implementation of rmw_zenoh's wire
independent of ours (its own RIHS01 hashes, CDR, attachments and liveliness tokens): it publishes
a recording's raw left/right ``sensor_msgs/Image``, both ``CameraInfo`` and the left camera's pose
on ``tf``, and waits, pair by pair, for the agent's ``cmd_vel`` stamped with the pair's stamp.

Run by tests/robot_agent/test_ros2_sdk.py in a process of its own (the SDK keeps one Zenoh session
per process):
``python tests/support/ros2_sdk_robot.py PORT DATA.npz MSGS_DIR NAMESPACE FIXED_FRAME``. The message
definitions come from MSGS_DIR (no network: the SDK would clone them from GitHub otherwise). Prints
``answered K`` after each answered pair, ``topics ...`` with what the SDK's discovery sees, and
exits 0 when every pair was answered.
"""

from __future__ import annotations

import os
import sys
import tempfile
import threading


def main(port: int, data_path: str, msgs: str, namespace: str, fixed_frame: str) -> int:
    os.environ["ZENOH_ROS2_SDK_CACHE"] = tempfile.mkdtemp(prefix="sdk-cache-")  # never a clone
    import numpy as np
    from zenoh_ros2_sdk import ROS2Publisher, ROS2Subscriber, get_registry, get_topic_names_and_types

    registry = get_registry(msgs)  # the shipped definitions first
    data = np.load(data_path)
    ns = namespace.rstrip("/")

    def publisher(topic: str, msg_type: str) -> ROS2Publisher:
        return ROS2Publisher(f"{ns}/{topic}", msg_type, namespace=namespace, router_port=port)

    images = [publisher(f"{side}/image_raw", "sensor_msgs/msg/Image") for side in ("left", "right")]
    infos = [publisher(f"{side}/camera_info", "sensor_msgs/msg/CameraInfo") for side in ("left", "right")]
    tf = publisher("tf", "tf2_msgs/msg/TFMessage")
    types = {name: registry.get_message_class(name) for name in (
        "builtin_interfaces/msg/Time", "std_msgs/msg/Header", "sensor_msgs/msg/RegionOfInterest",
        "geometry_msgs/msg/Vector3", "geometry_msgs/msg/Quaternion", "geometry_msgs/msg/Transform",
        "geometry_msgs/msg/TransformStamped")}  # fmt: skip
    answered: set[tuple[int, int]] = set()
    cond = threading.Condition()

    def on_cmd(msg) -> None:
        with cond:
            answered.add((int(msg.header.stamp.sec), int(msg.header.stamp.nanosec)))
            cond.notify_all()

    ROS2Subscriber(
        f"{ns}/cmd_vel", "geometry_msgs/msg/TwistStamped", on_cmd, namespace=namespace, router_port=port
    )

    def header(sec, nsec, frame):
        return types["std_msgs/msg/Header"](stamp=types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec),
                                            frame_id=frame)  # fmt: skip

    import time

    deadline = time.monotonic() + 60
    while not any(f"{ns}/left/image_raw" == name for name, _ in get_topic_names_and_types(router_port=port)):
        if time.monotonic() > deadline:
            print("no subscription to the images", flush=True)
            return 1
        time.sleep(0.2)
    time.sleep(1.0)  # every subscription of the agent declared
    seen = get_topic_names_and_types(router_port=port)
    print("topics", " ".join(f"{name}={','.join(kinds)}" for name, kinds in seen), flush=True)
    for k in range(len(data["sec"])):
        sec, nsec = int(data["sec"][k]), int(data["nsec"][k])
        x, y, z = (float(v) for v in data["position"][k])
        qw, qx, qy, qz = (float(v) for v in data["quaternion"][k])
        transform = types["geometry_msgs/msg/Transform"](
            translation=types["geometry_msgs/msg/Vector3"](x=x, y=y, z=z),
            rotation=types["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw),
        )
        stamped = types["geometry_msgs/msg/TransformStamped"](
            header=header(sec, nsec, fixed_frame), child_frame_id="cam0", transform=transform
        )
        tf.publish(transforms=[stamped])
        for side, frame in ((0, "cam0"), (1, "cam1")):
            which = ("left", "right")[side]
            height, width = data[which][k].shape
            roi = types["sensor_msgs/msg/RegionOfInterest"](
                x_offset=0, y_offset=0, height=0, width=0, do_rectify=False
            )
            infos[side].publish(
                header=header(sec, nsec, frame), height=height, width=width, distortion_model="plumb_bob",
                d=data[f"{which}_d"], k=data[f"{which}_k"].reshape(9), r=data[f"{which}_r"].reshape(9),
                p=data[f"{which}_p"].reshape(12), binning_x=0, binning_y=0, roi=roi,
            )  # fmt: skip
            images[side].publish(
                header=header(sec, nsec, frame), height=height, width=width, encoding="mono8", is_bigendian=0,
                step=width, data=np.ascontiguousarray(data[which][k]).reshape(-1),
            )  # fmt: skip
        with cond:
            if not cond.wait_for(lambda s=(sec, nsec): s in answered, 60):
                print(f"pair {k + 1} not answered", flush=True)
                return 1
        print(f"answered {k + 1}", flush=True)
    return 0


if __name__ == "__main__":
    port, data_path, msgs, namespace, fixed = sys.argv[1:6]
    code = main(int(port), data_path, msgs, namespace, fixed)
    sys.stdout.flush()
    os._exit(code)  # the SDK's session threads would keep the process alive
