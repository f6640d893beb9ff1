"""A simulated mission's ``entropy.png``: H(t) over sim time with H_th dashed and the mission
time marked. (The map's pictures, ``top_view.png``, ``map_3d.png`` and ``slices/``, are
:mod:`swarm.mission.map_pictures`.)"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np


def plot_entropy(path: str | Path, metrics: dict[str, Any]) -> None:
    """Entropy over sim time, H_th as a dashed line, the mission time marked."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    curve = np.asarray(metrics.get("entropy_curve") or [], dtype=np.float64).reshape(-1, 2)
    threshold = float(metrics["threshold_bits"])
    t_mission = metrics.get("mission_time_s")
    fig, ax = plt.subplots(figsize=(7.5, 4.2), dpi=120, layout="constrained")
    ax.plot(curve[:, 0], curve[:, 1], "-", color="tab:blue", lw=1.6, label="map entropy H(t)")
    ax.axhline(threshold, ls="--", color="tab:red", lw=1.2, label=f"H_th = {_bits(threshold)}")
    if t_mission is not None:
        below = np.flatnonzero(curve[:, 1] <= threshold)
        h_at = curve[below[0], 1] if below.size else threshold
        ax.axvline(t_mission, ls=":", color="tab:green", lw=1.2)
        ax.plot([t_mission], [h_at], "o", color="tab:green", label=f"mission time {t_mission:.1f} s")
    else:
        ax.text(0.98, 0.95, "threshold not reached", transform=ax.transAxes, ha="right", va="top")
    if not len(curve):
        ax.text(0.5, 0.5, "no entropy samples", transform=ax.transAxes, ha="center")
    top = max([threshold, float(metrics.get("initial_entropy_bits") or 0.0), *curve[:, 1]])
    ax.set_ylim(0.0, 1.05 * top if top > 0 else 1.0)
    ax.set_xlim(left=0.0)
    ax.set_xlabel("sim time (s)")
    ax.set_ylabel("map entropy (bits)")
    robots = metrics.get("robots") or []
    ax.set_title(
        f"{len(robots)} robot(s), {metrics.get('strategy')}, {metrics.get('coordination')}, "
        f"seed {metrics.get('seed')}"
    )
    ax.grid(True, alpha=0.3)
    ax.legend(loc="upper right" if t_mission is not None else "center right")
    fig.savefig(path)
    plt.close(fig)


def _bits(x: float) -> str:
    return f"{x:,.0f} bits" if abs(x) >= 100 else f"{x:.3g} bits"
