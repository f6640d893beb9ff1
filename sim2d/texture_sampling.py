"""The renderer's procedural surface texture: a mip-mapped periodic noise tile and its lookup.

A square tile of band-limited 1/f noise (values 0-1, side a power of two) and its box-filtered
mip levels live in one flat float32 array, each level stored in 4 x 4 texel blocks (64 bytes,
one cache line) so that the four texels of a bilinear lookup, and those of the next image
row, are mostly in one line. A pixel covering ``footprint`` metres of surface
reads the level of detail lod = log2(footprint / texel), clipped to the pyramid, and blends
bilinear lookups of the two levels around it (trilinear filtering), so distant surfaces do
not alias. Lookups are compiled with Numba; each is one pixel's worth of scalar arithmetic,
done in the same order as numpy would, so results do not depend on how pixels are batched.

When editing this module: ``render_kernels.shade_pixels`` compiles ``trilinear`` into itself,
and Numba's cache of it is keyed on ``render_kernels.py`` alone, so also touch that file (or
delete ``sim2d/__pycache__/*.nbi`` and ``*.nbc``), else the old lookup keeps running.
"""

from __future__ import annotations

import functools
import math

import numba
import numpy as np

BLOCK = 4  # texels per side of a storage block (``_row_offset`` and ``_column_offset`` assume 4)


