"""Write a coverage map to the file the output name asks for: ``.npz``, ``.ply`` or ``.bt``.

* ``.npz``: the map file (every voxel's belief; :mod:`swarm.formats.map_file`);
* ``.ply``: occupied voxels (E[C] > ``threshold``) with their belief
  (:mod:`swarm.formats.ply_map`), as cubes when ``cubes``;
* ``.bt``: OctoMap's binary maximum-likelihood tree (:mod:`swarm.formats.octomap_map`):
  voxels with sigma > ``max_sigma`` unknown, the others occupied when E[C] > 0.5.
"""

from __future__ import annotations

from pathlib import Path

from swarm.map.coverage_map import CoverageMap

SUFFIXES = (".npz", ".ply", ".bt")


def export_coverage_map(
    out: str | Path,
    cmap: CoverageMap,
    threshold: float = 0.5,
    cubes: bool = False,
    max_sigma: float = 0.5,
    align: str = "refuse",
) -> str:
    """Write ``cmap`` to ``out``; returns what was written. Raises ValueError naming ``out``."""
    out = Path(out)
    suffix = out.suffix.lower()
    if suffix == ".npz":
        from swarm.formats.map_file import save_map

        save_map(out, cmap)
        return f"wrote {out}: {cmap.grid.size:,} voxels {list(cmap.grid.shape)}"
    if suffix == ".ply":
        from swarm.formats.ply_map import write_belief_ply

        n = write_belief_ply(out, cmap, threshold, cubes)
        shape = "cubes" if cubes else "centres"
        return f"wrote {out}: {n:,} voxel {shape} with E[C] > {threshold:g} and their mu, sigma, entropy"
    if suffix == ".bt":
        from swarm.formats.octomap_map import export_bt

        try:
            return "wrote " + export_bt(out, cmap, max_sigma, align)
        except ValueError as exc:
            raise ValueError(f"{out}: {exc}" if str(out) not in str(exc) else str(exc)) from exc
    raise ValueError(
        f"{out}: the output must end in .npz (map file), .ply (occupied voxels) or .bt (OctoMap)"
    )
