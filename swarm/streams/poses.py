"""Camera poses of recordings, turned into the wire's ``Pose`` of the rectified left camera.

Conventions (docs/recordings.md):

* ``world_R_optical`` maps vectors of the camera's optical frame (x right, y down, z forward,
  the ROS/OpenCV camera frame) to the world (z up).
* The wire's ``Pose`` is the body frame (x forward, y left, z up): ``world_R_body =
  world_R_optical @ BODY_FROM_OPTICAL.T``, then yaw, pitch, roll of Rz Ry Rx.
* Rectification turns the left camera by ``R1`` (``X_rectified = R1 X_raw``), so the
  rectified camera is ``world_R_optical @ R1.T``.
"""

from __future__ import annotations

import math

import numpy as np

from swarm.protocol.wire import BODY_FROM_OPTICAL, Pose


def quaternion_matrix(w: float, x: float, y: float, z: float) -> np.ndarray:
    """The rotation matrix of a (w, x, y, z) Hamilton quaternion (normalised first)."""
    q = np.array([w, x, y, z], dtype=np.float64)
    norm = np.linalg.norm(q)
    if not norm > 0:
        raise ValueError("a zero quaternion is not a rotation")
    w, x, y, z = q / norm
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def interpolate_pose(
    s: float, p0: np.ndarray, r0: np.ndarray, p1: np.ndarray, r1: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The pose a fraction ``s`` (0..1) of the way from (p0, r0) to (p1, r1): straight line, and
    rotation about the one axis turning r0 into r1 (the rotations' slerp)."""
    import cv2

    turn, _ = cv2.Rodrigues(np.asarray(r0, dtype=np.float64).T @ np.asarray(r1, dtype=np.float64))
    step, _ = cv2.Rodrigues(turn * s)
    return (1 - s) * np.asarray(p0, dtype=np.float64) + s * np.asarray(p1, dtype=np.float64), r0 @ step


def ypr_of(world_R_body: np.ndarray) -> tuple[float, float, float]:
    """(yaw, pitch, roll) with world_R_body = Rz(yaw) Ry(pitch) Rx(roll)."""
    r = world_R_body
    pitch = -math.asin(max(-1.0, min(1.0, float(r[2, 0]))))
    yaw = math.atan2(float(r[1, 0]), float(r[0, 0]))
    roll = math.atan2(float(r[2, 1]), float(r[2, 2]))
    return yaw, pitch, roll


def wire_pose(
    position: np.ndarray, world_R_optical: np.ndarray, rectification: np.ndarray | None = None
) -> Pose:
    """The wire Pose of a camera at ``position`` (m) with optical orientation ``world_R_optical``.

    ``rectification`` is ``R1`` of the rectified left camera (None: the images are not turned).
    """
    rot = np.asarray(world_R_optical, dtype=np.float64)
    if rectification is not None:
        rot = rot @ np.asarray(rectification, dtype=np.float64).T
    body = rot @ BODY_FROM_OPTICAL.T
    p = np.asarray(position, dtype=np.float64).reshape(3)
    return Pose((float(p[0]), float(p[1]), float(p[2])), ypr_of(body))


def camera_from_body(
    body_position: np.ndarray, world_R_body: np.ndarray, body_from_camera: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """Camera position and world_R_optical from a body pose and the camera's ``T_BS`` (4x4)."""
    world_T_body = np.eye(4)
    world_T_body[:3, :3] = world_R_body
    world_T_body[:3, 3] = body_position
    world_T_cam = world_T_body @ np.asarray(body_from_camera, dtype=np.float64)
    return world_T_cam[:3, 3].copy(), world_T_cam[:3, :3].copy()
