"""Opening ROS bags with rosbags: the file or folder, its reader, its messages, each refusal one
line naming the bag (or the topic and time of a message that is not one of its type).

``open_reader`` yields rosbags' ``AnyReader``. A ROS 2 bag recorded before Iron holds no message
definitions and is read with Humble's standard types; connections whose definition the recorder
left empty are left out; a ``.db3`` or ``.mcap`` copied without its metadata.yaml is read alone.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

from replay.asl import RecordingError


def type_name(msgtype: str) -> str:
    return msgtype.replace("/msg/", "/")


def _one_line(exc: object) -> str:
    """rosbags' and its parsers' messages (a YAML error spans lines) on one line."""
    return " ".join(str(exc).split())


def bag_path(path: Path) -> Path:
    if not path.exists():
        raise RecordingError(f"{path}: no such bag")
    if path.is_file() and path.name.endswith((".db3", ".mcap", ".db3.zstd", ".mcap.zstd")):
        if path.suffix in (".db3", ".mcap") and not (path.parent / "metadata.yaml").is_file():
            return path  # copied without its metadata.yaml: rosbags reads the file alone
        return path.parent  # a ROS 2 bag is its folder (metadata.yaml); .zstd: file compression
    return path


@contextmanager
def open_reader(path: Path) -> Iterator[Any]:
    """rosbags' AnyReader on ``path``; a file it cannot read is a RecordingError naming it.

    A ROS 2 bag recorded before Iron (Foxy, Humble) holds no message definitions; its standard
    messages (the only ones read here) are read with Humble's, which these distributions share.
    """
    from rosbags.highlevel import AnyReader, AnyReaderError
    from rosbags.typesys import Stores, get_typestore

    if path.is_dir() and not (path / "metadata.yaml").is_file():
        raise RecordingError(
            f"{path}: a ROS 2 bag is a folder with its metadata.yaml beside the .db3 / .mcap files, and "
            "there is none ('ros2 bag reindex FOLDER' writes it)"
        )
    if path.suffix == ".active":
        raise RecordingError(
            f"{path}: an unfinished ROS 1 recording (rosbag record was stopped before it closed the bag): "
            "'rosbag reindex' it and rename it to .bag"
        )
    try:
        reader = AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE))
        reader.readers = [_DefinedConnections(r) for r in reader.readers]
        reader.open()
    except Exception as exc:  # rosbags' own code only; a cut-short .mcap raises its TypeError
        if not isinstance(exc, AnyReaderError | OSError):
            exc = f"{type(exc).__name__}: {exc}"
        raise RecordingError(f"{path}: not a readable ROS 1 or ROS 2 bag ({_one_line(exc)})") from None
    try:
        yield reader
    finally:
        reader.close()


class _DefinedConnections:
    """One of rosbags' bag readers, its connections without those whose message definition the
    recorder left empty (rosbag2 does so for a type it cannot find, ros2/rosbag2#1350): AnyReader
    would register such a type with no fields and refuse the whole bag on its hash, though the
    topics read here are others. (A bag with no definitions at all, Foxy's and Humble's, is read
    with the default typestore.) A topic left out is reported as not in the bag."""

    def __init__(self, reader: Any) -> None:
        self._reader = reader

    def __getattr__(self, name: str) -> Any:
        return getattr(self._reader, name)

    def __enter__(self) -> _DefinedConnections:
        self._reader.__enter__()
        return self

    def __exit__(self, *exc: object) -> Any:
        return self._reader.__exit__(*exc)

    @property
    def connections(self) -> list:
        from rosbags.interfaces import MessageDefinitionFormat

        every = self._reader.connections
        empty = [
            c for c in every if c.msgdef.format != MessageDefinitionFormat.NONE and not c.msgdef.data.strip()
        ]
        if not empty or len(empty) == len(every):
            return every
        return [c for c in every if c not in empty]


def messages(reader: Any, path: Path, connections: list) -> Iterator[tuple[Any, int, bytes]]:
    """``reader.messages(connections)``; a chunk that does not read (damaged, cut short) is a
    RecordingError naming the bag. rosbags passes its decompressors' errors on as they are (bz2's
    OSError, lz4's RuntimeError, ...), so any error of the reader here is the file's."""
    stream = reader.messages(connections=connections)
    while True:
        try:
            item = next(stream)
        except StopIteration:
            return
        except Exception as exc:
            raise RecordingError(
                f"{path}: the bag is damaged after its start ({type(exc).__name__}: {_one_line(exc)})"
            ) from None
        yield item


def deserialize(reader: Any, raw: bytes, conn: Any, t_ns: int) -> Any:
    """One message; one that does not deserialize as its type is a RecordingError naming its topic."""
    from rosbags.highlevel import AnyReaderError

    try:
        return reader.deserialize(raw, conn.msgtype)
    except AnyReaderError as exc:
        raise RecordingError(
            f"{conn.topic}: the message logged at {t_ns / 1e9:.9f} s is not a valid "
            f"{type_name(conn.msgtype)} ({len(raw)} bytes; {_one_line(exc)})"
        ) from None
