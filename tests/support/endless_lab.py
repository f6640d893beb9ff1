"""A lab mission that runs until it is stopped (H_th 0, a day of simulated time), for the interrupt tests."""

from __future__ import annotations

from pathlib import Path

from tests.support.paths import ROOT


def endless_lab(folder: Path) -> Path:
    """The lab mission with H_th 0 and a day of simulated time: it runs until it is stopped."""
    from swarm.config import load_mission

    lab = load_mission(ROOT / "configs" / "lab.yaml")
    stop = lab.stop.model_copy(update={"entropy_threshold_bits": 0.0, "max_time_s": 86400.0})
    path = folder / "endless-lab.yaml"
    path.write_text(lab.model_copy(update={"stop": stop}).to_yaml())  # its paths made absolute
    return path
