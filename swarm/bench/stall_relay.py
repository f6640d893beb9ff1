"""A TCP relay that stops draining: the slow subscriber of ``swarm bench stall`` and its tests.

:class:`StallRelay` listens on a loopback port and joins each connection it accepts to the
target endpoint (the map server's), copying bytes both ways. After :meth:`StallRelay.stall`
it stops reading what the target sends (its client's requests still go through, so the
target's session stays alive): the target's TCP send buffer, then its Zenoh queue for that
link, fill up, as they do for a subscriber on a slow or frozen link. A Zenoh session connected
through the relay is then a subscriber that does not drain. With ``stall_from="client"`` it
stops reading what the client sends instead (a publisher whose link froze).
:meth:`StallRelay.resume` drains again; :meth:`StallRelay.close` ends it.
"""

from __future__ import annotations

import socket
import threading

CHUNK = 64 << 10


class StallRelay:
    """A loopback TCP relay to ``target`` (host, port); ``endpoint``: the Zenoh endpoint to use.
    ``stall_from``: whose bytes a stall stops reading, "target" (default) or "client"."""

    def __init__(self, target: tuple[str, int], stall_from: str = "target") -> None:
        if stall_from not in ("target", "client"):
            raise ValueError(f"stall_from must be 'target' or 'client', got {stall_from!r}")
        self.target = target
        self._stall_downstream = stall_from == "target"
        self._listener = socket.create_server(("127.0.0.1", 0))
        self.port = self._listener.getsockname()[1]
        self.endpoint = f"tcp/127.0.0.1:{self.port}"
        self._stalled = threading.Event()
        self._closed = threading.Event()
        self._sockets: list[socket.socket] = []
        #: bytes copied from the target to the client (what the subscriber received)
        self.bytes_down = 0
        threading.Thread(target=self._accept, name="stall-relay", daemon=True).start()

    def stall(self) -> None:
        """Stop reading the stalled side's bytes, until :meth:`resume` or :meth:`close`."""
        self._stalled.set()

    def resume(self) -> None:
        """Read and forward again what waited."""
        self._stalled.clear()

    def close(self) -> None:
        """Close the listener and every connection."""
        self._closed.set()
        self._stalled.clear()
        for s in [self._listener, *self._sockets]:
            try:
                s.close()
            except OSError:
                pass

    def _accept(self) -> None:
        while not self._closed.is_set():
            try:
                client, _ = self._listener.accept()
                upstream = socket.create_connection(self.target, timeout=5.0)
                upstream.settimeout(None)
            except OSError:
                return
            self._sockets += [client, upstream]
            threading.Thread(target=self._pump, args=(client, upstream, False), daemon=True).start()
            threading.Thread(target=self._pump, args=(upstream, client, True), daemon=True).start()

    def _pump(self, src: socket.socket, dst: socket.socket, downstream: bool) -> None:
        """Copy ``src`` to ``dst``; the pump of the stalled side stops reading while stalled."""
        stallable = downstream == self._stall_downstream
        try:
            while not self._closed.is_set():
                if stallable and self._stalled.is_set():
                    self._closed.wait(0.1)
                    continue
                data = src.recv(CHUNK)
                if not data:
                    break
                dst.sendall(data)
                if downstream:
                    self.bytes_down += len(data)
        except OSError:
            pass
        finally:
            for s in (src, dst):
                try:
                    s.shutdown(socket.SHUT_RDWR)
                except OSError:
                    pass
