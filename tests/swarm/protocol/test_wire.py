"""Wire protocol v1: round trips, little-endian raw arrays, and rejection of malformed input."""

from __future__ import annotations

import math

import msgpack
import numpy as np
import pytest

from swarm.map.grid import Grid
from swarm.protocol.wire import (
    AssignReply,
    AssignRequest,
    Camera,
    Cmd,
    DeltaMessage,
    Frame,
    Pose,
    Snapshot,
    Status,
    TruthPoses,
    WireError,
)

CAMERA = Camera(width=8, height=6, fx=7.0, fy=7.0, cx=3.5, cy=2.5, baseline=0.09)
POSE = Pose((1.0, 2.0, 0.4), (0.3, 0.0, 0.0))


def stereo_frame(encoding: str = "raw8") -> Frame:
    rng = np.random.default_rng(0)
    left = rng.integers(0, 256, (6, 8), dtype=np.uint8)
    right = rng.integers(0, 256, (6, 8), dtype=np.uint8)
    return Frame("r1", 3, 1.5, POSE, CAMERA, encoding, left=left, right=right)


def tamper(payload: bytes, **changes) -> bytes:
    msg = msgpack.unpackb(payload, raw=False, strict_map_key=False)
    for k, v in changes.items():
        if v is None:
            del msg[k]
        else:
            msg[k] = v
    return msgpack.packb(msg, use_bin_type=True)


@pytest.mark.parametrize("encoding", ["raw8", "png"])
def test_stereo_frame_round_trip(encoding):
    frame = stereo_frame(encoding)
    back = Frame.decode(frame.encode())
    assert (back.robot, back.seq, back.t, back.pose, back.camera) == ("r1", 3, 1.5, POSE, CAMERA)
    assert back.encoding == encoding and not back.is_depth
    np.testing.assert_array_equal(back.left, frame.left)
    np.testing.assert_array_equal(back.right, frame.right)


def test_raw_arrays_are_little_endian_bytes():
    frame = stereo_frame()
    msg = msgpack.unpackb(frame.encode(), raw=False)
    assert msg["v"] == 1
    assert msg["left"] == frame.left.tobytes()
    depth = np.array([[1.5, np.nan]], dtype=">f4")  # big-endian input is converted
    cam = Camera(2, 1, 1.0, 1.0, 0.5, 0.0, 0.0)
    msg = msgpack.unpackb(Frame("r", 1, 0.0, POSE, cam, depth=depth).encode(), raw=False)
    assert msg["encoding"] == "f32"
    assert msg["depth"][:4] == np.float32(1.5).astype("<f4").tobytes()


def test_depth_frame_keeps_nan():
    depth = np.linspace(0.5, 4.0, 48, dtype=np.float32).reshape(6, 8)
    depth[0, :3] = np.nan
    back = Frame.decode(Frame("r2", 1, 0.0, POSE, CAMERA, depth=depth).encode())
    assert back.is_depth and back.left is None
    np.testing.assert_array_equal(back.depth, depth)


def test_frame_rejects_malformed_input():
    good = stereo_frame().encode()
    cases = {
        "missing field 'seq'": tamper(good, seq=None),
        "unsupported version 2": tamper(good, v=2),
        "left has 47 bytes, expected 48": tamper(good, left=b"\0" * 47),
        "pose.xyz[1] must be finite": tamper(good, pose={"xyz": [0, math.nan, 0], "ypr": [0, 0, 0]}),
        "unknown encoding 'jpeg'": tamper(good, encoding="jpeg"),
        "camera needs fx, fy > 0": tamper(good, camera={**CAMERA.to_wire(), "fx": -1.0}),
        "seq must be an integer": tamper(good, seq="3"),
    }
    for reason, payload in cases.items():
        with pytest.raises(WireError, match=reason.replace("[", r"\[").replace("]", r"\]")):
            Frame.decode(payload)
    with pytest.raises(WireError, match="not a msgpack payload"):
        Frame.decode(b"\xc1garbage")
    with pytest.raises(WireError, match="payload must be a map"):
        Frame.decode(msgpack.packb([1, 2]))
    with pytest.raises(WireError, match="not an 8-bit PNG"):
        Frame.decode(tamper(stereo_frame("png").encode(), left=b"not a png"))
    with pytest.raises(WireError, match="camera says"):
        Frame(
            "r", 1, 0.0, POSE, CAMERA, left=np.zeros((5, 8), np.uint8), right=np.zeros((5, 8), np.uint8)
        ).encode()


