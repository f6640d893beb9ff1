"""Bag files as they reach us, read by ``replay.bag``: ROS 1 and ROS 2 (zstd-compressed, without
message definitions, without metadata.yaml), and damaged or unreadable ones named on one line."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from replay.asl import RecordingError
from replay.bag import BagRecording
from tests.support.driver_bags import CALIB, DriverBag, _bag, gray_pattern, record_stereo

pytest.importorskip("rosbags")


@pytest.mark.parametrize(
    ("name", "content", "error"),
    [
        ("run.bag", b"not a bag", r"run.bag: not a readable ROS 1 or ROS 2 bag \(File magic is invalid"),
        (
            "run.bag.active",
            b"#ROSBAG V2.0\n",
            r"run.bag.active: an unfinished ROS 1 recording .*rosbag reindex",
        ),
        ("ros2/run_0.mcap", b"\x89MCAP0\r\n", r"run_0.mcap: not a readable ROS 1 or ROS 2 bag"),
        ("ros2/run_0.db3.zstd", b"\x28\xb5\x2f\xfd", r"ros2: a ROS 2 bag is a folder with its metadata.yaml"),
    ],
)
def test_a_bag_that_cannot_be_read_is_named(tmp_path, name, content, error):
    """A damaged file, an unfinished ROS 1 recording, a .mcap copied without its metadata.yaml."""
    path = tmp_path / name
    path.parent.mkdir(exist_ok=True)
    path.write_bytes(content)
    with pytest.raises(RecordingError, match=error):
        BagRecording(path, "/left", "/right", "/pose", CALIB)


def test_a_truncated_ros1_bag_is_named(tmp_path):
    """rosbag record killed: the end of the file (the index) is missing."""
    path = _bag(tmp_path, 1)
    with DriverBag(path, 1) as bag:
        record_stereo(bag, [1.0, 1.05])
    path.write_bytes(path.read_bytes()[:3000])
    with pytest.raises(RecordingError, match=r"b.bag: not a readable ROS 1 or ROS 2 bag"):
        BagRecording(path, "/left", "/right", "/pose", CALIB)


@pytest.mark.parametrize("storage", ["SQLITE3", "MCAP"])
def test_a_file_compressed_ros2_bag_is_read_from_its_zstd_file(tmp_path, storage):
    """ros2 bag record --compression-mode file leaves run_0.db3.zstd (or .mcap.zstd) beside
    metadata.yaml; naming that file, as one names a .db3, said 'Unrecognized storage format'."""
    from rosbags.rosbag2 import writer

    path = tmp_path / "run"
    bag = DriverBag(tmp_path / "unused", 2)
    bag.writer = writer.Writer(path, version=9, storage_plugin=getattr(writer.StoragePlugin, storage))
    bag.writer.set_compression(writer.CompressionMode.FILE, writer.CompressionFormat.ZSTD)
    with bag:
        record_stereo(bag, [1.0, 1.05])
    (data,) = path.glob("*.zstd")
    rec = BagRecording(data, "/left", "/right", "/pose", CALIB)
    assert [p.t for p in rec.pairs()] == pytest.approx([1.0, 1.05])


def _as_recorded_by_humble(folder: Path) -> None:
    """Rewrite a ROS 2 bag as rosbag2 before Iron writes it: metadata version 5, no type hashes,
    and no message definitions in the .db3 (schema 3: no message_definitions table)."""
    import sqlite3

    import yaml

    meta_path = folder / "metadata.yaml"
    meta = yaml.safe_load(meta_path.read_text())
    info = meta["rosbag2_bagfile_information"]
    info["version"] = 5
    for topic in info["topics_with_message_count"]:
        topic["topic_metadata"].pop("type_description_hash", None)
    meta_path.write_text(yaml.safe_dump(meta))
    for db in folder.glob("*.db3"):
        con = sqlite3.connect(db)
        con.executescript(
            "DROP TABLE message_definitions;"
            "CREATE TABLE t2(id INTEGER PRIMARY KEY, name TEXT NOT NULL, type TEXT NOT NULL,"
            " serialization_format TEXT NOT NULL, offered_qos_profiles TEXT NOT NULL);"
            "INSERT INTO t2 SELECT id, name, type, serialization_format, offered_qos_profiles FROM topics;"
            "DROP TABLE topics; ALTER TABLE t2 RENAME TO topics; UPDATE schema SET schema_version = 3;"
        )
        con.close()


@pytest.mark.slow
def test_a_ros2_bag_without_message_definitions_is_read(tmp_path):
    """Bags of Foxy and Humble carry no message definitions: rosbags refused them with 'Bag
    contains no type definitions' (mbpeterson70/robotdatapy#30); the standard types are known."""
    path = _bag(tmp_path, 2)
    with DriverBag(path, 2) as bag:
        record_stereo(bag, [1.0, 1.05])
    want = [
        (p.left.copy(), p.right.copy()) for p in BagRecording(path, "/left", "/right", "/pose", CALIB).pairs()
    ]
    _as_recorded_by_humble(path)
    got = list(BagRecording(path, "/left", "/right", "/pose", CALIB).pairs())
    assert len(got) == len(want) == 2
    for pair, (left, right) in zip(got, want, strict=True):
        assert np.array_equal(pair.left, left) and np.array_equal(pair.right, right)


