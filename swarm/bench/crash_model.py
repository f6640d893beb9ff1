"""What a power cut leaves on disk: a recording of the store's file operations, replayed up to
any instant with the data and names that were not yet synced dropped (in the style of the
crash-consistency checkers ALICE and CrashMonkey).

:class:`RecordingFiles` is the map server's file layer (``map_server.store_files``) that does
every operation with the OS, as the real one does, and notes it: folder made, file created,
bytes written at an offset, file cut, fsync of a file, rename, fsync of a folder, delete.
:func:`crash_states` replays the first ``cut`` operations on a model of a file system and
gives the file trees a power cut at that instant may leave:

- ``synced``: only what was made durable: a file's bytes as of its last fsync (nothing, for a
  file never synced), a folder's names as of its last fsync (a new, renamed or deleted name is
  lost until its folder is synced);
- ``all``: everything issued reached the disk (the in-order prefix of the operations);
- ``names``: the folders' names as issued, the files' bytes only as synced (metadata first,
  the classic "rename before the data" case);
- ``torn``: as ``names``, and each file that grew since its sync holds half of the bytes
  written since (a torn write);
- ``zeros``: as ``names``, and each such file has its issued length, zeros past its synced
  bytes (the size reached the disk, the data did not).

Not modelled: one file's unsynced writes reordered among themselves (beyond torn and zeroed
tails), files of one cut mixing the variants independently, sector corruption, a disk that
acknowledges an fsync it did not do, and file-system bugs. Reads go to the real files: the
live store sees its writes as a running system would.
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import BinaryIO

from map_server.store_files import StoreFiles

VARIANTS = ("synced", "all", "names", "torn", "zeros")


class RecordingFiles(StoreFiles):
    """The store's file layer, done with the OS and noted in :attr:`ops` (paths relative to
    ``root``, which exists and is durable before the first operation)."""

    def __init__(self, root: Path) -> None:
        self.root = root
        self.ops: list[tuple] = []
        self._fds: dict[int, str] = {}

    def _rel(self, path: Path) -> str:
        return str(Path(path).resolve().relative_to(self.root.resolve()))

    def note(self, *op) -> None:
        """Add an operation (or a marker of the caller's, such as an ack) to the recording."""
        self.ops.append(op)

    def make_dir(self, path: Path) -> None:
        for made in reversed([p for p in (path, *path.parents) if not p.exists()]):
            made.mkdir()
            self.note("mkdir", self._rel(made))
            self.fsync_dir(made.parent)

    def write_file(self, path: Path, fill: Callable[[BinaryIO], None]) -> None:
        rel = self._rel(path)
        with open(path, "wb") as f:
            self.note("create", rel)
            fill(_NotingFile(f, lambda offset, data: self.note("write", rel, offset, data)))
            f.flush()
            os.fsync(f.fileno())
            self.note("fsync", rel)

    def open_append(self, path: Path) -> int:
        fd = super().open_append(path)
        self._fds[fd] = self._rel(path)
        return fd

    def append(self, fd: int, data: bytes | memoryview) -> None:
        offset = os.lseek(fd, 0, os.SEEK_END)
        super().append(fd, data)
        self.note("write", self._fds[fd], offset, bytes(data))

    def truncate(self, fd: int, size: int) -> None:
        super().truncate(fd, size)
        self.note("truncate", self._fd_path(fd), size)
        self.note("fsync", self._fd_path(fd))

    def _fd_path(self, fd: int) -> str:
        return self._fds.get(fd) or self._rel(Path(os.readlink(f"/proc/self/fd/{fd}")))

    def fsync(self, fd: int) -> None:
        super().fsync(fd)
        self.note("fsync", self._fds[fd])

    def close(self, fd: int) -> None:
        self._fds.pop(fd, None)
        super().close(fd)

    def replace(self, src: Path, dst: Path) -> None:
        super().replace(src, dst)
        self.note("rename", self._rel(src), self._rel(dst))

    def fsync_dir(self, path: Path) -> None:
        super().fsync_dir(path)
        self.note("fsync_dir", self._rel(path))

    def unlink(self, path: Path) -> None:
        if path.exists():
            super().unlink(path)
            self.note("unlink", self._rel(path))


class _NotingFile:
    """A file object that reports each write (offset, bytes) and passes everything through."""

    def __init__(self, f: BinaryIO, on_write: Callable[[int, bytes], None]) -> None:
        self._f, self._on_write = f, on_write

    def write(self, data) -> int:
        offset = self._f.tell()
        n = self._f.write(data)
        self._on_write(offset, bytes(data))
        return n

    def __getattr__(self, name: str):
        return getattr(self._f, name)


@dataclass
class _Model:
    """Files (inode -> bytes) and folders (path -> {name: inode}), as issued and as durable."""

    files: dict[int, bytearray] = field(default_factory=dict)
    synced: dict[int, bytes] = field(default_factory=dict)
    dirs: dict[str, dict[str, int]] = field(default_factory=lambda: {".": {}})
    synced_dirs: dict[str, dict[str, int]] = field(default_factory=lambda: {".": {}})
    next_inode: int = 0

    def entry(self, rel: str) -> tuple[str, str]:
        parent, name = os.path.split(rel)
        return parent or ".", name

    def inode(self, rel: str) -> int:
        parent, name = self.entry(rel)
        return self.dirs[parent][name]

    def apply(self, op: tuple) -> None:
        kind = op[0]
        if kind == "mkdir":
            parent, name = self.entry(op[1])
            self.dirs[op[1]], self.synced_dirs[op[1]] = {}, {}
            self.dirs[parent][name] = -1  # a folder: its names live in dirs[path]
        elif kind == "create":
            parent, name = self.entry(op[1])
            if name in self.dirs[parent]:
                self.files[self.dirs[parent][name]][:] = b""  # open("wb") empties the same file
            else:
                self.next_inode += 1
                self.files[self.next_inode] = bytearray()
                self.dirs[parent][name] = self.next_inode
        elif kind == "write":
            content, offset, data = self.files[self.inode(op[1])], op[2], op[3]
            content.extend(b"\0" * max(0, offset - len(content)))
            content[offset : offset + len(data)] = data
        elif kind == "truncate":
            content = self.files[self.inode(op[1])]
            del content[op[2] :]
        elif kind == "fsync":
            ino = self.inode(op[1])
            self.synced[ino] = bytes(self.files[ino])
        elif kind == "rename":
            (sp, sn), (dp, dn) = self.entry(op[1]), self.entry(op[2])
            self.dirs[dp][dn] = self.dirs[sp].pop(sn)
        elif kind == "unlink":
            parent, name = self.entry(op[1])
            del self.dirs[parent][name]
        elif kind == "fsync_dir":
            self.synced_dirs[op[1]] = dict(self.dirs[op[1]])
        # any other kind is a caller's marker (an ack): no change on disk

    def tree(self, variant: str) -> dict[str, bytes | None]:
        """The files (bytes) and folders (None) a cut leaves under this variant, by path."""
        names = self.synced_dirs if variant == "synced" else self.dirs
        out: dict[str, bytes | None] = {}

        def walk(folder: str) -> None:
            for name, ino in sorted(names.get(folder, {}).items()):
                rel = name if folder == "." else f"{folder}/{name}"
                if ino == -1:
                    out[rel] = None
                    walk(rel)
                else:
                    out[rel] = self.content(ino, variant)

        walk(".")
        return out

    def content(self, ino: int, variant: str) -> bytes:
        issued, synced = bytes(self.files[ino]), self.synced.get(ino, b"")
        if variant == "all":
            return issued
        grew = len(issued) > len(synced) and issued.startswith(synced)
        if variant == "torn" and grew:
            return issued[: len(synced) + (len(issued) - len(synced)) // 2]
        if variant == "zeros" and grew:
            return synced + b"\0" * (len(issued) - len(synced))
        return synced


def crash_states(ops: list[tuple]) -> Iterator[tuple[int, str, dict[str, bytes | None]]]:
    """``(cut, variant, tree)`` for every cut 0..len(ops) (the first ``cut`` operations done)
    and every variant of :data:`VARIANTS`; a tree already given for an earlier cut or variant is
    given again only when the cut is later (the caller's acks may have grown meanwhile)."""
    model = _Model()
    seen: set[str] = set()
    for cut in range(len(ops) + 1):
        if cut:
            model.apply(ops[cut - 1])
        for variant in VARIANTS:
            tree = model.tree(variant)
            digest = _digest(tree, cut, ops)
            if digest not in seen:
                seen.add(digest)
                yield cut, variant, tree


def trees_after(ops: list[tuple]) -> dict[str, dict[str, bytes | None]]:
    """The tree of each variant a power cut right after ``ops`` leaves (repeats included)."""
    model = _Model()
    for op in ops:
        model.apply(op)
    return {variant: model.tree(variant) for variant in VARIANTS}


def _digest(tree: dict[str, bytes | None], cut: int, ops: list[tuple]) -> str:
    """A tree's fingerprint, with the number of markers (acks) before ``cut``: the same tree
    needs checking again only once more deltas were acked."""
    h = hashlib.sha256(str(sum(1 for op in ops[:cut] if op[0] == "acked")).encode())
    for rel, content in sorted(tree.items()):
        h.update(rel.encode() + b"\0" + (b"/" if content is None else hashlib.sha256(content).digest()))
    return h.hexdigest()


def materialize(tree: dict[str, bytes | None], root: Path) -> None:
    """Write ``tree`` (from :func:`crash_states`) under the empty folder ``root``."""
    for rel, content in sorted(tree.items()):
        target = root / rel
        if content is None:
            target.mkdir()
        else:
            target.write_bytes(content)