def test_cmd_status_truth_assign_round_trip():
    cmd = Cmd("r1", 7, 3.5, 0.25, -0.5)
    assert Cmd.decode(cmd.encode()) == cmd
    # "v" is the protocol version, so the speed travels as "speed".
    assert msgpack.unpackb(cmd.encode())["v"] == 1
    assert msgpack.unpackb(cmd.encode())["speed"] == 0.25
    with pytest.raises(WireError, match="omega must be finite"):
        Cmd.decode(tamper(cmd.encode(), omega=math.inf))
    assert cmd.tilt is None and "tilt" not in msgpack.unpackb(cmd.encode())
    tilted = Cmd("r1", 8, 4.0, 0.0, 0.0, tilt=-0.6)
    assert Cmd.decode(tilted.encode()) == tilted
    with pytest.raises(WireError, match="tilt must be finite"):
        Cmd.decode(tamper(tilted.encode(), tilt=math.nan))
    with pytest.raises(WireError, match="tilt must be within"):
        Cmd.decode(tamper(tilted.encode(), tilt=2.0))
    status = Status("r1", 3.5, POSE, (1.0, 2.0, 0.0), "exploring", 1234)
    assert Status.decode(status.encode()) == status
    idle = Status("r1", 3.5, POSE, None, "idle", 0)
    assert Status.decode(idle.encode()) == idle
    truth = TruthPoses(2.0, {"r1": (1.0, 2.0, 0.5), "r2": (0.0, 0.0, 0.0)}, ["r2"])
    assert TruthPoses.decode(truth.encode()) == truth
    request = AssignRequest("r1", POSE)
    assert AssignRequest.decode(request.encode()) == request
    reply = AssignReply((1.0, 2.0, 0.4), (0.0, 1.0, 0.0), 12.5)
    assert AssignReply.decode(reply.encode()) == reply
    assert AssignReply.decode(AssignReply(None, None, 0.0).encode()).target is None


def test_the_view_additions_travel_and_are_optional():
    """Status.view, AssignReply.views and .goals, additions to protocol v1: absent means none."""
    looking = Status("r1", 3.5, POSE, (1.0, 2.0, 0.0), "drive", 10, view=(3.05, 1.15, 1.85))
    assert Status.decode(looking.encode()) == looking
    older = msgpack.unpackb(looking.encode())
    del older["view"]
    assert Status.decode(msgpack.packb(older)).view is None
    reply = AssignReply(None, None, 0.0, views=((3.05, 1.15), (5.25, 2.95)))
    assert AssignReply.decode(reply.encode()) == reply
    oldest = msgpack.packb({"v": 1, "target": None, "gaze": None, "utility": 0.0})
    assert AssignReply.decode(oldest).views == ()
    bad = {
        "'views' must be a list": 3,
        r"views\[1\] must be \[x, y\]": [[1.0, 2.0], [1.0]],
        r"views\[0\] must be finite": [[math.nan, 2.0]],
        "at most 4096": [[0.0, 0.0]] * 4097,
    }
    for reason, views in bad.items():
        with pytest.raises(WireError, match=reason):
            AssignReply.decode(tamper(reply.encode(), views=views))
    # goals: where the other robots are heading, the same form, at most 256 points
    reply = AssignReply(None, None, 0.0, views=((3.05, 1.15),), goals=((1.0, 2.0), (6.5, 3.25)))
    assert AssignReply.decode(reply.encode()) == reply
    assert AssignReply.decode(oldest).goals == ()
    bad = {
        "'goals' must be a list": {"x": 1},
        r"goals\[0\] must be \[x, y\]": [[1.0, 2.0, 3.0]],
        r"goals\[1\] must be finite": [[1.0, 2.0], [math.inf, 0.0]],
        "at most 256": [[0.0, 0.0]] * 257,
    }
    for reason, goals in bad.items():
        with pytest.raises(WireError, match=reason):
            AssignReply.decode(tamper(reply.encode(), goals=goals))
    with pytest.raises(WireError, match="view"):
        Status.decode(tamper(looking.encode(), view=[1.0, math.inf, 0.0]))


def test_delta_round_trip_and_checks():
    grid = Grid((0.0, 0.0, 0.0), 0.1, (4, 3, 2))
    delta = DeltaMessage(
        "r1", 1_700_000_000_000_000_000, 1, 0.5, grid,
        idx=np.array([0, 5, 23], np.uint32),
        dlam=np.array([1.0, 2.0, 3.0], np.float32),
        deta=np.array([0.5, -1.0, 3.0], np.float32),
    )  # fmt: skip
    back = DeltaMessage.decode(delta.encode())
    assert (back.robot, back.epoch, back.seq, back.grid) == ("r1", delta.epoch, 1, grid)
    for name in ("idx", "dlam", "deta"):
        np.testing.assert_array_equal(getattr(back, name), getattr(delta, name))
    payload = delta.encode()
    with pytest.raises(WireError, match="voxel index 24 outside grid of 24"):
        DeltaMessage.decode(tamper(payload, idx=np.array([0, 5, 24], "<u4").tobytes()))
    with pytest.raises(WireError, match="dlam has 8 bytes, expected 12"):
        DeltaMessage.decode(tamper(payload, dlam=np.zeros(2, "<f4").tobytes()))
    with pytest.raises(WireError, match="information cannot be negative"):
        DeltaMessage.decode(tamper(payload, dlam=np.array([1, -1, 1], "<f4").tobytes()))
    with pytest.raises(WireError, match="must be finite"):
        DeltaMessage.decode(tamper(payload, deta=np.array([1, np.nan, 1], "<f4").tobytes()))
    with pytest.raises(WireError, match="seq must be >= 1"):
        DeltaMessage.decode(tamper(payload, seq=0))
    with pytest.raises(WireError, match="grid.shape"):
        DeltaMessage.decode(tamper(payload, grid={"origin": [0, 0, 0], "voxel": 0.1, "shape": [4, 3]}))


