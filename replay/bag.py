"""ROS 1 (``.bag``) and ROS 2 (``.db3``, ``.mcap`` folders) recordings, read with ``rosbags``
(no ROS install; opening the file and finding the topics: ``replay.bag_files``).

* images: ``sensor_msgs/Image`` (mono8/16, bgr8, rgb8, bgra8, rgba8, YUV 4:2:2, Bayer 8/16) or
  ``sensor_msgs/CompressedImage`` (PNG, JPEG), left and right topics, or one topic of
  side-by-side pairs (a double-width image, the left camera's in its left half);
* calibration: a ``StereoCalibration`` from files, or the two ``sensor_msgs/CameraInfo``
  topics (the first message of each);
* poses of the **left camera's optical frame** in the world (z up), ROS's usual meaning
  (the orientation turns camera vectors into world vectors): ``geometry_msgs/PoseStamped``,
  ``geometry_msgs/PoseWithCovarianceStamped``, ``nav_msgs/Odometry``,
  ``geometry_msgs/TransformStamped`` (these two filtered by ``child_frame``), or
  ``tf2_msgs/TFMessage`` (``/tf``, with ``/tf_static``): the transforms on the path from
  ``world_frame`` down to ``child_frame``, composed (``replay.tf_tree``).

Times are the messages' header stamps (sorted); right images are matched to each left image
within a tolerance, the pose at each left image's stamp follows ``replay.trajectory``'s rule
(interpolated between two poses around it, or one within the tolerance), and what was dropped
is counted (``matched.describe()``). Each camera's first image is decoded when the bag is
opened, and checked against the calibration (``replay.frames.fit_image_size``).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np

from replay import pose_messages as pm
from replay.asl import RecordingError
from replay.bag_files import bag_path, deserialize, messages, open_reader, topic_connections
from swarm.formats.calibration_formats import stereo_from_camera_infos
from swarm.formats.pixel_bits import SignificantBits, to_8_bits
from swarm.formats.stereo_calibration import StereoCalibration
from swarm.streams.frames import RecordedPair, fit_image_size
from swarm.streams.image_messages import camera_info, decode_image, split_side_by_side
from swarm.streams.matching import Matched, match_stamps
from swarm.streams.tf_tree import Chain, TfError, TfTree
from swarm.streams.trajectory import MAX_GAP_S, Trajectory

BIT_SAMPLES = 30  # 16-bit images: how many of each camera's, spread over the bag, set the bits


class BagRecording:
    """A stereo recording in a ROS bag; ``pairs()`` yields matched raw pairs with poses.

    Images: the ``left`` and ``right`` topics, or ``side_by_side``, one topic of double-width
    images (left half: the left camera's; left and right are then None).
    ``calibration``: a ``StereoCalibration``, or a function of the images' (width, height)
    returning one (for a file that states no image size), or None for the CameraInfo topics
    ``left_info`` and ``right_info``. A rectified rig that states no size takes the images'.
    Raises RecordingError (or CalibrationError) naming the bag and the topic.
    """

    def __init__(
        self,
        path: str | Path,
        left: str | None,
        right: str | None,
        pose: str,
        calibration: StereoCalibration | Callable[[tuple[int, int]], StereoCalibration] | None = None,
        left_info: str | None = None,
        right_info: str | None = None,
        child_frame: str | None = None,
        tolerance_s: float = 0.01,
        world_frame: str | None = None,
        tf_static: str | None = None,
        side_by_side: str | None = None,
    ) -> None:
        self.path = bag_path(Path(path))
        if side_by_side and (left or right):
            raise RecordingError(f"{path}: give the image topics as --left and --right or as --side-by-side, "
                                 "not both")  # fmt: skip
        if not (side_by_side or (left and right)):
            raise RecordingError(f"{path}: give both image topics (--left, --right) or --side-by-side")
        images = {"stereo": side_by_side} if side_by_side else {"left": left, "right": right}
        self.topics: dict[str, str] = {**images, "pose": pose}
        if calibration is None:
            if not (left_info and right_info):
                raise RecordingError(f"{path}: give a calibration (--calib-left/--calib-right) or both "
                                     "camera_info topics (--left-info, --right-info)")  # fmt: skip
            self.topics |= {"left_info": left_info, "right_info": right_info}
        self.child_frame = child_frame
        self.pose_frames: str | None = None  # a /tf pose: its chain of frames, for the summary
        stamps: dict[str, list[float]] = {role: [] for role in (*images, "pose")}
        positions, rotations, infos = [], [], {}
        children: set[str] = set()  # the pose topic's child frames, for the errors
        first: dict[str, np.ndarray] = {}  # each image topic's first image
        unusable = 0  # pose messages of the camera that are not a pose, skipped
        with open_reader(self.path) as reader:
            conns, self._static = topic_connections(reader, self.path, self.topics, tf_static)
            bits = SignificantBits({r: sum(c.msgcount for c in conns[r]) for r in images}, BIT_SAMPLES)
            tree = TfTree() if any(c.msgtype in pm.TF_TYPES for c in conns["pose"]) else None
            if tree is None and (world_frame or tf_static):
                raise RecordingError(f"{path}: --world-frame and --tf-static are for a /tf pose topic")
            for conn, t_ns, raw in messages(reader, path, [c for cs in conns.values() for c in cs]):
                role = next(r for r, cs in conns.items() if conn in cs)
                if role in ("left_info", "right_info"):
                    if role not in infos:
                        infos[role] = camera_info(
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
                else:  # an image topic
                    image = None
                    if role not in first:  # read now: a bad image is an error before anything starts
                        image = first[role] = decode_image(msg, conn.topic)
                    if first[role].dtype == np.uint16 and bits.wants(role, len(stamps[role])):
                        bits.add(decode_image(msg, conn.topic) if image is None else image)
                    stamps[role].append(pm.stamp(msg))
        if tree is not None:  # /tf: the camera's chain of transforms, world first
            track: Trajectory | Chain = self._chain(tree, children, world_frame)
            stamps["pose"], unusable = track.stamps().tolist(), track.unusable
        else:
            track = Trajectory(stamps["pose"], positions, rotations)
        self._check_messages(stamps, infos, unusable, children)
        if side_by_side:
            where = f"{path}: topic {side_by_side}"
            first["left"], first["right"] = split_side_by_side(first.pop("stereo"), where)
            stamps["left"] = stamps["right"] = stamps.pop("stereo")
        self.calibration = self._fit_calibration(calibration, infos, first)
        # 16-bit images: a 10- or 12-bit camera's values sit in the low bits (0..4095 of 65535),
        # and their top 8 bits would be black: every image is scaled to 8 bits by the bits the
        # brightest pixel of images spread over the bag needs (a camera may start in the dark).
        self.pixel_bits = bits.bits
        self._match(stamps, tolerance_s, track, unusable)

    def _image_topic(self, side: str) -> str:
        """The topic of the ``left`` or ``right`` camera's images, as errors name it."""
        if "stereo" in self.topics:
            return f"{self.topics['stereo']} ({side} half)"
        return self.topics[side]

    def _check_messages(self, stamps: dict, infos: dict, unusable: int, children: set[str]) -> None:
        """A topic asked for with no message (of the camera: a pose topic) is named."""
        for role in self.topics:
            if stamps.get(role) if role in stamps else role in infos:
                continue
            what = (
                "no messages" if role != "pose" or not unusable else f"every message is an {pm.UNUSABLE_POSE}"
            )
            if role == "pose" and children:
                what = (
                    f"no messages with child_frame_id {self.child_frame!r}"
                    if self.child_frame
                    else "give --child-frame, the left camera's child_frame_id"
                ) + f" (child frames: {', '.join(sorted(children))})"
            raise RecordingError(f"{self.path}: topic {self.topics[role]}: {what}")

    def _fit_calibration(self, calibration, infos: dict, first: dict[str, np.ndarray]) -> StereoCalibration:
        """The calibration, checked against (or sized by) each camera's first image."""
        if calibration is None:
            calibration = stereo_from_camera_infos(infos["left_info"], infos["right_info"])
        elif callable(calibration):  # a loader that needs the images' (width, height)
            calibration = calibration(first["left"].shape[1::-1])
        for side in ("left", "right"):
            h, w = first[side].shape[:2]
            calibration = fit_image_size(calibration, w, h, f"{self.path}: topic {self._image_topic(side)}")
        return calibration

    def _match(self, stamps: dict, tolerance_s: float, track: Trajectory | Chain, unusable: int) -> None:
        """Right images and poses for the left images; what was dropped is counted."""
        # Header stamps, sorted (a driver's threads or a merged bag can put them out of order); a
        # left stamp seen twice (a republished image, a topic recorded twice) is kept once.
        ordered = {}
        for side in ("left", "right"):
            arr = np.asarray(stamps[side])
            if arr.size > 1 and np.all(arr == arr[0]):
                raise RecordingError(
                    f"{self.path}: topic {self._image_topic(side)}: all {arr.size} messages have the header "
                    f"stamp {arr[0]:.9f} (the driver does not stamp its images)"
                )
            ordered[side] = np.argsort(arr, kind="stable")
        left_sorted = np.asarray(stamps["left"])[ordered["left"]]
        first = np.r_[True, np.diff(left_sorted) > 0]
        self.left_stamps = left_sorted[first]
        self._left_message = ordered["left"][first]  # message number of each left stamp
        self._right_message = ordered["right"]
        # the pose at each left stamp (replay.trajectory's rule, for a pose topic and /tf alike)
        rows, self.pose_positions, self.pose_rotations, self.interpolated_poses = track.poses_at(
            self.left_stamps, tolerance_s, MAX_GAP_S
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
            spans = {"left": self.left_stamps, "right": np.asarray(stamps["right"]),
                     "pose": np.asarray(stamps["pose"])}  # fmt: skip
            shown = ", ".join(
                f"{self.topics['pose'] if role == 'pose' else self._image_topic(role)} "
                f"{arr.min():.3f} .. {arr.max():.3f}"
                for role, arr in spans.items()
            )
            raise RecordingError(
                f"{self.path}: no pair left after matching ({self.matched.describe()}); header stamps (s): "
                f"{shown}: are the topics stamped by one clock?"
            )

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
        roles = [r for r in ("left", "right", "stereo") if r in self.topics]
        counts = dict.fromkeys(roles, 0)
        nxt = start
        with open_reader(self.path) as reader:
            conns = {r: [c for c in reader.connections if c.topic == self.topics[r]] for r in roles}
            for conn, t_ns, raw in messages(reader, self.path, [c for r in roles for c in conns[r]]):
                role = next(r for r in roles if conn in conns[r])
                n = counts[role]
                counts[role] += 1
                sides = ("left", "right") if role == "stereo" else (role,)
                if not any(n in want[side] for side in sides):
                    continue
                image = to_8_bits(
                    decode_image(deserialize(reader, raw, conn, t_ns), conn.topic), self.pixel_bits
                )
                halves = split_side_by_side(image, conn.topic) if role == "stereo" else (image,)
                for side, half in zip(sides, halves, strict=True):
                    for k in want[side].get(n, ()):
                        found.setdefault(k, {})[side] = half
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
