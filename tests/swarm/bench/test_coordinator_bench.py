"""``swarm bench coordinator`` on a small floor: its figures, and a floor plan with doors."""

from __future__ import annotations

import math

import numpy as np

from swarm.bench import coordinator as bench


def test_the_bench_times_every_answer_and_prints_its_phases():
    figures = bench.run(3, size=(16.0, 12.0, 1.2), explore_frames=4, rounds=2, frames_between=1)
    assert len(figures["times"]) == 6 and np.all(figures["times"] > 0)
    assert 0 < figures["known"] < 1
    assert set(figures["phases"]) <= set(bench.PHASES)
    assert sum(figures["phases"].values()) <= figures["times"].sum() + 1e-6  # nested time counted once
    text = bench.format_figures(figures)
    assert "p95" in text and "planning" in text and "from the memo" in text


def test_the_floor_plan_has_rooms_with_doors_off_corridors():
    walls = bench.floor_plan((40.0, 24.0), 0.1)
    assert walls[0].all() and walls[:, -1].all()  # outer walls
    assert 0.01 < walls.mean() < 0.2
    room_wall = walls[80, 100:160]  # x = 8 m, y 10-16 m: a room wall with one 1 m door
    assert np.count_nonzero(~room_wall) == 10
    # a frame from a corridor crossing sees walls within the sensor's reach, and the floor
    pts = bench.frame_points(walls, 0.1, 2.2, np.array([10.0, 6.0]), 0.0, 5.0)
    assert pts.shape == (bench.FRAME_RAYS[0] * bench.FRAME_RAYS[1], 3)
    assert np.all(np.linalg.norm(pts - [10.0, 6.0, bench.CAMERA_HEIGHT], axis=1) <= 5.0 * 1.2 + 1e-9)
    assert np.any(np.isclose(pts[:, 2], 0.0)) and math.isfinite(float(pts.sum()))
