"""The numpy forms of stereo's per-pixel steps: the oracles of ``robot_agent.disparity_kernels``."""

from __future__ import annotations

import numpy as np


def reference_valid_disparity(raw, pad_left, width, min_disparity, texture, min_texture_sq):
    """``disparity_kernels.valid_disparity`` with numpy masks (the agent's code before it)."""
    raw = raw[:, pad_left : pad_left + width]
    disp = raw.astype(np.float32)
    disp *= np.float32(1.0 / 16.0)
    invalid = raw < min_disparity * 16
    columns = np.arange(width, dtype=np.float32)
    invalid |= disp > columns
    if min_disparity < 0:
        invalid |= disp < columns - np.float32(width - 1)
    if texture.size:
        invalid |= texture < np.float32(min_texture_sq)
    disp[invalid] = np.nan
    return disp


def reference_depth(disp, fb, offset):
    """``disparity_kernels.depth_of_disparity`` with ``np.where``."""
    denom = np.asarray(disp, dtype=np.float32) + np.float32(offset)
    with np.errstate(divide="ignore", invalid="ignore"):
        depth = np.where(denom > 0, np.float32(fb) / denom, np.float32(np.nan))
    return depth.astype(np.float32, copy=False)
