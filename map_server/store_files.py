"""The store's file operations in one small layer, and the lock that keeps a store to one server.

Every change the map server's store makes on disk goes through :class:`StoreFiles`: make a
folder, write a whole new file, append to the log, cut a file, fsync a file or a folder,
rename, delete. The real layer does each with the OS and nothing more; a recording layer
(``swarm.bench.power_cut``) does the same and notes each operation, so a test can rebuild
what a power cut at any instant would have left on disk (unsynced data and names dropped).

:class:`StoreLock` holds ``store.lock`` with ``flock`` for the server's lifetime: a second
server on the same folder is refused, naming the holder's pid and host; the kernel drops the
lock when its process dies (SIGKILL or power cut included), so a stale lock never blocks a
restart. (``flock`` works across hosts on NFS v4 and on Linux's NFS v3 client through
``fcntl`` locks; other network file systems may not lock at all.)
"""

from __future__ import annotations

import errno
import fcntl
import json
import os
import socket
import time
from collections.abc import Callable
from pathlib import Path
from typing import BinaryIO

LOCK_FILE = "store.lock"
#: errno values that mean "no room": the store pauses its acks until space returns
NO_SPACE = frozenset({errno.ENOSPC, errno.EDQUOT})


class StoreFiles:
    """The store's file operations, done with the OS (subclass to observe them)."""

    def make_dir(self, path: Path) -> None:
        """Create ``path`` (and missing parents) and fsync the folder holding it, so the new
        folder's name survives a power cut."""
        missing = [p for p in (path, *path.parents) if not p.exists()]
        path.mkdir(parents=True, exist_ok=True)
        for made in reversed(missing):
            self.fsync_dir(made.parent)

    def write_file(self, path: Path, fill: Callable[[BinaryIO], None]) -> None:
        """Create (or empty) ``path``, let ``fill`` write it, flush and fsync it."""
        with open(path, "wb") as f:
            fill(f)
            f.flush()
            os.fsync(f.fileno())

    def open_append(self, path: Path) -> int:
        """A file descriptor that appends to ``path`` (which exists)."""
        return os.open(path, os.O_WRONLY | os.O_APPEND)

    def append(self, fd: int, data: bytes | memoryview) -> None:
        """Write all of ``data`` at the end of ``fd``'s file (no fsync)."""
        data = memoryview(data)
        written = 0
        while written < len(data):
            written += os.write(fd, data[written:])

    def size(self, fd: int) -> int:
        return os.lseek(fd, 0, os.SEEK_END)

    def truncate(self, fd: int, size: int) -> None:
        """Cut ``fd``'s file to ``size`` bytes and fsync it."""
        os.ftruncate(fd, size)
        os.fsync(fd)

    def truncate_path(self, path: Path, size: int) -> None:
        fd = os.open(path, os.O_RDWR)
        try:
            self.truncate(fd, size)
        finally:
            os.close(fd)

    def fsync(self, fd: int) -> None:
        os.fsync(fd)

    def close(self, fd: int) -> None:
        os.close(fd)

    def replace(self, src: Path, dst: Path) -> None:
        """Rename ``src`` over ``dst`` (atomic; durable only once the folder is fsynced)."""
        os.replace(src, dst)

    def fsync_dir(self, path: Path) -> None:
        fd = os.open(path, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)

    def unlink(self, path: Path) -> None:
        """Delete ``path`` if it is there."""
        path.unlink(missing_ok=True)

    def free_bytes(self, path: Path) -> int:
        """Bytes an unprivileged writer may still use on the file system of ``path``."""
        st = os.statvfs(path)
        return st.f_bavail * st.f_frsize


#: The layer a store uses unless told otherwise.
OS_FILES = StoreFiles()


class StoreInUse(RuntimeError):
    """Another live process holds the store's lock; the text names the folder and the holder."""


class StoreLock:
    """An exclusive ``flock`` on ``<folder>/store.lock`` naming its holder; :meth:`release` (or the
    holder's death) frees it."""

    def __init__(self, folder: Path) -> None:
        self.path = folder / LOCK_FILE
        self._fd: int | None = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(self._fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            os.close(self._fd)
            self._fd = None
            if exc.errno not in (errno.EWOULDBLOCK, errno.EACCES):
                raise
            raise StoreInUse(
                f"{folder}: store in use by another map server ({self._holder()}); stop that server, "
                "or give this one another --store folder"
            ) from None
        holder = {
            "pid": os.getpid(),
            "host": socket.gethostname(),
            "since": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        }
        os.ftruncate(self._fd, 0)
        os.pwrite(self._fd, json.dumps(holder).encode(), 0)

    def _holder(self) -> str:
        try:
            holder = json.loads(self.path.read_text() or "{}")
            return f"pid {holder['pid']} on host {holder['host']}, since {holder['since']}"
        except (OSError, ValueError, KeyError, TypeError):
            return f"its holder did not write {self.path} yet"

    def release(self) -> None:
        if self._fd is not None:
            os.close(self._fd)  # closing the descriptor drops the flock
            self._fd = None
