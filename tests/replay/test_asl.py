"""Replay: timestamp matching, pose conventions, depth of a real EuRoC pair against the floor, and a
few EuRoC frames through a real agent and map server over loopback Zenoh."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from swarm.map.rotation import rotation_zyx
from swarm.streams.matching import match_stamps
from swarm.streams.poses import camera_from_body, quaternion_matrix, wire_pose
from tests.support.euroc_replay import EUROC_MINI as EUROC  # four real pairs (its README)


def test_matching_drops_a_missing_right_frame_and_counts_it():
    left = np.arange(10) * 0.05
    right = np.delete(left, 4) + 0.001  # frame 4 of the right camera was lost
    poses = np.arange(0, 0.5, 0.01)
    m = match_stamps(left, {"right": right, "pose": poses}, tolerance=0.004)
    assert m.reference.tolist() == [0, 1, 2, 3, 5, 6, 7, 8, 9]
    assert m.others["right"].tolist() == [0, 1, 2, 3, 4, 5, 6, 7, 8]
    assert m.dropped == {"no right within 0.004": 1}
    assert "9 kept, dropped: 1 no right within 0.004" == m.describe()


def test_wire_pose_of_optical_frames():
    # Optical z forward along world +x, x right along world -y, y down along world -z: level camera.
    level = np.array([[0.0, 0, 1], [-1, 0, 0], [0, -1, 0]])
    pose = wire_pose(np.array([1.0, 2.0, 0.5]), level)
    assert pose.xyz == (1.0, 2.0, 0.5)
    assert np.allclose(pose.ypr, 0.0)
    # Tilted down by 30 degrees and turned left by 40: the body rotation must come back.
    body = rotation_zyx(math.radians(40), math.radians(30), 0.0)
    pose = wire_pose(np.zeros(3), body @ level)
    assert np.allclose(pose.ypr, (math.radians(40), math.radians(30), 0.0))
    # A rectification R1 turns the camera: the published pose is the rectified camera's.
    r1 = rotation_zyx(0.02, -0.01, 0.03)
    rectified = wire_pose(np.zeros(3), level, r1)
    assert np.allclose(
        rotation_zyx(*rectified.ypr) @ np.array([[0.0, 0, 1], [-1, 0, 0], [0, -1, 0]]), level @ r1.T
    )


def test_body_ground_truth_and_camera_extrinsics_compose():
    q = np.array([0.9, 0.1, -0.2, 0.3])
    world_R_body = quaternion_matrix(*q)
    assert np.allclose(world_R_body @ world_R_body.T, np.eye(3))
    t_bs = np.eye(4)
    t_bs[:3, :3] = rotation_zyx(0.3, 0.1, -0.2)
    t_bs[:3, 3] = [0.1, -0.05, 0.02]
    pos, rot = camera_from_body(np.array([1.0, 2.0, 3.0]), world_R_body, t_bs)
    assert np.allclose(pos, [1, 2, 3] + world_R_body @ t_bs[:3, 3])
    assert np.allclose(rot, world_R_body @ t_bs[:3, :3])


def _floor_fit(points: np.ndarray, camera_z: float) -> tuple[float, float]:
    """Height below the camera and tilt (deg) of the dominant horizontal-ish plane (RANSAC-free:
    iterated least squares on the points within 5 cm of the current plane)."""
    floor = points[points[:, 2] < camera_z - 0.6]
    z0 = np.median(floor[:, 2])
    keep = np.abs(floor[:, 2] - z0) < 0.1
    for _ in range(5):
        a = np.c_[floor[keep, :2], np.ones(keep.sum())]
        coef, *_ = np.linalg.lstsq(a, floor[keep, 2], rcond=None)
        keep = np.abs(floor[:, :2] @ coef[:2] + coef[2] - floor[:, 2]) < 0.05
    normal = np.array([-coef[0], -coef[1], 1.0])
    tilt = math.degrees(math.acos(normal[2] / np.linalg.norm(normal)))
    centre = np.median(floor[keep, :2], axis=0)
    return camera_z - float(centre @ coef[:2] + coef[2]), tilt


@pytest.mark.slow
def test_real_euroc_pairs_put_the_floor_093_m_below_the_camera():
    from replay.asl import AslRecording
    from robot_agent.stereo import StereoMatcher, points_from_depth
    from swarm.streams.frames import make_frame, rectified_camera

    rec = AslRecording(EUROC)
    assert len(rec) == 4 and not rec.matched.dropped
    cam = rectified_camera(rec.calibration)
    matcher = StereoMatcher.for_rig(cam)
    for pair in rec.pairs():  # one per second of the recording
        frame = make_frame("r1", 0, pair, rec.calibration, cam)
        depth = matcher.depth(frame.left, frame.right, cam)
        assert np.isfinite(depth).mean() > 0.6
        points = points_from_depth(depth, cam.fx, cam.fy, cam.cx, cam.cy, frame.pose.xyz, frame.pose.ypr, 5.0)
        height, tilt = _floor_fit(points, frame.pose.xyz[2])
        assert height == pytest.approx(0.93, abs=0.05), pair.t
        assert tilt < 3.0, pair.t


@pytest.mark.slow
def test_euroc_frames_through_a_real_agent_fill_the_floor(euroc_asl_run):
    """``swarm replay asl`` of three pairs (tests/conftest.py): real server and agent processes."""
    from replay.asl import AslRecording
    from swarm.formats.map_file import load_map
    from swarm.map.entropy_table import entropy_info
    from swarm.mission.replay_run import entropy_title, occupied_points

    out = euroc_asl_run
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["frames"] == 3 and metrics["unanswered"] == 0 and metrics["agent_exit_code"] == 0
    assert metrics["entropy_end_bits"] < metrics["entropy_start_bits"] - 10_000
    for name in ("map.npz", "top_view.png", "map_3d.png", "entropy.png", "frames.csv", "occupied.ply"):
        assert (out / name).is_file(), name
    cmap = load_map(out / "map.npz")
    # metrics.json's end is the final map's (after the agent's shutdown flush), and so is the
    # end entropy.png names; the per-frame curve may stop above it (held-back information)
    final = float(entropy_info(cmap.lam, cmap.eta).sum())
    assert metrics["entropy_end_bits"] == pytest.approx(final, rel=1e-6)
    assert f"-> {metrics['entropy_end_bits']:,.0f} bits (start -> final map)" in entropy_title(
        metrics["entropy_start_bits"], metrics["entropy_end_bits"]
    )
    points, _ = occupied_points(cmap)
    assert len(points) == metrics["occupied_voxels"]
    camera = AslRecording(EUROC).positions()[0]
    # Most surfaces lie on the floor, 0.93 m below the camera, in front of it (+x in the Vicon room).
    # The floor plane lies on a boundary of the workspace's voxel layers (its corners are on the
    # 0.1 m lattice): its hits fill the layers on both sides, so the band is two voxels each way.
    floor = np.abs(points[:, 2] - (camera[2] - 0.93)) < 0.2
    assert floor.mean() > 0.4
    assert np.median(points[floor, 0]) > camera[0]


@pytest.mark.slow
def test_a_replays_map_exports_to_octomap_as_it_is(euroc_asl_run, tmp_path, capsys):
    """The default workspace's corners lie on the voxel lattice (OctoMap's): no --align shift."""
    from swarm.cli.main import main
    from swarm.formats.map_file import load_map

    origin = load_map(euroc_asl_run / "map.npz").grid.origin
    assert all(abs(v / 0.1 - round(v / 0.1)) < 1e-6 for v in origin), origin
    assert "-0.0" not in (euroc_asl_run / "config.yaml").read_text()
    assert (
        main(["map", "export", "--from", str(euroc_asl_run / "map.npz"), "--out", str(tmp_path / "m.bt")])
        == 0
    )
    out = capsys.readouterr().out
    assert "OctoMap tree at 0.1 m" in out and "moved by" not in out, out


def test_the_default_workspace_holds_the_box_on_the_lattice():
    from swarm.mission.replay_run import lattice_box

    lo, hi = lattice_box(np.array([-3.0012, 0.25, -1e-4]), np.array([4.33, 5.0, 2.1]), 0.1)
    assert (lo, hi) == ([-3.1, 0.2, -0.1], [4.4, 5.0, 2.1])  # outward, and 2.1 stays 2.1
    assert lattice_box(np.array([-1e-12, 0.0, 0.0]), np.array([1.0, 1.0, 1.0]), 0.05)[0] == [0.0, 0.0, 0.0]
    assert str(lattice_box(np.array([-1e-12, 0.0, 0.0]), np.array([1, 1, 1]), 0.05)[0]) == "[0.0, 0.0, 0.0]"


@pytest.mark.slow
def test_realtime_replay_keeps_the_recorded_pace_and_gives_the_lockstep_map(tmp_path, euroc_asl_run):
    """``--realtime``: frames leave at the recorded times (one per second here), never before; the agent
    takes them all (reliable delivery, its queue), so the map is the lockstep run's, bit for bit, and
    so is the entropy after each frame (frames.csv; it was the one when the frame left, before its
    delta came in: the previous frame's)."""
    import csv

    from swarm.formats.map_file import load_map
    from tests.support.euroc_replay import REPLAY_FRAMES, swarm_replay

    out = tmp_path / "realtime"
    swarm_replay(["asl", str(EUROC), "--frames", str(REPLAY_FRAMES), "--realtime"], out)
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["frames"] == REPLAY_FRAMES and metrics["unanswered"] == 0
    with (out / "frames.csv").open() as fh:
        rows = list(csv.DictReader(fh))
    t = np.array([float(r["t"]) for r in rows])
    sent = np.array([float(r["sent_s"]) for r in rows])
    assert np.all(np.diff(t) > 0.9)  # the shipped pairs are one second apart
    assert np.all(sent >= t - t[0] - 0.005)  # no frame leaves before its recorded time
    assert all(float(r["round_trip_ms"]) > 0 and 0 < float(r["stereo_valid"]) <= 1 for r in rows)
    got, want = load_map(out / "map.npz"), load_map(euroc_asl_run / "map.npz")
    assert np.array_equal(got.lam, want.lam) and np.array_equal(got.eta, want.eta)
    with (euroc_asl_run / "frames.csv").open() as fh:
        lockstep = [float(r["entropy_bits"]) for r in csv.DictReader(fh)]
    assert [float(r["entropy_bits"]) for r in rows] == pytest.approx(lockstep, rel=1e-12)
    assert lockstep[0] < json.loads((out / "metrics.json").read_text())["entropy_start_bits"]


def test_the_entropy_after_a_frame_is_the_one_after_its_deltas():
    """FrameEntropy: the replayed robot's deltas carry their frame's time; the entropy after frame
    t is the one after the last of them with a time <= t, whenever they arrive; another robot's
    deltas change the team map but mark no frame."""
    from swarm.config import mission_from_dict
    from swarm.mission.replay_run import FrameEntropy
    from swarm.mission.team_monitor import TeamMonitor
    from swarm.protocol.map_messages import DeltaMessage

    mission = mission_from_dict(
        {"mission": "m", "workspace": {"lo": [0, 0, 0], "hi": [1, 1, 1], "voxel": 0.5},
         "robots": [{"id": "r1", "start": {"x": 0.5, "y": 0.5}}]}
    )  # fmt: skip
    monitor = TeamMonitor(mission)
    entropy = FrameEntropy(monitor, "r1")
    grid = mission.workspace.grid()

    def delta(robot: str, seq: int, t: float, voxel: int) -> bytes:
        one = np.ones(1, np.float32)
        return DeltaMessage(robot, 1, seq, t, grid, np.array([voxel], np.uint32), one * 5, one * 5).encode()

    start = monitor.team_entropy
    assert entropy.latest() is None and entropy.after(10.0) == start
    entropy.on_delta("m/delta/r1", delta("r1", 1, 10.0, 0))
    h10 = monitor.team_entropy
    entropy.on_delta("m/delta/r2", delta("r2", 1, 99.0, 1))  # another robot: no frame of ours
    entropy.on_delta("m/delta/r1", delta("r1", 2, 12.0, 2))
    assert h10 < start and monitor.team_entropy < h10
    assert entropy.latest() == 12.0
    assert entropy.after(9.9) == start and entropy.after(10.0) == entropy.after(11.0) == h10
    assert entropy.after(12.0) == monitor.team_entropy
    entropy.on_delta("m/delta/r1", b"not a delta")  # counted by the monitor, ignored here
    assert monitor.rejected == 1 and entropy.latest() == 12.0


@pytest.mark.parametrize(
    ("options", "message"),
    [
        (
            ["--start", "100", "--frames", "20"],
            "--start 100: the recording has 4 pairs after matching (0 to 3)",
        ),
        (["--start", "-1"], "--start -1: must be 0 or more"),
        (["--frames", "0"], "--frames 0: must be at least 1"),
    ],
)
def test_start_and_frames_outside_the_recording_are_refused(tmp_path, capsys, options, message):
    """docs/recordings.md's ``--frames 20 --start 100`` on a shorter recording: one error line, no
    empty run of the server and agent."""
    from swarm.cli import main

    out = tmp_path / "run"
    assert main(["replay", "asl", str(EUROC), "--out", str(out), *options]) == 2
    assert message in capsys.readouterr().err
    assert not out.exists()


def test_asl_csv_files_saved_by_excel_load(tmp_path):
    """data.csv files with a byte-order mark and CRLF line ends (Excel's "CSV UTF-8") read as the
    originals; a CSV not in UTF-8 is refused naming it."""
    import shutil

    from replay.asl import AslRecording, RecordingError

    copy = tmp_path / "euroc"
    shutil.copytree(EUROC, copy)
    for path in copy.rglob("data.csv"):
        lines = path.read_bytes().replace(b"\r\n", b"\n").split(b"\n")
        path.write_bytes(b"\xef\xbb\xbf" + b"\r\n".join(lines))
    want, got = AslRecording(EUROC), AslRecording(copy)
    assert len(got) == len(want) == 4
    assert np.array_equal(got.left_stamps, want.left_stamps) and np.allclose(
        got.positions(), want.positions()
    )
    path = copy / "mav0/cam0/data.csv"
    path.write_bytes(path.read_bytes().replace(b"#timestamp", b"#\xb5timestamp"))
    with pytest.raises(RecordingError, match=r"cam0/data.csv: not UTF-8 text"):
        AslRecording(copy)


def test_an_image_file_missing_from_a_copy_leaves_its_pair_out_and_counts_it(tmp_path):
    """A partial copy (data.csv lists a PNG that is not there): the other pairs replay, the missing
    file is counted; with no image file at all the recording is refused naming the folder."""
    import shutil

    from replay.asl import AslRecording, RecordingError

    copy = tmp_path / "euroc"
    shutil.copytree(EUROC, copy)
    (copy / "mav0/cam1/data/1403715275312143104.png").unlink()
    rec = AslRecording(copy)
    assert len(rec) == 3
    assert (
        rec.matched.describe() == "3 kept, dropped: 1 cam1 image file missing, 1 no cam1 image within 0.005"
    )
    assert len(list(rec.pairs())) == 3
    for png in (copy / "mav0/cam0/data").glob("*.png"):
        png.unlink()
    with pytest.raises(RecordingError, match=r"cam0/data.csv: none of its 4 image files is in .*cam0/data"):
        AslRecording(copy)


@pytest.mark.slow
def test_a_replay_that_fails_stops_its_agent(tmp_path, monkeypatch):
    """However the replay ends (here a recording whose second image is unreadable), the agent and
    server processes it started are stopped: no orphans."""
    import shutil

    from replay.asl import AslRecording, RecordingError
    from swarm.mission import replay_run
    from swarm.mission.replay_run import ReplayOptions, default_mission, run_replay

    copy = tmp_path / "euroc"
    shutil.copytree(EUROC, copy)
    (copy / "mav0/cam1/data/1403715275312143104.png").write_bytes(b"not a png")
    started = []
    start = replay_run.start_role

    def recorded_start(*args, **kwargs):
        started.append(start(*args, **kwargs))
        return started[-1]

    monkeypatch.setattr(replay_run, "start_role", recorded_start)
    rec = AslRecording(copy)
    with pytest.raises(RecordingError, match="1403715275312143104.png: missing or not a readable image"):
        run_replay(rec, default_mission(rec), ReplayOptions(out=tmp_path / "run", quiet=True))
    assert len(started) == 2 and all(p.poll() is not None for p in started)  # server and agent


def test_asl_images_of_another_size_than_the_calibration_are_refused_when_opened(tmp_path):
    """sensor.yaml for 640 x 480 beside 752 x 480 images: one error naming the image file and the
    calibration, when the folder is opened (before, only the command line checked, apart from the
    bag reader's own check)."""
    import shutil

    from replay.asl import AslRecording
    from swarm.formats.stereo_calibration import CalibrationError

    copy = tmp_path / "euroc"
    shutil.copytree(EUROC, copy)
    for cam in ("cam0", "cam1"):
        path = copy / f"mav0/{cam}/sensor.yaml"
        path.write_text(path.read_text().replace("resolution: [752, 480]", "resolution: [640, 480]"))
    with pytest.raises(
        CalibrationError,
        match=r"cam0/data/\d+.png: images are 752x480, the calibration .*sensor.yaml\) is for 640x480",
    ):
        AslRecording(copy)


def test_asl_nanosecond_stamps_are_read_exactly(tmp_path):
    """Timestamps in ns went through a float64, which keeps 256 ns at today's epoch: a pose 100 ns
    from its image was read 0 or 256 ns from it. Integers and '.000' decimals now read exactly."""
    import shutil

    from replay.asl import AslRecording

    copy = tmp_path / "euroc"
    shutil.copytree(EUROC, copy)
    path = copy / "mav0/cam0_groundtruth/data.csv"
    lines = path.read_text().splitlines()
    first = lines[1].split(",")
    first[0] = str(int(first[0].split(".")[0]) + 100)  # 1403715274312143204: not a float64
    lines[1] = ",".join(first)
    path.write_text("\n".join(lines) + "\n")
    rec = AslRecording(copy)
    assert rec.poses.stamps[0] - rec.left_stamps[0] == 100
    assert rec.left_stamps[0] == 1403715274312143104


def test_asl_poses_between_the_images_stamps_are_interpolated(tmp_path):
    """A pose file whose samples fall between the images' stamps (a ground truth at its own rate):
    each image takes the pose interpolated at its stamp, by the rule of the bags
    (replay.trajectory), not the nearest sample 2 ms away."""
    import shutil

    from replay.asl import AslRecording

    copy = tmp_path / "euroc"
    shutil.copytree(EUROC, copy)
    path = copy / "mav0/cam0_groundtruth/data.csv"
    rows = [line.split(",") for line in path.read_text().splitlines() if not line.startswith("#")]
    velocity = np.array([1.0, -0.5, 0.2])  # m/s: a camera moving while its rotation holds
    lines = []
    for row in rows:
        stamp, values = int(row[0].split(".")[0]), np.array([float(v) for v in row[1:8]])
        for dt_ns in (-2_000_000, 3_000_000):  # ns stamps as integers: a float64 keeps 256 ns
            moved = values.copy()
            moved[:3] += velocity * dt_ns * 1e-9
            lines.append(",".join([str(stamp + dt_ns)] + [repr(float(v)) for v in moved]))
    path.write_text("#timestamp,p_x,p_y,p_z,q_w,q_x,q_y,q_z\n" + "\n".join(lines) + "\n")
    want, got = AslRecording(EUROC), AslRecording(copy)
    assert len(got) == len(want) == 4 and got.interpolated_poses == 4 and want.interpolated_poses == 0
    for a, b in zip(got.pairs(), want.pairs(), strict=True):
        assert a.t == b.t
        assert np.allclose(a.position, b.position, rtol=0, atol=1e-9)
        assert np.allclose(a.world_R_optical, b.world_R_optical, rtol=0, atol=1e-9)


@pytest.mark.parametrize("row", ["nan,0.87,0.93", "inf,2.2,0.93", "0.86,2.2,0.93,0,0,0,0"])
def test_asl_pose_rows_that_are_not_poses_are_left_out_and_counted(tmp_path, row):
    """A ground-truth row of NaN, inf or a zero quaternion went through as a NaN pose (or a
    ValueError naming no file); it is now left out and counted, as the bag reader does."""
    import shutil

    from replay.asl import UNUSABLE_POSE_ROW, AslRecording, RecordingError

    folder = tmp_path / "euroc"
    shutil.copytree(EUROC, folder)
    gt = folder / "mav0" / "cam0_groundtruth" / "data.csv"
    lines = gt.read_text().splitlines()
    bad = row.split(",")

    def spoilt(line: str) -> str:
        stamp, *numbers = line.split(",")
        return ",".join([stamp, *bad, *numbers[len(bad) :]])

    gt.write_text("\n".join([lines[0], spoilt(lines[1]), *lines[2:]]) + "\n")
    rec = AslRecording(folder)
    assert len(rec) == 3 and rec.matched.dropped[UNUSABLE_POSE_ROW] == 1
    assert np.isfinite(rec.positions()).all()
    gt.write_text("\n".join([lines[0], *map(spoilt, lines[1:])]) + "\n")
    with pytest.raises(RecordingError, match=r"data.csv: none of its 4 poses is usable"):
        AslRecording(folder)
