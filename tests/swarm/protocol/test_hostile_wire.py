"""Every decoder of the wire against hostile bytes, without Zenoh: any bytes, any msgpack value,
every field of every message kind mutated (Hypothesis), msgpack that is truncated, deeply
nested or declares huge lengths. A decoder returns a message or raises WireError naming what
is wrong, quickly, and never anything else (docs/protocol.md, revision 2)."""

from __future__ import annotations

import struct
import time

import msgpack
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from map_server.ledger import Rejected, validate_delta
from swarm.protocol.wire import (
    AssignReply,
    AssignRequest,
    Camera,
    Cmd,
    DeltaMessage,
    Frame,
    Pose,
    Region,
    Snapshot,
    Status,
    TruthPoses,
    WireError,
)
from tests.support.malformed_deltas import good
from tests.support.map_server_mission import small_mission

GRID = small_mission().workspace.grid()
POSE = Pose((1.0, 1.0, 0.4), (0.1, 0.0, 0.0))
CAMERA = Camera(4, 3, 2.0, 2.0, 2.0, 1.5, 0.1)


def _valid_messages() -> dict[str, tuple[type, bytes]]:
    """One valid payload of every message kind, with its class."""
    n = GRID.size
    lam = np.full(n, 2.0, np.float32)
    one = np.ones(1, np.float32)
    return {
        "delta": (DeltaMessage, good(GRID)),
        "snapshot": (Snapshot, Snapshot(GRID, lam, lam * 0.5, {"r1": {7: 3}}, {"r1": {7: [5]}}).encode()),
        "region": (Region, Region(GRID, np.array([4], np.uint32), one, one, one, one).encode()),
        "status": (Status, Status("r1", 1.0, POSE, (1.0, 2.0, 0.4), "drive", 10, (1.0, 1.0, 0.2)).encode()),
        "cmd": (Cmd, Cmd("r1", 3, 1.5, 0.3, -0.2, 0.1).encode()),
        "assign request": (AssignRequest, AssignRequest("r1", POSE).encode()),
        "assign reply": (
            AssignReply,
            AssignReply((1.0, 2.0, 0.4), (1.0, 0.0, 0.0), 3.0, True, ((1.0, 2.0),), ((3.0, 1.0),)).encode(),
        ),
        "truth": (TruthPoses, TruthPoses(2.0, {"r1": (1.0, 2.0, 0.3)}, ["r2"]).encode()),
        "depth frame": (Frame, Frame("r1", 1, 0.5, POSE, CAMERA, depth=np.ones((3, 4), np.float32)).encode()),
        "raw8 frame": (
            Frame,
            Frame(
                "r1", 1, 0.5, POSE, CAMERA, "raw8", np.zeros((3, 4), np.uint8), np.ones((3, 4), np.uint8)
            ).encode(),
        ),
        "png frame": (
            Frame,
            Frame(
                "r1", 1, 0.5, POSE, CAMERA, "png", np.zeros((3, 4), np.uint8), np.ones((3, 4), np.uint8)
            ).encode(),
        ),
    }


VALID = _valid_messages()
KINDS = sorted(VALID)

# any msgpack value: every scalar type at its extremes, nested a little
_scalars = (
    st.none()
    | st.booleans()
    | st.integers(min_value=-(2**63), max_value=2**64 - 1)
    | st.sampled_from([0, -1, 1, 2**32, 2**63 - 1, -(2**63), 2**64 - 1])
    | st.floats(allow_nan=True, allow_infinity=True)
    | st.sampled_from([float("nan"), float("inf"), -float("inf"), 0.0, -0.0, 1e308, -1e308, 5e-324])
    | st.text(max_size=10)
    | st.binary(max_size=24)
)
VALUES = st.recursive(
    _scalars,
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=6), inner, max_size=4),
    max_leaves=10,
)


def decodes_or_refuses(cls: type, payload: bytes):
    """The message, or None when the decoder refused it with a WireError; anything else fails."""
    try:
        return cls.decode(payload)
    except WireError as exc:
        assert len(str(exc)) < 400, f"an error text of {len(str(exc))} characters"
        return None


def refused_by_the_server(payload: bytes) -> None:
    """validate_delta refuses a payload under a named kind, never as an internal error."""
    try:
        validate_delta(payload, GRID, "r1")
    except Rejected as exc:
        assert exc.kind != "internal_error", exc


def _mutate(msg, path: list, action: str, value):
    """``msg`` with the field at ``path`` (keys and list positions) replaced, deleted or joined by
    an extra field."""
    if not path:
        return value
    head, rest = path[0], path[1:]
    out = dict(msg) if isinstance(msg, dict) else list(msg)
    if rest:
        out[head] = _mutate(out[head], rest, action, value)
    elif action == "delete" and isinstance(out, dict):
        del out[head]
    elif action == "extra" and isinstance(out, dict):
        out[f"{head}_extra"] = value
    else:
        out[head] = value
    return out


