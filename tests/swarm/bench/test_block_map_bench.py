"""``swarm bench sparse``'s pieces: its ray streams and its comparison of the two maps."""

import numpy as np

from swarm.bench import block_map as bench
from swarm.bench import ray_streams
from swarm.config import load_mission
from tests.support.paths import ROOT


def test_the_comparison_finds_the_block_map_equal_to_the_dense_one_on_office_frames():
    mission = load_mission(ROOT / "configs" / "office.yaml")
    frames = ray_streams.office_frames(mission, spacing=4.0)
    sensor = mission.sensor_model_of(mission.rig_for(mission.robot_ids[0]))
    figures = bench.compare("office", "weighted", mission.workspace.grid(), sensor, frames, repeat=1)
    assert figures.frames == len(frames) >= 4 and figures.rays > 10_000
    assert figures.bounded_difference == 0.0 and figures.unbounded_difference == 0.0
    maps = {"dense", "dense grid", "bounded", "unbounded"}
    assert 0 < figures.bounded_blocks <= figures.blocks and set(figures.seconds) == maps | {
        f"{m} +H" for m in maps
    }
    text = bench.format_streams([figures], 1)
    assert "0.0e+00 / 0.0e+00" in text


def test_the_campus_streets_are_free_floor_and_the_runs_stay_on_the_site():
    plan = ray_streams.campus_plan()
    paths = ray_streams.street_paths(16)
    assert len({(*s, *d) for s, d in paths}) == 16  # two may share a corner, heading apart
    for start, direction in paths:
        along = start + direction * np.linspace(0, ray_streams.RUN, 50)[:, None]
        assert np.all(plan.height_at(along) == 0)
        assert np.all((along >= 1.5 - 1e-9) & (along <= np.array(ray_streams.SITE[:2]) - 1.5 + 1e-9))
    floor = ray_streams.free_floor(plan, 5.0, 0.5)
    assert len(floor) and np.all(plan.height_at(floor) == 0)