class TexturePyramid:
    """A periodic square grey texture tile (values 0-1) with its mip levels, in metres.

    ``texel`` is the finest texel's size (m). ``texels`` holds every level, level k (side
    ``sizes[k]``, texel ``texel`` / ``shrink[k]`` m) from ``starts[k]``, in 4 x 4 blocks (row-major blocks
    of row-major texels; levels smaller than 4 x 4 are plain row-major): see ``level``.
    """

    def __init__(self, tile: np.ndarray, texel: float):
        if tile.ndim != 2 or tile.shape[0] != tile.shape[1] or tile.shape[0] & (tile.shape[0] - 1):
            raise ValueError(f"texture tile: must be square with a power-of-two side (got {tile.shape})")
        self.texel = texel
        levels = [tile.astype(np.float32)]
        while levels[-1].shape[0] > 1:
            t = levels[-1]
            levels.append(0.25 * (t[::2, ::2] + t[1::2, ::2] + t[::2, 1::2] + t[1::2, 1::2]))
        self.count = len(levels)
        self.sizes = np.array([lvl.shape[0] for lvl in levels], dtype=np.int64)
        self.starts = np.concatenate([[0], np.cumsum(self.sizes**2)[:-1]]).astype(np.int64)
        self.shrink = np.exp2(-np.arange(self.count, dtype=np.float64))  # 2^-k, exact
        self.texels = np.concatenate([_blocked(lvl) for lvl in levels])

    def level(self, k: int) -> np.ndarray:
        """Mip level ``k`` as a (side, side) float32 array, row = v, column = u."""
        n = int(self.sizes[k])
        flat = self.texels[self.starts[k] : self.starts[k] + n * n]
        if n < BLOCK:
            return flat.reshape(n, n)
        return flat.reshape(n // BLOCK, n // BLOCK, BLOCK, BLOCK).transpose(0, 2, 1, 3).reshape(n, n)

    def sample(self, u: np.ndarray, v: np.ndarray, footprint: np.ndarray) -> np.ndarray:
        """Trilinear lookup (values 0-1) at (u, v) metres for pixels covering ``footprint`` metres.

        ``u``, ``v``, ``footprint``: arrays of one shape; returns float64 of that shape.
        """
        arrays = np.broadcast_arrays(u, v, footprint)
        u, v, footprint = (np.ascontiguousarray(a, dtype=np.float64) for a in arrays)
        out = np.empty(u.shape)
        trilinear(self.texels, self.starts, self.sizes, self.shrink, self.texel, u.ravel(), v.ravel(),
                  footprint.ravel(), u.size, np.empty((3, u.size)), out.reshape(-1))  # fmt: skip
        return out


def _blocked(level: np.ndarray) -> np.ndarray:
    """A square level flattened in BLOCK x BLOCK blocks (inverse of ``TexturePyramid.level``)."""
    n = level.shape[0]
    if n < BLOCK:
        return level.ravel()
    return level.reshape(n // BLOCK, BLOCK, n // BLOCK, BLOCK).transpose(0, 2, 1, 3).ravel()


@numba.njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _row_offset(n, j):
    """Where row ``j`` of an n x n level starts in that level's block layout (add ``_column_offset``)."""
    if n < BLOCK:
        return j * n
    return ((j >> 2) * n + (j & 3)) << 2  # block row (j >> 2) holds n / 4 blocks of 16 texels


@numba.njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _column_offset(n, i):
    """Offset of column ``i`` within a row of an n x n level's block layout."""
    if n < BLOCK:
        return i
    return ((i >> 2) << 4) + (i & 3)


@numba.njit(cache=True, nogil=True, inline="always", error_model="numpy")
def _bilinear(texels, starts, sizes, level, x, y):
    """Bilinear lookup of mip ``level`` at (x, y) in that level's texels (the tile repeats)."""
    n = sizes[level]
    x0 = math.floor(x)
    y0 = math.floor(y)
    fx = x - x0
    fy = y - y0
    wrap = n - 1
    i0 = np.int64(x0) & wrap
    j0 = np.int64(y0) & wrap
    base = starts[level]
    row0 = base + _row_offset(n, j0)
    row1 = base + _row_offset(n, (j0 + 1) & wrap)
    col0 = _column_offset(n, i0)
    col1 = _column_offset(n, (i0 + 1) & wrap)
    top = texels[row0 + col0] * (1 - fx) + texels[row0 + col1] * fx
    bottom = texels[row1 + col0] * (1 - fx) + texels[row1 + col1] * fx
    return top * (1 - fy) + bottom * fy


@numba.njit(cache=True, nogil=True, error_model="numpy")
def trilinear(texels, starts, sizes, shrink, texel, u, v, footprint, count, scratch, out):
    """Trilinear lookups of the first ``count`` pixels: (u, v) and ``footprint`` in m.

    The arrays of a ``TexturePyramid``, then (N,) ``u``, ``v``, ``footprint``, a (3, N)
    ``scratch`` and ``out`` (values 0-1). Level k's texel is texel 2^k, so u / (texel 2^k) is
    (u / texel) 2^-k exactly (scaling by a power of two does not round; ``shrink[k]`` = 2^-k):
    one division per coordinate. log2 is monotonic and exact at 1, so a footprint of at most
    one texel has level of detail 0 without calling it. Where the level of detail is clipped
    (lod - fine = 0) the second level has no weight and is not read: a + (b - a) 0 = a. In
    passes (divisions, levels of detail, lookups) so that the divisions of several pixels go
    in one vector instruction and the processor overlaps the lookups of many pixels.
    """
    top_level = len(sizes) - 1
    lod, x, y = scratch[0], scratch[1], scratch[2]
    for k in range(count):
        x[k] = u[k] / texel
        y[k] = v[k] / texel
        lod[k] = max(footprint[k], 1e-9) / texel
    for k in range(count):
        ratio = lod[k]
        lod[k] = 0.0 if ratio <= 1.0 else min(math.log2(ratio), float(top_level))
    for k in range(count):
        fine = np.int64(math.floor(lod[k]))
        step = shrink[fine]
        a = _bilinear(texels, starts, sizes, fine, x[k] * step - 0.5, y[k] * step - 0.5)
        weight = lod[k] - fine
        if weight == 0:
            out[k] = a
            continue
        coarse = min(fine + 1, top_level)
        step = shrink[coarse]
        b = _bilinear(texels, starts, sizes, coarse, x[k] * step - 0.5, y[k] * step - 0.5)
        out[k] = a + (b - a) * weight


@functools.lru_cache(maxsize=4)
def texture_pyramid(seed: int, size: int = 1024, texel: float = 0.004) -> TexturePyramid:
    """Band-limited 1/f noise on a periodic ``size`` x ``size`` tile of ``texel`` m, squashed to 0-1."""
    rng = np.random.default_rng([seed, 1])
    freq = np.fft.fftfreq(size)
    radius = np.hypot(freq[:, None], freq[None, :])
    amplitude = np.where(radius > 0, 1.0 / np.maximum(radius, 1.0 / size) ** 0.9, 0.0)
    amplitude *= np.exp(-((radius / 0.35) ** 4))  # gentle roll-off near Nyquist
    spectrum = np.fft.fft2(rng.standard_normal((size, size))) * amplitude
    tile = np.real(np.fft.ifft2(spectrum))
    tile = (tile - tile.mean()) / tile.std()
    tile = 0.5 + 0.5 * np.tanh(0.8 * tile)
    return TexturePyramid(tile, texel)
