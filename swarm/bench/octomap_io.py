"""``swarm bench octomap``: reading and writing OctoMap ``.bt`` files, ours beside OctoMap's own.

Both sides do the same job on the same file: read the whole tree (ours: every leaf, pruned
ones kept whole; OctoMap: ``OcTree(path)``), and write it back (ours: encode the leaf-level
voxels, pruning included; OctoMap: ``writeBinary``, which prunes before it writes). The best
of ``repeat`` runs, single-threaded, in one process.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from swarm.formats.octomap_file import TREE_DEPTH, read_bt, write_bt


def _best(fn, repeat: int) -> float:
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times)


def _expanded(path: Path) -> tuple[float, np.ndarray, np.ndarray]:
    leaves = read_bt(path)
    keys, occupied = [], []
    for depth in np.unique(leaves.depth):
        pick = leaves.depth == depth
        n = 1 << (TREE_DEPTH - int(depth))
        offsets = np.stack(np.meshgrid(*[np.arange(n)] * 3, indexing="ij"), -1).reshape(-1, 3)
        keys.append((leaves.key[pick][:, None, :] + offsets[None]).reshape(-1, 3))
        occupied.append(np.repeat(leaves.occupied[pick], n**3))
    return leaves.resolution, np.concatenate(keys), np.concatenate(occupied)


def run(path: Path, repeat: int = 3) -> list[dict]:
    """Rows of figures: operation, ours (s), OctoMap's (s) or None without octomap-python."""
    try:
        import octomap
    except ImportError:
        octomap = None
    resolution, keys, occupied = _expanded(path)
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "ours.bt"
        ours_read = _best(lambda: read_bt(path), repeat)
        ours_write = _best(lambda: write_bt(out, resolution, keys, occupied), repeat)
        theirs_read = theirs_write = None
        if octomap is not None:
            theirs_read = _best(lambda: octomap.OcTree(str(path).encode()), repeat)
            tree = octomap.OcTree(str(path).encode())
            theirs_write = _best(lambda: tree.writeBinary(str(Path(tmp) / "theirs.bt").encode()), repeat)
    return [
        {"operation": f"read {path.name}", "ours_s": ours_read, "octomap_s": theirs_read},
        {"operation": f"write {len(keys):,} voxels", "ours_s": ours_write, "octomap_s": theirs_write},
    ]


def format_table(rows: list[dict]) -> str:
    lines = [f"{'operation':<28} {'ours (s)':>10} {'OctoMap (s)':>12} {'ours / OctoMap':>15}"]
    for row in rows:
        theirs = row["octomap_s"]
        ratio = f"{row['ours_s'] / theirs:.1f}x" if theirs else "-"
        shown = f"{theirs:.3f}" if theirs is not None else "n/a"
        lines.append(f"{row['operation']:<28} {row['ours_s']:>10.3f} {shown:>12} {ratio:>15}")
    return "\n".join(lines)
