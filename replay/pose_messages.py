"""The left camera's pose from a bag's pose messages: PoseStamped, PoseWithCovarianceStamped,
Odometry, TransformStamped, and the TFMessages of ``/tf`` and ``/tf_static`` (``replay.tf_tree``)."""

from __future__ import annotations

from typing import Any

import numpy as np

from swarm.streams.poses import quaternion_matrix
from swarm.streams.tf_tree import TfTree

TF_TYPES = ("tf2_msgs/msg/TFMessage", "tf/msg/tfMessage")
UNUSABLE_POSE = "unusable pose message (NaN, or a zero quaternion)"


def stamp(msg: Any) -> float:
    t = msg.header.stamp
    return float(t.sec) + float(t.nanosec) * 1e-9


def child_frames(msg: Any) -> list[str]:
    """The child_frame_id(s) a pose message carries (TFMessage, Odometry, TransformStamped)."""
    if hasattr(msg, "transforms"):
        return [tf.child_frame_id for tf in msg.transforms]
    return [msg.child_frame_id] if hasattr(msg, "child_frame_id") else []


class UnusablePose(ValueError):
    """A pose message of the camera whose numbers are not a pose (a lost tracker's NaN, w = x = y = z = 0)."""


def message_pose(msg: Any, child_frame: str | None) -> tuple[float, np.ndarray, np.ndarray] | None:
    """(time, position, world_R_optical) of a pose message, or None if it is of another frame.

    Odometry and TransformStamped: kept when ``child_frame`` is None or is their child_frame_id.
    Raises ``UnusablePose``. (A TFMessage goes to a ``TfTree`` with ``add_transforms``.)
    """
    if child_frame and hasattr(msg, "child_frame_id"):
        if msg.child_frame_id.lstrip("/") != child_frame.lstrip("/"):
            return None
    if hasattr(msg, "transform"):  # TransformStamped (e.g. vicon_bridge, motion capture)
        p, q = msg.transform.translation, msg.transform.rotation
    else:
        pose = msg.pose.pose if hasattr(msg.pose, "pose") else msg.pose
        p, q = pose.position, pose.orientation
    return stamp(msg), *position_rotation(p, q)


def add_transforms(tree: TfTree, msg: Any, static: bool) -> None:
    """Each transform of a TFMessage into ``tree``."""
    for tf in msg.transforms:
        p, q = tf.transform.translation, tf.transform.rotation
        tree.add(
            tf.header.frame_id, tf.child_frame_id, stamp(tf), (p.x, p.y, p.z), (q.w, q.x, q.y, q.z), static
        )


def position_rotation(p: Any, q: Any) -> tuple[np.ndarray, np.ndarray]:
    position = np.array([p.x, p.y, p.z], dtype=np.float64)
    quat = np.array([q.w, q.x, q.y, q.z], dtype=np.float64)
    if not (np.all(np.isfinite(position)) and np.all(np.isfinite(quat)) and np.linalg.norm(quat) > 1e-9):
        raise UnusablePose(UNUSABLE_POSE)
    return position, quaternion_matrix(*quat)
