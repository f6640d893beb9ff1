"""swarm view: a short simulated mission recorded to .rrd, read back with rerun's own reader."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

rr = pytest.importorskip("rerun", reason="the live view needs rerun-sdk (pip install '.[view]')")
from rerun.chunk import RrdReader  # noqa: E402

from swarm.view.scene import boundary_mask  # noqa: E402

MISSION = """
mission: viewed
workspace: {lo: [0.0, 0.0, 0.0], hi: [2.4, 2.4, 0.8], voxel: 0.1}
floor_plan: plan.yaml
robots:
  - id: r1
    start: {x: 0.6, y: 0.6, yaw: 0.0}
rig: {mode: range, camera_height: 0.4, width: 40, height: 30}
stop: {max_time_s: 4}
sim: {agent_timeout_s: 30}
"""

PLAN = """
name: box
wall_height: 1.0
wall_thickness: 0.1
walls:
  - points: [[-0.05, -0.05], [2.45, -0.05], [2.45, 2.45], [-0.05, 2.45]]
    closed: true
boxes:
  - {centre: [1.7, 1.0], size: [0.4, 0.4], height: 0.6}
"""


def columns(path: Path) -> dict[str, dict[str, list]]:
    """entity path -> column name -> values, over every chunk of the recording."""
    out: dict[str, dict[str, list]] = {}
    for chunk in RrdReader(str(path)).stream():
        batch = chunk.to_record_batch()
        cols = out.setdefault(chunk.entity_path, {})
        for name in batch.schema.names:
            if name == "log_time" or name.startswith("rerun.controls"):
                continue  # wall-clock nanoseconds and row ids
            cols.setdefault(name, []).extend(batch.column(name).to_pylist())
    return out


@pytest.mark.slow
def test_a_recorded_mission_holds_voxels_poses_and_entropy(tmp_path: Path):
    (tmp_path / "plan.yaml").write_text(PLAN)
    (tmp_path / "m.yaml").write_text(MISSION)
    out = tmp_path / "run"
    proc = subprocess.run(
        [sys.executable, "-m", "swarm.cli", "sim", str(tmp_path / "m.yaml"), "--out", str(out), "--quiet",
         "--view", str(tmp_path / "run.rrd")],
        capture_output=True, text=True, timeout=240,
    )  # fmt: skip
    logs = "\n".join(f"--- {p.name}\n{p.read_text()[-2000:]}" for p in sorted(out.glob("*.log")))
    assert proc.returncode == 0, proc.stdout + proc.stderr + logs
    data = columns(tmp_path / "run.rrd")
    boxes = data["/world/map/occupied"]["Boxes3D:centers"]
    assert boxes and len(boxes[-1]) > 10, logs  # the last frame shows the box and walls
    last = np.array(boxes[-1])
    assert np.all((last >= -0.01) & (last <= 2.41))
    # the box at x 1.5-1.9, y 0.8-1.2 is in the robot's view from (0.6, 0.6) facing +x
    on_box = (last[:, 0] > 1.45) & (last[:, 0] < 1.95) & (last[:, 1] > 0.75) & (last[:, 1] < 1.25)
    assert on_box.any(), last
    assert data["/world/map/entropy"]["Points3D:positions"][-1]
    poses = data["/world/robots/r1"]["Points3D:positions"]
    assert poses and np.allclose(poses[0][0][:2], (0.6, 0.6), atol=0.3)
    entropy = np.array([v[0] for v in data["/plots/entropy"]["Scalars:scalars"]])
    assert len(entropy) >= 3 and entropy[-1] < entropy[0]
    assert np.all(np.diff(entropy) <= 1e-3 * entropy[0])  # information only ever lowers H here
    assert "sim_time" in data["/plots/entropy"]


def test_boundary_is_known_free_next_to_unknown():
    known = np.zeros((5, 5, 3), bool)
    known[:3] = True
    free = known.copy()
    free[0, 0, 0] = False  # occupied
    edge = boundary_mask(known, free)
    assert np.array_equal(np.argwhere(edge)[:, 0], np.full(15, 2))  # the layer x = 2 touches x = 3
