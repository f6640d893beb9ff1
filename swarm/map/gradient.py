"""Entropy-gradient exploration geometry (paper eq. 27-35, docs/design.md section 3).

Pure functions over numpy arrays, no I/O:

- :func:`robot_axes`: gaze axis p, lateral axis q and motion-plane normal n (eq. 27-28);
- :func:`project_on_plane`: projection on the robot's motion plane (eq. 29, 33);
- :func:`candidate_voxels`: the neighbourhood N_G(x, xi) (eq. 30);
- :func:`entropy_gradient`: backward-difference entropy gradient (eq. 32);
- :func:`projected_gradient`: that gradient projected on the motion plane (eq. 33);
- :func:`target_scores`, :func:`select_target`: the target of eq. 35 and its gaze (eq. 34).

Conventions: a field is an array of shape (nx, ny, nz) over the grid of
:class:`swarm.map.grid.Grid` (flat index = C order); vectors are (..., 3) in world axes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = [
    "Target",
    "candidate_voxels",
    "entropy_gradient",
    "project_on_plane",
    "projected_gradient",
    "robot_axes",
    "select_target",
    "target_scores",
]


def robot_axes(yaw, pitch=0.0, roll=0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Robot axes (p, q, n) for ZYX Euler angles in radians (eq. 27-28).

    R = Rz(yaw) Ry(pitch) Rx(roll), right-handed, angles positive counterclockwise about
    their axes (so a positive pitch turns the gaze below the horizon when z is up):
    p = R x_hat is the gaze axis, q = R y_hat the lateral axis and n = R z_hat = p x q the
    normal of the motion plane spanned by p and q. Angles broadcast; each axis has shape
    (..., 3).
    """
    yaw, pitch, roll = np.broadcast_arrays(
        np.asarray(yaw, np.float64), np.asarray(pitch, np.float64), np.asarray(roll, np.float64)
    )
    cy, sy = np.cos(yaw), np.sin(yaw)
    cp, sp = np.cos(pitch), np.sin(pitch)
    cr, sr = np.cos(roll), np.sin(roll)
    p = np.stack([cy * cp, sy * cp, -sp], axis=-1)
    q = np.stack([cy * sp * sr - sy * cr, sy * sp * sr + cy * cr, cp * sr], axis=-1)
    n = np.stack([cy * sp * cr + sy * sr, sy * sp * cr - cy * sr, cp * cr], axis=-1)
    return p, q, n


def project_on_plane(vectors, normal) -> np.ndarray:
    """Projection of ``vectors`` (..., 3) on the plane through 0 with normal ``normal``.

    Eq. 29 writes it as (u.p) p + (u.q) q for the orthonormal axes p, q of the plane; with
    n = p x q that is u - (u.n) n, computed here. ``normal`` (3,) or (..., 3) need not be
    unit length (it is normalised; a zero normal is an error).
    """
    v = np.asarray(vectors)
    if not np.issubdtype(v.dtype, np.floating):
        v = v.astype(np.float64)
    n = np.asarray(normal, dtype=np.float64)
    norm = np.linalg.norm(n, axis=-1, keepdims=True)
    if np.any(norm == 0) or not np.all(np.isfinite(norm)):
        raise ValueError("plane normal must be a finite non-zero vector")
    n = (n / norm).astype(v.dtype)
    return v - np.sum(v * n, axis=-1, keepdims=True) * n


def entropy_gradient(H: np.ndarray, voxel: float) -> np.ndarray:
    """Entropy gradient by backward differences (eq. 32), shape (nx, ny, nz, 3).

    dH/dx at voxel l = (H(l) - H(l - x_hat)) / e, and likewise along y and z. A voxel on
    the lower boundary of an axis has no neighbour l - x_hat: its component along that
    axis is 0 (it neither attracts nor repels the robot). The result has the floating
    dtype of ``H`` (float32 stays float32).
    """
    H = np.asarray(H)
    if H.ndim != 3:
        raise ValueError(f"entropy field must be 3-D (nx, ny, nz), got shape {H.shape}")
    if not (np.isfinite(voxel) and voxel > 0):
        raise ValueError(f"voxel size must be > 0, got {voxel!r}")
    dtype = np.result_type(H.dtype, np.float32)
    G = np.zeros(H.shape + (3,), dtype=dtype)
    inv = dtype.type(1.0 / voxel)
    np.subtract(H[1:, :, :], H[:-1, :, :], out=G[1:, :, :, 0], casting="unsafe")
    np.subtract(H[:, 1:, :], H[:, :-1, :], out=G[:, 1:, :, 1], casting="unsafe")
    np.subtract(H[:, :, 1:], H[:, :, :-1], out=G[:, :, 1:, 2], casting="unsafe")
    G *= inv
    return G


def projected_gradient(H: np.ndarray, voxel: float, normal) -> np.ndarray:
    """grad H_G: the eq. 32 gradient projected on the motion plane with ``normal`` (eq. 33)."""
    return project_on_plane(entropy_gradient(H, voxel), normal)