def test_snapshot_round_trip():
    grid = Grid((0.0, 0.0, 0.0), 0.1, (2, 2, 2))
    snap = Snapshot(
        grid, np.full(8, 0.2, np.float32), np.full(8, 0.1, np.float32), {"r1": {17: 4}}, {"r1": {17: [7, 6]}}
    )
    back = Snapshot.decode(snap.encode())
    assert back.acks == {"r1": {17: 4}} and back.above == {"r1": {17: [6, 7]}}
    assert Snapshot.decode(tamper(snap.encode(), above=None)).above == {}  # optional: older servers
    with pytest.raises(WireError, match="above must be"):
        Snapshot.decode(tamper(snap.encode(), above={"r1": {"17": 5}}))
    with pytest.raises(WireError, match="map key"):  # keys are strings (revision 2): epochs in decimal
        Snapshot.decode(tamper(snap.encode(), acks={"r1": {17: 4}}))
    with pytest.raises(WireError, match="decimal string"):
        Snapshot.decode(tamper(snap.encode(), acks={"r1": {"1_7": 4}}))
    assert msgpack.unpackb(snap.encode())["acks"] == {"r1": {"17": 4}}  # msgpack's strict default reads it
    np.testing.assert_array_equal(back.lam, snap.lam)
    with pytest.raises(WireError, match="lam has 28 bytes"):
        Snapshot.decode(tamper(snap.encode(), lam=np.zeros(7, "<f4").tobytes()))


def test_pose_frames():
    forward = np.array([1.0, 0.0, 0.0])
    turned = Pose((0, 0, 0), (math.pi / 2, 0.0, 0.0))
    np.testing.assert_allclose(turned.rotation() @ forward, [0, 1, 0], atol=1e-12)
    down = Pose((0, 0, 0), (0.0, 0.3, 0.0))
    assert (down.rotation() @ forward)[2] == pytest.approx(-math.sin(0.3))
    # The optical z axis is the body's forward axis, optical x its right, optical y its down.
    r = turned.optical_rotation()
    np.testing.assert_allclose(r @ [0, 0, 1], [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(r @ [1, 0, 0], [1, 0, 0], atol=1e-12)
    np.testing.assert_allclose(r @ [0, 1, 0], [0, 0, -1], atol=1e-12)


def test_grid_matches_across_rounding_but_not_across_voxels():
    """Every role tests grids with Grid.matches: YAML/msgpack rounding passes, another grid does not."""
    grid = Grid((18.0, 0.0, 0.0), 0.1, (122, 80, 22))
    rounded = Grid((18.0 + 1e-9, 1e-12, 0.0), 0.1 * (1 + 1e-9), (122, 80, 22))
    assert grid.matches(rounded) and rounded.matches(grid)
    assert grid.matches(Grid.from_dict(msgpack.unpackb(msgpack.packb(grid.to_dict()))))
    assert not grid.matches(Grid((18.05, 0.0, 0.0), 0.1, (122, 80, 22)))  # half a voxel off
    assert not grid.matches(Grid((18.0, 0.0, 0.0), 0.1, (122, 80, 23)))
    assert not grid.matches(Grid((18.0, 0.0, 0.0), 0.1001, (122, 80, 22)))


def test_a_frame_built_as_docs_protocol_md_shows_it_decodes_and_its_answer_reads_back():
    # a driver in another language builds the map by hand (docs/protocol.md, "A robot's frames")
    from swarm.protocol.wire import Cmd, Frame

    left = np.arange(120 * 160, dtype=np.uint32).astype(np.uint8).reshape(120, 160)
    doc_frame = {
        "v": 1,
        "robot": "r1",
        "seq": 42,
        "t": 21.0,
        "pose": {"xyz": [1.0, 5.0, 0.4], "ypr": [0.0, 0.0, 0.0]},
        "camera": {"width": 160, "height": 120, "fx": 138.564, "fy": 138.564, "cx": 79.5, "cy": 59.5,
                   "baseline": 0.09},
        "encoding": "raw8",
        "left": left.tobytes(),
        "right": left[:, ::-1].tobytes(),
    }  # fmt: skip
    frame = Frame.decode(msgpack.packb(doc_frame, use_bin_type=True))
    assert (frame.robot, frame.seq, frame.t, frame.camera.fx) == ("r1", 42, 21.0, 138.564)
    np.testing.assert_array_equal(frame.left, left)
    np.testing.assert_array_equal(frame.right[0], left[0, ::-1])  # rows top to bottom
    answer = msgpack.unpackb(Cmd("r1", 42, 21.0, 0.35, -0.2).encode(), raw=False)
    assert answer == {"v": 1, "robot": "r1", "seq": 42, "t": 21.0, "speed": 0.35, "omega": -0.2}
