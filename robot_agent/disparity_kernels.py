"""Compiled per-pixel steps of stereo (Numba): SGBM's raw output to disparity, disparity to depth.

At 640x480 the numpy forms of these two steps took about 6 ms of a 60 ms pair (four
temporaries and a masked assignment each); one pass per step takes well under 1 ms.
``tests/support/stereo_oracle.py`` keeps the numpy forms, which the tests compare these with.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True, error_model="numpy")
def valid_disparity(raw, pad_left, width, min_disparity, texture, min_texture_sq):
    """Disparity (H, ``width``) float32 in pixels, NaN where invalid, from SGBM's fixed-point output.

    ``raw`` (H, W') int16 is ``StereoSGBM.compute``'s output (16 x disparity) of images padded
    by ``pad_left`` columns; the image's columns are ``pad_left .. pad_left + width``. A pixel
    is invalid when SGBM marked it (below ``min_disparity``), when its match u - d lies
    outside the right image (columns 0 .. width - 1), or when ``texture`` (H, width) grey-level
    variance is below ``min_texture_sq`` (pass an empty (0, 0) array for no texture filter).
    """
    h = raw.shape[0]
    out = np.empty((h, width), np.float32)
    lowest = min_disparity * 16
    sixteenth = np.float32(1.0 / 16.0)
    last = np.float32(width - 1)
    textured = texture.shape[0] > 0
    for v in range(h):
        for u in range(width):
            r = raw[v, pad_left + u]
            d = np.float32(r) * sixteenth
            column = np.float32(u)
            ok = r >= lowest and not d > column
            if min_disparity < 0 and d < column - last:
                ok = False
            if textured and texture[v, u] < min_texture_sq:
                ok = False
            out[v, u] = d if ok else np.float32(np.nan)
    return out


@njit(cache=True, nogil=True, error_model="numpy")
def depth_of_disparity(disp, fb, offset):
    """Depth Z = fb / (d + offset) in metres (float32, the shape of ``disp``), NaN where d + offset <= 0
    or d is NaN; ``disp`` float32 C-contiguous, ``fb`` = fx * baseline, ``offset`` = cx_right - cx."""
    flat = disp.ravel()
    out = np.empty(flat.size, np.float32)
    fb32 = np.float32(fb)
    offset32 = np.float32(offset)
    for n in range(flat.size):
        denom = flat[n] + offset32
        out[n] = fb32 / denom if denom > 0 else np.float32(np.nan)
    return out.reshape(disp.shape)
