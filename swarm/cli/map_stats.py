"""``swarm map stats``'s summary: a running map server's ``map/stats`` in a few lines
(``--json`` prints the whole object, docs/protocol.md "Queries")."""

from __future__ import annotations

from swarm.formats.shown_numbers import shown


def stats_summary(stats: dict) -> list[str]:
    """The lines ``swarm map stats`` prints: the mission and its grid, the known fraction, the
    entropy beside the initial one and H_th (and whether the mission is done), the deltas with
    what was refused, and per robot its deltas and acks."""
    shape = " x ".join(str(n) for n in stats.get("shape", []))
    origin = ", ".join(f"{shown(v, 6):g}" for v in stats.get("origin", []))
    lines = [
        f"mission {stats.get('mission', '?')}: {stats.get('voxels', 0):,} voxels of "
        f"{stats.get('voxel_size', 0):g} m ({shape}, origin {origin} m), "
        f"known {stats.get('known_fraction', 0.0):.1%}"
    ]
    h, h0 = float(stats.get("entropy_bits", 0.0)), float(stats.get("initial_entropy_bits", 0.0))
    line = f"entropy {h:,.0f} bits"
    if h0 > 0:
        line += f", {h / h0:.1%} of the initial {h0:,.0f}"
    threshold = stats.get("threshold_bits")
    if threshold is not None:
        left = h - float(threshold)
        togo = f"({left:,.0f} to go)" if left > 0 else "(reached)"
        line += f"; H_th {float(threshold):,.0f} bits {togo}"
    lines.append(line)
    done = stats.get("mission_done")
    if done:
        if done.get("reason") == "threshold":
            why = "the entropy reached H_th"
        else:
            why = f"nothing left (robots done: {', '.join(done.get('robots') or []) or 'none'})"
        lines.append(f"mission done: {why}; announced on mission/done")
    rejected = {k: v for k, v in (stats.get("rejected") or {}).items() if v}
    refused = ", ".join(f"{k} {v}" for k, v in rejected.items()) or "none"
    updates = f"{stats.get('updates_merged', 0):,} voxel updates"
    lines.append(
        f"deltas applied {stats.get('deltas_applied', 0):,} ({updates}), "
        f"duplicates {stats.get('duplicates', 0):,}, refused: {refused}"
    )
    for robot, figures in sorted((stats.get("robots") or {}).items()):
        acked, last = figures.get("acked_seq"), figures.get("last_seq")
        note = " (quarantined)" if figures.get("quarantined") else ""
        updates = f"{figures.get('voxel_updates', 0):,} voxel updates"
        acks = f"acked {_count(acked)} of {_count(last)} in its latest run"
        lines.append(f"  {robot}: {figures.get('deltas', 0):,} deltas, {updates}, {acks}{note}")
    if not stats.get("robots"):
        lines.append("  no robot's delta yet")
    lines.append("(swarm map stats --json: every figure)")
    return lines


def _count(value) -> str:
    """An integer with thousands separators; anything else (None: not told) as it is."""
    return f"{value:,}" if isinstance(value, int) else str(value)
