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


def reference_refine_disparity(left, right, disp, window, max_step, min_gradient_var, min_significance):
    """``subpixel.refine_disparity`` pixel by pixel: each window's terms gathered and solved with
    ``np.linalg.lstsq`` (e = -G delta + b), delta's standard error from the residuals."""
    left = left.astype(np.float64)
    right = right.astype(np.float64)
    h, w = disp.shape
    grad, resid = np.zeros((h, w)), np.zeros((h, w))
    used = np.zeros((h, w), bool)
    for v in range(h):
        grad_right = np.gradient(right[v])  # central differences inside the row
        grad_left = np.gradient(left[v])
        for u in range(1, w - 1):
            if not np.isfinite(disp[v, u]):
                continue
            x = u - float(disp[v, u])
            x0 = int(np.floor(x))
            if x0 < 1 or x0 + 2 > w - 1:
                continue  # both samples need a neighbour on each side
            a = x - x0
            grad[v, u] = 0.5 * ((1 - a) * grad_right[x0] + a * grad_right[x0 + 1] + grad_left[u])
            resid[v, u] = left[v, u] - ((1 - a) * right[v, x0] + a * right[v, x0 + 1])
            used[v, u] = True
    out = disp.astype(np.float32).copy()
    r = window // 2
    for v in range(h):
        for u in range(w):
            if not used[v, u]:
                continue
            box = (slice(max(v - r, 0), v + r + 1), slice(max(u - r, 0), u + r + 1))
            g, e = grad[box][used[box]], resid[box][used[box]]
            n = g.size
            design = np.stack([-g, np.ones(n)], axis=1)
            if n <= 2 or np.linalg.det(design.T @ design) <= min_gradient_var * n * n:
                continue
            solution = np.linalg.lstsq(design, e, rcond=None)[0]
            rss = float(np.sum((design @ solution - e) ** 2))
            variance = rss / (n - 2) * np.linalg.inv(design.T @ design)[0, 0]
            delta = solution[0]
            if delta**2 > min_significance**2 * variance and abs(delta) < max_step:
                out[v, u] = disp[v, u] + np.float32(delta)
    return out
