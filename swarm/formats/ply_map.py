"""PLY of a coverage map's occupied voxels with their belief (binary little-endian PLY 1.0).

One vertex per voxel with E[C] > ``threshold`` (default 0.5), with these vertex properties:

========================  ======  ============================================================
``x``, ``y``, ``z``       float   the voxel centre, metres (with ``cubes``: a cube corner)
``mu``                    float   the Gaussian coverage mean (may leave [0, 1]; untruncated)
``sigma``                 float   its standard deviation (coverage units)
``entropy``               float   the voxel's entropy, bits (128 bins, paper eq. 17)
``expected_coverage``     float   E[C] of the belief truncated to [0, 1]
``red``, ``green``,       uchar   E[C] on the viridis colour map, so that viewers show it
``blue``
========================  ======  ============================================================

With ``cubes=True`` each voxel is a cube: 8 corner vertices carrying the voxel's properties
and a ``face`` element of 6 quads (``property list uchar int vertex_indices``), so MeshLab,
CloudCompare or Open3D show volumes.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from swarm.map.coverage_map import CoverageMap
from swarm.map.entropy import expected_coverage
from swarm.map.entropy_table import default_table

BELIEF_PROPERTIES = ("mu", "sigma", "entropy", "expected_coverage")
_CORNERS = np.array([[i, j, k] for k in (0, 1) for j in (0, 1) for i in (0, 1)], dtype=np.float64)
# quads of the unit cube on the corner numbering above, counter-clockwise seen from outside
_QUADS = np.array(
    [[0, 2, 3, 1], [4, 5, 7, 6], [0, 1, 5, 4], [2, 6, 7, 3], [0, 4, 6, 2], [1, 3, 7, 5]], dtype=np.int32
)


def belief_rows(cmap: CoverageMap, threshold: float = 0.5) -> dict[str, np.ndarray]:
    """Flat index, centre (N, 3) and the belief properties of voxels with E[C] > ``threshold``."""
    mu = cmap.mean().astype(np.float64)
    sigma = cmap.sigma().astype(np.float64)
    coverage = expected_coverage(mu, sigma)
    idx = np.flatnonzero(coverage > threshold)
    return {
        "idx": idx,
        "centre": cmap.grid.centre(cmap.grid.unflat(idx)),
        "mu": mu[idx],
        "sigma": sigma[idx],
        "entropy": default_table()(mu[idx].astype(np.float32), sigma[idx].astype(np.float32)),
        "expected_coverage": coverage[idx],
    }


def write_belief_ply(path: str | Path, cmap: CoverageMap, threshold: float = 0.5, cubes: bool = False) -> int:
    """Write the occupied voxels of ``cmap`` (module doc); returns how many voxels. Raises OSError."""
    from matplotlib import colormaps

    rows = belief_rows(cmap, threshold)
    n = len(rows["idx"])
    colour = (colormaps["viridis"](np.clip(rows["expected_coverage"], 0, 1))[:, :3] * 255).round()
    points = rows["centre"]
    repeat = 1
    if cubes:
        repeat = 8
        half = cmap.grid.voxel / 2
        points = (points[:, None, :] - half + _CORNERS[None] * cmap.grid.voxel).reshape(-1, 3)
    fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
    fields += [(name, "<f4") for name in BELIEF_PROPERTIES]
    fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
    data = np.empty(n * repeat, dtype=fields)
    data["x"], data["y"], data["z"] = points.T
    for name in BELIEF_PROPERTIES:
        data[name] = np.repeat(rows[name], repeat)
    for c, name in enumerate(("red", "green", "blue")):
        data[name] = np.repeat(colour[:, c], repeat)
    header = ["ply", "format binary_little_endian 1.0", "comment swarm coverage map: occupied voxels"]
    header += [f"comment voxel {cmap.grid.voxel:g} m, E[C] > {threshold:g}", f"element vertex {len(data)}"]
    types = {"<f4": "float", "u1": "uchar"}
    header += [f"property {types[t]} {name}" for name, t in fields]
    faces = b""
    if cubes:
        header += [f"element face {6 * n}", "property list uchar int vertex_indices"]
        quads = (_QUADS[None] + 8 * np.arange(n)[:, None, None]).reshape(-1, 4)
        face = np.empty(len(quads), dtype=[("n", "u1"), ("v", "<i4", (4,))])
        face["n"], face["v"] = 4, quads
        faces = face.tobytes()
    header.append("end_header")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as f:
        f.write(("\n".join(header) + "\n").encode("ascii"))
        f.write(data.tobytes())
        f.write(faces)
    return n
