"""What every command shares: the error line users see, and the check of Zenoh endpoints."""

from __future__ import annotations

import re
import sys

#: Zenoh link protocols whose address is HOST:PORT.
_HOST_PORT_PROTOCOLS = ("tcp", "udp", "tls", "quic", "ws")
#: Other Zenoh link protocols, passed on as they are.
_OTHER_PROTOCOLS = ("unixsock-stream", "unixpipe", "serial", "vsock")
_HOST_PORT = re.compile(r"^(\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9_.-]+):(\d+)$")


def fail(message: str) -> int:
    """Print ``swarm: error: LINE`` on stderr for each line of MESSAGE; the exit status 2 of a user error."""
    for line in str(message).splitlines() or [""]:
        print(f"swarm: error: {line}", file=sys.stderr)
    return 2


def endpoint_problem(text: str) -> str | None:
    """Why ``text`` is not a Zenoh endpoint (``PROTOCOL/ADDRESS``, e.g. ``tcp/127.0.0.1:7447``), or None."""
    protocol, slash, rest = text.partition("/")
    address = rest.split("?", 1)[0].split("#", 1)[0]
    if not slash:
        if _HOST_PORT.match(text):
            return f"an endpoint names its protocol: write tcp/{text}"
        return "an endpoint is PROTOCOL/ADDRESS, e.g. tcp/127.0.0.1:7447"
    if protocol in _OTHER_PROTOCOLS:
        return None if address else f"{protocol}/ needs an address"
    if protocol not in _HOST_PORT_PROTOCOLS:
        known = ", ".join(_HOST_PORT_PROTOCOLS + _OTHER_PROTOCOLS)
        return f"unknown protocol {protocol!r} (Zenoh knows {known})"
    match = _HOST_PORT.match(address)
    if not match:
        return f"{protocol}/ needs HOST:PORT, e.g. {protocol}/127.0.0.1:7447"
    if not 0 <= int(match.group(2)) <= 65535:
        return f"port {match.group(2)} is not in 0..65535"
    return None


def zenoh_message(text: str) -> str:
    """A Zenoh error made one line, without the Rust source locations it carries."""
    text = re.sub(r" at /\S+\.rs:\d+\.?", "", str(text))
    return " ".join(text.split())
