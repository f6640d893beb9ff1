"""Eq. 14 of one voxel, compiled (Numba, inlined into the fusion loops of
``swarm.map.fusion_kernel`` and ``swarm.map.block_kernels``).

Given a ray that ends at distance d (metres) from the sensor and a voxel whose centre is at
distance r, eq. 14 gives the voxel's information lam = 1 / sigma^2 and its mean mu (0 in
front of the end, 1 behind it). In front of the end lam is the ray's gain
exp(2 (d - e/2) / tau) / sigma_s^2 times the voxel's damping exp(-2 r / tau); the fusion loops
sum the gains of the voxels surely in front and apply the damping once per voxel
(:func:`voxel_lam`). Every lam is bounded by :data:`LAM_MAX`, so any finite input gives
finite sums. Distances are float32 like the fusion's sums; the gains are float64.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

#: Upper bound of one measurement's information lam = 1/sigma^2 on one voxel (sigma >= 1e-12).
#: Eq. 14's damping makes lam grow as exp(2 (d - d_l) / tau), which overflows float32 for rays
#: longer than about 85 m (tau = 2 m); the bound keeps any finite input finite.
LAM_MAX = 1e24

#: exp() arguments up to this stay far from float64's overflow and underflow.
EXP_LIMIT = 600.0


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def centre_distance(i, j, k, voxel, centre_offset):
    """Distance r (float32, metres) from the sensor to the centre of voxel (i, j, k)."""
    ox = i * voxel + centre_offset[0]
    oy = j * voxel + centre_offset[1]
    oz = k * voxel + centre_offset[2]
    return np.float32(math.sqrt(np.float32(ox * ox + oy * oy + oz * oz)))


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def voxel_information(diff, r32, half32, two_over_tau, two_over_tau32, inv_s2, gain):
    """Eq. 14's lam of one voxel at distance ``r32`` and float32 offset ``diff`` = r - d from the ray's end.

    Inside the end voxel's half width lam = 1 / sigma_s^2; in front of it
    lam = exp(2 (d - e/2 - r) / tau) / sigma_s^2, computed as the ray's gain =
    exp(2 (d - e/2) / tau) / sigma_s^2 times the voxel's exp(-2 r / tau) when both are finite
    and non-zero; otherwise, and behind the end, from eq. 14 directly. Bounded by LAM_MAX.
    """
    ad = abs(diff)
    if ad <= half32:
        return min(inv_s2, LAM_MAX)
    if diff < 0 and gain > 0.0:
        arg = two_over_tau * np.float64(r32)
        if arg < EXP_LIMIT:
            w = math.exp(-arg)
            if w > 0.0:
                return min(gain * w, LAM_MAX)
    return min(np.float64(math.exp((ad - half32) * two_over_tau32)) * inv_s2, LAM_MAX)


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def voxel_mean(diff, inv_voxel):
    """Eq. 14's mean mu of a voxel at float32 offset ``diff`` = r - d from a return (0 in front, 1 behind)."""
    return min(max(np.float32(0.5) + diff * inv_voxel, np.float32(0.0)), np.float32(1.0))


@njit(cache=True, nogil=True, error_model="numpy", inline="always")
def voxel_lam(g, other, i, j, k, voxel, centre_offset, two_over_tau):
    """A touched voxel's lam from its sums: the gain sum ``g`` times its damping exp(-2 r / tau)
    (none when ``g`` <= 0), plus ``other``."""
    total = other
    if g > 0.0:
        total += g * math.exp(-two_over_tau * np.float64(centre_distance(i, j, k, voxel, centre_offset)))
    return total