@pytest.mark.parametrize("ros", [1, 2])
@pytest.mark.parametrize("role", ["left", "pose"])
def test_a_message_that_does_not_deserialize_is_named_with_its_topic(tmp_path, ros, role):
    """A message cut short (a recorder killed mid-write, a type whose definition changed) raised
    rosbags' AnyReaderError as a traceback."""
    path = _bag(tmp_path, ros)
    with DriverBag(path, ros) as bag:
        record_stereo(bag, [1.0, 1.05])
        bag.writer.write(bag.conns[f"/{role}"], int(1.1e9), b"\x01\x02\x03")
    with pytest.raises(
        RecordingError, match=rf"^/{role}: the message logged at 1.100000000 s is not a valid "
    ):
        list(BagRecording(path, "/left", "/right", "/pose", CALIB).pairs())


@pytest.mark.parametrize(("compression", "magic"), [("BZ2", b"BZh"), ("LZ4", b"\x04\x22\x4d\x18")])
def test_a_damaged_compressed_chunk_is_named(tmp_path, compression, magic):
    """A ROS 1 bag of bz2 / lz4 chunks reads as the uncompressed one; a chunk damaged after the
    start raised bz2's OSError or lz4's RuntimeError as a traceback (rosbags passes them on)."""
    from rosbags.rosbag1 import Writer

    path = _bag(tmp_path, 1)
    bag = DriverBag(path, 1)
    bag.writer.set_compression(getattr(Writer.CompressionFormat, compression))
    bag.writer.chunk_threshold = 200  # several chunks
    with bag:
        record_stereo(bag, [1.0 + 0.05 * k for k in range(6)])
    pairs = list(BagRecording(path, "/left", "/right", "/pose", CALIB).pairs())
    assert len(pairs) == 6 and np.array_equal(pairs[5].left, gray_pattern(5))
    raw = bytearray(path.read_bytes())
    at = raw.find(magic, len(raw) // 2)
    raw[at + 8 : at + 60] = b"\xff" * 52
    path.write_bytes(bytes(raw))
    with pytest.raises(RecordingError, match=r"b.bag: the bag is damaged after its start \("):
        list(BagRecording(path, "/left", "/right", "/pose", CALIB).pairs())


@pytest.mark.parametrize(
    ("metadata", "words"),
    [
        ("rosbag2_bagfile_information: [\n", "Could not load YAML"),  # PyYAML's error spans lines
        ("foo: 1\n", "rosbag2_bagfile_information"),
    ],
)
def test_a_damaged_metadata_yaml_is_named_on_one_line(tmp_path, metadata, words):
    path = _bag(tmp_path, 2)
    with DriverBag(path, 2) as bag:
        record_stereo(bag, [1.0])
    (path / "metadata.yaml").write_text(metadata)
    with pytest.raises(RecordingError, match="not a readable ROS 1 or ROS 2 bag") as info:
        BagRecording(path, "/left", "/right", "/pose", CALIB)
    assert words in str(info.value) and "\n" not in str(info.value), str(info.value)


def test_a_custom_topic_with_an_empty_definition_does_not_refuse_the_bag(tmp_path):
    """rosbag2 leaves the definition of a type it cannot find empty (ros2/rosbag2#1922, #1350)
    but stores its hash: rosbags refused the whole bag on that hash, though the stereo topics are
    standard ones with good definitions."""
    import sqlite3

    from rosbags.typesys import get_types_from_msg

    path = _bag(tmp_path, 2)
    bag = DriverBag(path, 2)
    bag.store.register(
        get_types_from_msg("float64 exposure\nint32 gain\n", "realsense2_camera_msgs/msg/Metadata")
    )
    with bag:
        record_stereo(bag, [1.0, 1.05])
        meta = bag.store.types["realsense2_camera_msgs/msg/Metadata"](exposure=1.0, gain=2)
        bag.write("/meta", "realsense2_camera_msgs/msg/Metadata", meta, 1.0)
    con = sqlite3.connect(next(path.glob("*.db3")))
    con.execute(
        "UPDATE message_definitions SET encoded_message_definition = '' WHERE topic_type LIKE 'realsense%'"
    )
    con.commit()
    con.close()
    pairs = list(BagRecording(path, "/left", "/right", "/pose", CALIB).pairs())
    assert len(pairs) == 2 and np.array_equal(pairs[1].left, gray_pattern(1))
    with pytest.raises(RecordingError, match=r"topic /meta \(pose\) is not in the bag"):
        BagRecording(path, "/left", "/right", "/meta", CALIB)


@pytest.mark.slow
@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_a_ros2_bag_file_copied_without_its_metadata_is_read(tmp_path, storage):
    """A .mcap or .db3 copied alone (its metadata.yaml left behind) was refused with 'ros2 bag
    reindex'; rosbags reads either file by itself."""
    from rosbags.rosbag2 import StoragePlugin, Writer

    path = _bag(tmp_path, 2)
    bag = DriverBag(path, 2)
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    bag.writer = Writer(path, version=9, storage_plugin=plugin)
    with bag:
        record_stereo(bag, [1.0, 1.05])
    (single,) = [f for f in path.iterdir() if f.suffix in (".db3", ".mcap")]
    alone = tmp_path / "copied" / single.name
    alone.parent.mkdir()
    alone.write_bytes(single.read_bytes())
    want = list(BagRecording(path, "/left", "/right", "/pose", CALIB).pairs())
    got = list(BagRecording(alone, "/left", "/right", "/pose", CALIB).pairs())
    assert len(got) == len(want) == 2
    for a, b in zip(got, want, strict=True):
        assert np.array_equal(a.left, b.left) and np.array_equal(a.right, b.right)
