"""What every command shares: the error line users see, the check of Zenoh endpoints, and
subcommand parsers that add their arguments only when used (so that ``swarm --help`` does not
import the roles, OpenCV and the compiled kernels to describe commands it does not run), the
files shipped in the repository that commands default to, and argparse's integer bounds."""

from __future__ import annotations

import argparse
import re
import sys
from collections.abc import Callable
from pathlib import Path

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


class LazyParser(argparse.ArgumentParser):
    """An argument parser some of whose arguments are added only when it is used.

    ``defer(add)`` keeps ``add(parser)`` until the parser parses its part of the command line
    or formats its help, so a subcommand whose arguments need heavy imports (a role's
    defaults, OpenCV's modes) costs nothing to a command line that does not name it. Its
    subparsers are LazyParsers too. :func:`complete` adds every deferred argument of a tree.
    """

    def __init__(self, *args, **kwargs) -> None:
        super().__init__(*args, **kwargs)
        self._deferred: list[Callable[[argparse.ArgumentParser], None]] = []

    def defer(self, add: Callable[[argparse.ArgumentParser], None]) -> None:
        self._deferred.append(add)

    def complete(self) -> None:
        """Add the deferred arguments of this parser (not of its subparsers)."""
        while self._deferred:
            self._deferred.pop(0)(self)

    def parse_known_args(self, args=None, namespace=None):
        self.complete()
        return super().parse_known_args(args, namespace)

    def format_help(self) -> str:
        self.complete()
        return super().format_help()

    def format_usage(self) -> str:
        self.complete()
        return super().format_usage()


def complete(parser: argparse.ArgumentParser) -> argparse.ArgumentParser:
    """Add every deferred argument of ``parser`` and of all its subparsers; returns ``parser``."""
    if isinstance(parser, LazyParser):
        parser.complete()
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for sub in action.choices.values():
                complete(sub)
    return parser


def bundled(relative: Path) -> Path:
    """A file shipped in the repository, from the project folder or beside an editable install
    (``relative`` itself when neither has it: the benchmark then says it is missing)."""
    beside_install = Path(__file__).resolve().parents[2] / relative
    return next((p for p in (relative, beside_install) if p.exists()), relative)


def at_least(lowest: int):
    """An argparse type: an integer of at least ``lowest`` (else argparse's one-line error)."""

    def parse(text: str) -> int:
        value = int(text)
        if value < lowest:
            raise argparse.ArgumentTypeError(f"must be at least {lowest:,} (got {value})")
        return value

    parse.__name__ = "integer"  # argparse's word for a value it cannot parse
    return parse
