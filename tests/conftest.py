"""Fixtures shared by test files."""

from __future__ import annotations

import pytest

from tests.support.euroc_replay import EUROC_MINI, REPLAY_FRAMES, swarm_replay

# Fixtures defined beside the helpers they serve (tests/support), offered to every test.
pytest_plugins = ["tests.support.secure_team", "tests.support.stereo_scenes"]


@pytest.fixture(scope="session")
def euroc_asl_run(tmp_path_factory):
    """The run folder of ``swarm replay asl tests/data/euroc_mini --frames 3`` (run once per session)."""
    out = tmp_path_factory.mktemp("euroc-asl")
    swarm_replay(["asl", str(EUROC_MINI), "--frames", str(REPLAY_FRAMES)], out)
    return out
