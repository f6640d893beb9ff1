"""ROS 1 (``.bag``) and ROS 2 (``.db3``, ``.mcap`` folders) recordings, read with ``rosbags``
(no ROS install).

* images: ``sensor_msgs/Image`` (mono8/16, bgr8, rgb8, bgra8, rgba8, YUV 4:2:2, Bayer 8/16) or
  ``sensor_msgs/CompressedImage`` (PNG, JPEG), left and right topics;
* calibration: a ``StereoCalibration`` from files, or the two ``sensor_msgs/CameraInfo``
  topics (the first message of each);
* poses of the **left camera's optical frame** in the world (z up), ROS's usual meaning
  (the orientation turns camera vectors into world vectors): ``geometry_msgs/PoseStamped``,
  ``geometry_msgs/PoseWithCovarianceStamped``, ``nav_msgs/Odometry``,
  ``geometry_msgs/TransformStamped`` (these two filtered by ``child_frame``), or
  ``tf2_msgs/TFMessage`` (``/tf``, with ``/tf_static``): the transforms on the path from
  ``world_frame`` down to ``child_frame``, composed (``replay.tf_tree``).

Times are the messages' header stamps (sorted); left, right and pose are matched within a
tolerance, a pose between two slower ones is interpolated, and what was dropped is counted
(``matched.describe()``). Each camera's first image is decoded when the bag is opened.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from replay import pose_messages as pm
from replay.asl import RecordingError
from replay.bag_files import bag_path, deserialize, messages, open_reader, type_name
from replay.frames import RecordedPair
from replay.image_messages import decode_image
from replay.matching import Matched, match_stamps
from replay.poses import interpolate_pose
from replay.tf_tree import Chain, TfError, TfTree
from swarm.formats.calibration_formats import CameraInfo, stereo_from_camera_infos
from swarm.formats.stereo_calibration import StereoCalibration

POSE_GAP_S = 0.2  # poses at most this far apart are interpolated between, for an image between them
_PEAK_IMAGES = 30  # 16-bit images: the first ones of each camera whose brightest pixel sets the bits


_IMAGE_TYPES = ("sensor_msgs/msg/Image", "sensor_msgs/msg/CompressedImage")
_POSE_TYPES = (
    "geometry_msgs/msg/PoseStamped",
    "geometry_msgs/msg/PoseWithCovarianceStamped",
    "nav_msgs/msg/Odometry",
    "geometry_msgs/msg/TransformStamped",
    *pm.TF_TYPES,
)
_INFO_TYPES = ("sensor_msgs/msg/CameraInfo",)
ROLE_TYPES = {  # the message types each role reads (rosbags' names, ROS 1 and ROS 2 alike)
    "left": _IMAGE_TYPES,
    "right": _IMAGE_TYPES,
    "pose": _POSE_TYPES,
    "left_info": _INFO_TYPES,
    "right_info": _INFO_TYPES,
}


def _camera_info(msg: Any, where: str) -> CameraInfo:
    """The CameraInfo of the images as published (binning and region of interest as
    ``CameraInfo.from_dict`` reads them, the same as in a camera_info file)."""
    data: dict[str, Any] = {"width": int(msg.width), "height": int(msg.height)}
    data["distortion_model"] = msg.distortion_model
    for name in ("k", "d", "r", "p"):  # ROS 2 names; ROS 1 spells them K D R P
        data[name] = list(getattr(msg, name) if hasattr(msg, name) else getattr(msg, name.upper()))
    data["binning_x"], data["binning_y"] = int(msg.binning_x), int(msg.binning_y)
    roi = msg.roi
    data["roi"] = {"x_offset": int(roi.x_offset), "y_offset": int(roi.y_offset)}
    data["roi"].update(width=int(roi.width), height=int(roi.height))
    return CameraInfo.from_dict(data, where)


class BagRecording:
    """A stereo recording in a ROS bag; ``pairs()`` yields matched raw pairs with poses.

    ``calibration``: a ``StereoCalibration``, or a function of the images' (width, height)
    returning one (for a file that states no image size), or None for the CameraInfo topics
    ``left_info`` and ``right_info``.
    """

    def __init__(
        self,
        path: str | Path,
        left: str,
        right: str,
        pose: str,
        calibration: StereoCalibration | Callable[[tuple[int, int]], StereoCalibration] | None = None,
        left_info: str | None = None,
        right_info: str | None = None,
        child_frame: str | None = None,
        tolerance_s: float = 0.01,
        world_frame: str | None = None,
        tf_static: str | None = None,
    ) -> None:
        self.path = bag_path(Path(path))
        self.topics = {"left": left, "right": right, "pose": pose}
        if calibration is None:
            if not (left_info and right_info):
                raise RecordingError(f"{path}: give a calibration (--calib-left/--calib-right) or both "
                                     "camera_info topics (--left-info, --right-info)")  # fmt: skip
            self.topics |= {"left_info": left_info, "right_info": right_info}
        self.child_frame = child_frame
        self.pose_frames: str | None = None  # a /tf pose: its chain of frames, for the summary
        stamps: dict[str, list[float]] = {"left": [], "right": [], "pose": []}
        positions, rotations, infos = [], [], {}
        children: set[str] = set()  # the pose topic's child frames, for the errors
        first: dict[str, np.ndarray] = {}  # each camera's first image
        peak = 0  # the brightest 16-bit pixel of the first images
        unusable = 0  # pose messages of the camera that are not a pose, skipped
        with open_reader(self.path) as reader:
            conns = self._connections(reader, tf_static)
            tree = TfTree() if any(c.msgtype in pm.TF_TYPES for c in conns["pose"]) else None
            if tree is None and (world_frame or tf_static):
                raise RecordingError(f"{path}: --world-frame and --tf-static are for a /tf pose topic")
            for conn, t_ns, raw in messages(reader, path, [c for cs in conns.values() for c in cs]):
                role = next(r for r, cs in conns.items() if conn in cs)
                if role in ("left_info", "right_info"):
                    if role not in infos:
                        infos[role] = _camera_info(
                            deserialize(reader, raw, conn, t_ns), f"{path}: {conn.topic}"
                        )
                    continue
                msg = deserialize(reader, raw, conn, t_ns)
                if tree is not None and role in ("pose", "tf_static"):  # edges of the transform tree
                    children.update(pm.child_frames(msg) if role == "pose" else ())
                    pm.add_transforms(tree, msg, static=role == "tf_static")
                elif role == "pose":
                    children.update(pm.child_frames(msg))
                    try:
                        found = pm.message_pose(msg, child_frame)
                    except pm.UnusablePose:
                        unusable += 1
                        continue
                    if found is not None:
                        stamps["pose"].append(found[0])
                        positions.append(found[1])
                        rotations.append(found[2])
                else:
                    stamps[role].append(pm.stamp(msg))
                    image = None
                    if role not in first:  # read now: a bad image is an error before anything starts
                        image = first[role] = decode_image(msg, conn.topic)
                    if first[role].dtype == np.uint16 and len(stamps[role]) <= _PEAK_IMAGES:
                        image = decode_image(msg, conn.topic) if image is None else image
                        peak = max(peak, int(image.max()))
        chain = None
        if tree is not None:  # /tf: the camera's chain of transforms, world first
            chain = self._chain(tree, children, world_frame)
            if chain.direct:  # its own transforms, world -> camera: read as they are
                stamps["pose"], positions, rotations = (list(v) for v in chain.edges[0].samples())
            else:
                stamps["pose"] = list(chain.stamps())
            unusable = chain.unusable
        for role in self.topics:
            if not (stamps[role] if role in stamps else role in infos):
                what = (
                    "no messages"
                    if role != "pose" or not unusable
                    else f"every message is an {pm.UNUSABLE_POSE}"
                )
                if role == "pose" and children:
                    what = (
                        f"no messages with child_frame_id {child_frame!r}"
                        if child_frame
                        else "give --child-frame, the left camera's child_frame_id"
                    ) + f" (child frames: {', '.join(sorted(children))})"
                raise RecordingError(f"{path}: topic {self.topics[role]}: {what}")
        if calibration is None:
            calibration = stereo_from_camera_infos(infos["left_info"], infos["right_info"])
        elif callable(calibration):  # a loader that needs the images' (width, height)
            calibration = calibration(first["left"].shape[1::-1])
        self.calibration = calibration
        # 16-bit images: a 10- or 12-bit camera's values sit in the low bits (0..4095 of 65535),
        # and their top 8 bits would be black; the significant bits are those the brightest pixel
        # of the first images needs, and every image is scaled to 8 bits by them.
        self.pixel_bits = next(b for b in (8, 10, 12, 14, 16) if peak < 2**b) if peak else None
        size = getattr(calibration, "image_size", None)
        for role in ("left", "right"):
            h, w = first[role].shape[:2]
            if size is not None and (w, h) != tuple(size):
                raise RecordingError(
                    f"{path}: topic {self.topics[role]}: images are {w}x{h}, the calibration "
                    f"({calibration.source}) is for {size[0]}x{size[1]}"
                )
        # Header stamps, sorted (a driver's threads or a merged bag can put them out of order); a
        # left stamp seen twice (a republished image, a topic recorded twice) is kept once.
        ordered = {}
        for role in ("left", "right"):
            arr = np.asarray(stamps[role])
            if arr.size > 1 and np.all(arr == arr[0]):
                raise RecordingError(
                    f"{path}: topic {self.topics[role]}: all {arr.size} messages have the header stamp "
                    f"{arr[0]:.9f} (the driver does not stamp its images)"
                )
            ordered[role] = np.argsort(arr, kind="stable")
        left_sorted = np.asarray(stamps["left"])[ordered["left"]]
        first = np.r_[True, np.diff(left_sorted) > 0]
        self.left_stamps = left_sorted[first]
        self._left_message = ordered["left"][first]  # message number of each left stamp
        self._right_message = ordered["right"]
        if chain is None or chain.direct:
            order = np.argsort(stamps["pose"])
            self.pose_stamps = np.asarray(stamps["pose"])[order]
            self.pose_positions = np.asarray(positions)[order]
            self.pose_rotations = np.asarray(rotations)[order]
            self._interpolate_poses(tolerance_s)
        else:  # each left image's pose, composed along the chain at its stamp
            rows, self.pose_positions, self.pose_rotations, self.interpolated_poses = chain.poses_at(
                self.left_stamps, tolerance_s, POSE_GAP_S
            )
            self.pose_stamps = self.left_stamps[rows]
        self.matched: Matched = match_stamps(
            self.left_stamps,
            {"right image": np.asarray(stamps["right"])[ordered["right"]], "pose": self.pose_stamps},
            tolerance_s,
        )
        if not first.all():
            self.matched.dropped["duplicate left stamp"] += int((~first).sum())
        if unusable:
            self.matched.dropped[pm.UNUSABLE_POSE] += unusable
        if len(self.matched.reference) == 0:  # often topics stamped by different clocks
            spans = {
                "left": self.left_stamps,
                "right": np.asarray(stamps["right"]),
                "pose": np.asarray(stamps["pose"]),
            }
            shown = ", ".join(
                f"{self.topics[role]} {arr.min():.3f} .. {arr.max():.3f}" for role, arr in spans.items()
            )
            raise RecordingError(
                f"{path}: no pair left after matching ({self.matched.describe()}); header stamps (s): "
                f"{shown}: are the topics stamped by one clock?"
            )

    def _interpolate_poses(self, tolerance_s: float) -> None:
        """Add a pose at each left stamp with none within the tolerance but one on each side at most
        ``POSE_GAP_S`` apart (odometry or /tf slower than the camera), interpolated between them."""
        stamps, positions, rotations = self.pose_stamps, self.pose_positions, self.pose_rotations
        self.interpolated_poses = 0
        if stamps.size < 2:
            return
        after = np.clip(np.searchsorted(stamps, self.left_stamps), 1, stamps.size - 1)
        t0, t1 = stamps[after - 1], stamps[after]
        near = np.minimum(np.abs(self.left_stamps - t0), np.abs(self.left_stamps - t1)) <= tolerance_s
        inside = (t0 <= self.left_stamps) & (self.left_stamps <= t1) & (t1 - t0 <= POSE_GAP_S)
        rows = np.flatnonzero(~near & inside)
        if rows.size == 0:
            return
        new_p, new_r = [], []
        for row in rows:
            j = after[row]
            s = (self.left_stamps[row] - stamps[j - 1]) / (stamps[j] - stamps[j - 1])
            p, r = interpolate_pose(s, positions[j - 1], rotations[j - 1], positions[j], rotations[j])
            new_p.append(p)
            new_r.append(r)
        all_stamps = np.concatenate([stamps, self.left_stamps[rows]])
        order = np.argsort(all_stamps, kind="stable")
        self.pose_stamps = all_stamps[order]
        self.pose_positions = np.concatenate([positions, np.asarray(new_p)])[order]
        self.pose_rotations = np.concatenate([rotations, np.asarray(new_r)])[order]
        self.interpolated_poses = int(rows.size)

    def _chain(self, tree: TfTree, children: set[str], world_frame: str | None) -> Chain:
        """The left camera's chain in the transform tree of the /tf pose topic (and /tf_static)."""
        where = f"{self.path}: topic {self.topics['pose']}" + (f" + {self._static}" if self._static else "")
        if not self.child_frame:
            what = "no messages" if not children else "give --child-frame, the left camera's child_frame_id"
            raise RecordingError(f"{where}: {what} (child frames: {', '.join(sorted(children))})")
        try:
            chain = tree.chain(self.child_frame, world_frame)
        except TfError as exc:
            raise RecordingError(f"{where}: {exc}") from None
        how = "--world-frame" if world_frame else "the root of its tree"
        self.pose_frames = f"{chain.child} in {chain.world} ({how}): {chain.describe()}"
        return chain

    def _connections(self, reader: Any, tf_static: str | None) -> dict[str, list]:
        present = sorted({c.topic for c in reader.connections})
        conns = {}
        roles: dict[str, str] = {}
        for role, topic in self.topics.items():
            if topic in roles:
                raise RecordingError(f"{self.path}: topic {topic} is given as both {roles[topic]} and {role}")
            roles[topic] = role
            found = [c for c in reader.connections if c.topic == topic]
            if not found:
                raise RecordingError(f"{self.path}: topic {topic} ({role}) is not in the bag "
                                     f"(topics: {', '.join(present)})")  # fmt: skip
            for conn in found:
                if conn.msgtype not in ROLE_TYPES[role]:
                    wanted = ", ".join(type_name(t) for t in ROLE_TYPES[role])
                    raise RecordingError(
                        f"{self.path}: topic {topic} ({role}) is a {type_name(conn.msgtype)}; "
                        f"the {role} topic must be one of {wanted}"
                    )
            conns[role] = found
        self._static = None  # the /tf_static topic read with a /tf pose topic
        static = tf_static or "/tf_static"
        if any(c.msgtype in pm.TF_TYPES for c in conns["pose"]) and static != self.topics["pose"]:
            found = [c for c in reader.connections if c.topic == static]
            if tf_static and not found:
                raise RecordingError(f"{self.path}: --tf-static {tf_static} is not in the bag "
                                     f"(topics: {', '.join(present)})")  # fmt: skip
            for conn in found:
                if conn.msgtype not in pm.TF_TYPES:
                    raise RecordingError(f"{self.path}: topic {conn.topic} (tf_static) is a "
                                         f"{type_name(conn.msgtype)}, not a tf2_msgs/TFMessage")  # fmt: skip
            if found:
                self._static, conns["tf_static"] = found[0].topic, found
        return conns

    def __len__(self) -> int:
        return len(self.matched.reference)

    def positions(self) -> np.ndarray:
        return self.pose_positions[self.matched.others["pose"]]

    def pairs(self, start: int = 0, count: int | None = None) -> Iterator[RecordedPair]:
        """Matched pairs in time order (the bag is read once more, keeping only the pairs asked)."""
        stop = len(self) if count is None else min(len(self), start + count)
        # message number on each topic -> the pairs it is in (a right image can serve two left ones)
        want: dict[str, dict[int, list[int]]] = {"left": {}, "right": {}}
        for k in range(start, stop):
            i, j = self.matched.reference[k], self.matched.others["right image"][k]
            want["left"].setdefault(int(self._left_message[i]), []).append(k)
            want["right"].setdefault(int(self._right_message[j]), []).append(k)
        found: dict[int, dict[str, np.ndarray]] = {}
        counts = {"left": 0, "right": 0}
        nxt = start
        with open_reader(self.path) as reader:
            conns = {
                r: [c for c in reader.connections if c.topic == self.topics[r]] for r in ("left", "right")
            }
            for conn, t_ns, raw in messages(reader, self.path, conns["left"] + conns["right"]):
                role = "left" if conn in conns["left"] else "right"
                n = counts[role]
                counts[role] += 1
                ks = want[role].get(n)
                if ks is None:
                    continue
                image = decode_image(deserialize(reader, raw, conn, t_ns), conn.topic)
                if image.dtype == np.uint16:
                    shift = (self.pixel_bits or 16) - 8
                    image = np.minimum(image >> shift, 255).astype(np.uint8)
                for k in ks:
                    found.setdefault(k, {})[role] = image
                while nxt in found and len(found[nxt]) == 2:
                    p = self.matched.others["pose"][nxt]
                    t = float(self.left_stamps[self.matched.reference[nxt]])
                    pair = found.pop(nxt)
                    yield RecordedPair(
                        t, pair["left"], pair["right"], self.pose_positions[p], self.pose_rotations[p]
                    )
                    nxt += 1
                if nxt >= stop:
                    return
        if nxt < stop:
            raise RecordingError(f"{self.path}: pair {nxt} of {len(self)} was not found on the second read")