def candidate_voxels(grid_shape, voxel: float, origin, position, radius: float, z_slab: int = 0):
    """Flat indices (int64, ascending) of the neighbourhood N_G(x, xi) (eq. 30).

    The motion plane of a ground robot is horizontal at sensor height: its voxels are the
    layer k0 = floor((x_z - o_z) / e) that contains the sensor, widened to the slab
    k0 - z_slab .. k0 + z_slab (``z_slab`` whole layers each side, 0 = the one layer).
    A voxel l of the slab is a candidate when its centre w(l) satisfies
    |w(l) - x| <= xi (the paper's 3-D distance, eq. 30). A sensor outside the grid's z
    range, or a radius < 0, gives no candidate.
    """
    nx, ny, nz = (int(v) for v in grid_shape)
    e = float(voxel)
    o = np.asarray(origin, dtype=np.float64)
    x = np.asarray(position, dtype=np.float64)
    xi = float(radius)
    z_slab = int(z_slab)
    if z_slab < 0:
        raise ValueError(f"z_slab must be >= 0 layers, got {z_slab}")
    empty = np.zeros(0, dtype=np.int64)
    if not (xi >= 0 and np.all(np.isfinite(x))):
        return empty
    k0 = int(np.floor((x[2] - o[2]) / e))
    k_lo, k_hi = max(k0 - z_slab, 0), min(k0 + z_slab, nz - 1)
    # index ranges whose centres can lie within xi along each horizontal axis (+-1 slack;
    # the exact test below decides)
    i_lo = max(int(np.floor((x[0] - xi - o[0]) / e - 0.5)), 0)
    i_hi = min(int(np.ceil((x[0] + xi - o[0]) / e - 0.5)), nx - 1)
    j_lo = max(int(np.floor((x[1] - xi - o[1]) / e - 0.5)), 0)
    j_hi = min(int(np.ceil((x[1] + xi - o[1]) / e - 0.5)), ny - 1)
    if k_lo > k_hi or i_lo > i_hi or j_lo > j_hi:
        return empty
    i = np.arange(i_lo, i_hi + 1)
    j = np.arange(j_lo, j_hi + 1)
    k = np.arange(k_lo, k_hi + 1)
    dx = o[0] + (i + 0.5) * e - x[0]
    dy = o[1] + (j + 0.5) * e - x[1]
    dz = o[2] + (k + 0.5) * e - x[2]
    d2 = dx[:, None, None] ** 2 + dy[None, :, None] ** 2 + dz[None, None, :] ** 2
    ii, jj, kk = np.nonzero(d2 <= xi * xi)
    return ((i[ii] * ny + j[jj]) * nz + k[kk]).astype(np.int64)


def target_scores(grad_plane_norm, expected_cov, candidates) -> np.ndarray:
    """Eq. 35 utility of each candidate: |grad H_G(l)| * (1 - E[C_l]) (float64).

    ``grad_plane_norm`` and ``expected_cov`` are fields (any shape, read in flat C order)
    of the projected-gradient magnitude and the expected coverage; ``candidates`` are
    flat indices (e.g. from :func:`candidate_voxels`, possibly filtered for reachability).
    """
    c = np.asarray(candidates, dtype=np.int64).ravel()
    g = np.asarray(grad_plane_norm).reshape(-1)
    ec = np.asarray(expected_cov).reshape(-1)
    return g[c].astype(np.float64) * (1.0 - ec[c].astype(np.float64))


@dataclass(frozen=True)
class Target:
    """The selected voxel l_s (flat index), its eq. 35 score and the gaze on arrival."""

    index: int
    score: float
    gaze: np.ndarray


def select_target(grad_plane, expected_cov, candidates, min_score: float = 0.0) -> Target | None:
    """l_s = argmax over candidates of |grad H_G(l)| (1 - E[C_l]) (eq. 35), with its gaze.

    ``grad_plane`` is the projected gradient field (..., 3) (e.g. (nx, ny, nz, 3) from
    :func:`projected_gradient`), ``expected_cov`` the expected-coverage field, both read
    in flat C order. The gaze is grad H_G(l_s) / |grad H_G(l_s)| (eq. 34): it points
    towards higher entropy (the paper's minus sign belongs to its difference convention,
    docs/design.md). Ties go to the first candidate in the given order. Returns None when there
    is no candidate or the best score is not above ``min_score`` (the criterion is not
    conclusive: the caller wanders). Non-finite scores never win.
    """
    c = np.asarray(candidates, dtype=np.int64).ravel()
    if c.size == 0:
        return None
    g = np.asarray(grad_plane)
    if g.shape[-1] != 3:
        raise ValueError(f"grad_plane must have a last axis of 3, got shape {g.shape}")
    vec = g.reshape(-1, 3)[c].astype(np.float64)
    norm = np.sqrt(np.einsum("ij,ij->i", vec, vec))
    scores = target_scores(norm, np.asarray(expected_cov).reshape(-1)[c], np.arange(c.size))
    scores[~np.isfinite(scores)] = -np.inf  # a NaN belief never wins
    best = int(np.argmax(scores))
    score = float(scores[best])
    if not score > min_score:
        return None
    return Target(index=int(c[best]), score=score, gaze=vec[best] / norm[best])
