"""swarm.bench.agent_memory's measures: /proc figures, resident pages of an array, arrays held."""

import sys
from pathlib import Path

import numpy as np
import pytest

from swarm.bench import agent_memory

ROOT = Path(__file__).resolve().parents[3]
pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")


def test_memory_reads_rss_peak_and_pss():
    mem = agent_memory.memory()
    assert 0 < mem["rss"] <= mem["hwm"]
    assert 0 < mem["pss"] <= mem["rss"] + 1.0
    assert mem["private"] + mem["shared"] == pytest.approx(mem["rss"], rel=0.05)


def test_resident_bytes_counts_only_the_pages_written():
    array = np.zeros(64 << 20, dtype=np.uint8)  # calloc'd: no page written yet
    assert agent_memory.resident_bytes(array) < 4 << 20
    array[: 16 << 20] = 1
    assert agent_memory.resident_bytes(array) >= 16 << 20
    assert agent_memory.resident_bytes(array[: 1 << 20]) == 1 << 20


class _Holder:
    __module__ = "swarm.test"  # the walk enters the project's objects only

    def __init__(self) -> None:
        self.big = np.ones(2_000_000, dtype=np.float32)
        self.view = self.big[10:]  # a view: counted once, at its base
        self.small = np.ones(10)


def test_arrays_held_walks_attributes_and_counts_each_buffer_once():
    holder = _Holder()
    held = agent_memory.arrays_held({"h": {"inner": [holder]}}, min_bytes=1_000_000)
    assert [(path, nbytes) for path, nbytes, _, _ in held] == [("h['inner'][0].big", 8_000_000)]
    assert held[0][2] == 8_000_000  # written by np.ones: all of it resident


@pytest.mark.slow
def test_run_measures_an_agent_frame_by_frame(capsys):
    rows = agent_memory.run(ROOT / "configs" / "office.yaml", None, 3, arrays=True, trace=False)
    steps = [row["step"] for row in rows]
    assert steps[:4] == ["imports (before)", "import robot_agent.agent", "zenoh router session", "Agent()"]
    assert [s.split(" (")[0] for s in steps[4:7]] == ["frame   1", "frame   2", "frame   3"]
    assert all(row["rss"] > 0 for row in rows)
    out = capsys.readouterr().out
    assert "agent.explorer.local.map.lam" in out and "results: map sha256" in out