def _paths(value, prefix=()) -> list[tuple]:
    """Every field path of a decoded message (map keys and list positions, nested)."""
    found = []
    items = value.items() if isinstance(value, dict) else enumerate(value) if isinstance(value, list) else ()
    for key, inner in items:
        found.append((*prefix, key))
        found.extend(_paths(inner, (*prefix, key)))
    return found


FIELD_PATHS = {kind: _paths(msgpack.unpackb(VALID[kind][1], raw=False)) for kind in KINDS}
FUZZ = settings(max_examples=400, deadline=None, suppress_health_check=list(HealthCheck))


def test_valid_messages_decode():
    for kind, (cls, payload) in VALID.items():
        assert decodes_or_refuses(cls, payload) is not None, kind


@pytest.mark.slow
@FUZZ
@given(st.sampled_from(KINDS), st.data())
def test_every_field_of_every_message_mutated(kind, data):
    cls, payload = VALID[kind]
    path = data.draw(st.sampled_from(FIELD_PATHS[kind]))
    action = data.draw(st.sampled_from(["replace", "delete", "extra"]))
    msg = _mutate(msgpack.unpackb(payload, raw=False), list(path), action, data.draw(VALUES))
    mutated = msgpack.packb(msg, use_bin_type=True)
    decodes_or_refuses(cls, mutated)
    if kind == "delta":
        refused_by_the_server(mutated)


@FUZZ
@given(st.sampled_from(KINDS), VALUES)
def test_any_msgpack_value(kind, value):
    payload = msgpack.packb(value, use_bin_type=True)
    assert decodes_or_refuses(VALID[kind][0], payload) is None
    refused_by_the_server(payload)


@FUZZ
@given(st.sampled_from(KINDS), st.binary(max_size=64))
def test_any_bytes(kind, payload):
    decodes_or_refuses(VALID[kind][0], payload)
    refused_by_the_server(payload)


def _hostile_msgpack() -> list[bytes]:
    """msgpack that is truncated, deeply nested, or declares far more than it holds."""
    huge = [
        b"\xdd" + struct.pack(">I", 2**32 - 1),  # array32 of 4 billion items, none sent
        b"\xdf" + struct.pack(">I", 2**32 - 1),  # map32
        b"\xdb" + struct.pack(">I", 2**32 - 1) + b"x",  # str32
        b"\xc6" + struct.pack(">I", 2**32 - 1) + b"x",  # bin32
        b"\xc9" + struct.pack(">I", 2**32 - 1) + b"\x01",  # ext32
        b"\xd6\xff" + b"\x00" * 4,  # a msgpack timestamp (an ext type)
        b"\x81\xa1v\x01" + b"\xdd" + struct.pack(">I", 70_000) + b"\xc0" * 70_000,  # 70,000 nils
    ]
    nested = [b"\x91" * depth + b"\x01" for depth in (100, 10_000, 200_000)]
    nested += [b"\x81\xa1a" * depth + b"\x01" for depth in (100, 100_000)]
    cut = [p[:n] for _cls, p in VALID.values() for n in range(0, len(p), max(1, len(p) // 40))]
    return huge + nested + cut


@pytest.mark.parametrize("kind", KINDS)
def test_truncated_nested_and_overdeclared_msgpack_is_refused_quickly(kind):
    cls = VALID[kind][0]
    for payload in _hostile_msgpack():
        started = time.perf_counter()
        assert decodes_or_refuses(cls, payload) is None, payload[:40]
        assert time.perf_counter() - started < 2.0, payload[:40]  # ms when refused early


def _png_declaring(width: int, height: int) -> bytes:
    """A small PNG of zeros that declares ``width`` x ``height`` pixels (a decompression bomb)."""
    import zlib

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    packer = zlib.compressobj(9)
    rows = (
        b"".join(packer.compress(b"\x00" * (width + 1) * 500) for _ in range(height // 500)) + packer.flush()
    )
    header = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", rows) + chunk(b"IEND", b"")


def test_a_png_frame_declaring_a_gigapixel_is_refused_before_it_is_inflated(monkeypatch):
    """A 0.4 MB PNG declaring 20,000 x 20,000 pixels made the agent inflate 400 MB per image
    (1 s) before the shape check refused it; the header's size is checked first now."""
    import cv2

    bomb = _png_declaring(20_000, 20_000)
    assert len(bomb) < 500_000
    msg = msgpack.unpackb(VALID["png frame"][1], raw=False)
    msg["left"] = msg["right"] = bomb
    inflated = []
    real = cv2.imdecode
    monkeypatch.setattr(cv2, "imdecode", lambda *a: inflated.append(1) or real(*a))
    with pytest.raises(
        WireError, match=r"not an 8-bit PNG of shape \(3, 4\) \(got a header of shape \(20000, 20000\)\)"
    ):
        Frame.decode(msgpack.packb(msg, use_bin_type=True))
    assert not inflated
    assert Frame.decode(VALID["png frame"][1]).left.shape == (3, 4) and inflated
