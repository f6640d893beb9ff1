"""Sub-pixel refinement of a disparity image: one 1-D Lucas-Kanade step on the rectified pair (Numba).

SGBM's own sub-pixel step fits a parabola to its aggregated cost at d - 1, d, d + 1; that fit is
biased towards whole pixels ("pixel locking": a surface at 8.25 px comes out near 8.16, at 8.75
near 8.87). This step fits the images themselves instead. With the disparity ``d`` of every
pixel, the right image is sampled at ``u - d`` (linear interpolation) and the residual
``e = L(u) - R(u - d)`` is linearised in a correction ``delta`` common to a ``window`` x
``window`` neighbourhood, with a brightness offset ``b`` (the two cameras' exposures differ):

    L(u) - R(u - d - delta) ~ e + G delta,     minimise  sum over the window of (e + G delta - b)^2

where ``G`` is the x-gradient, averaged between the left image at ``u`` and the right image at
``u - d``. The two normal equations are solved per pixel from six window sums (count, G, e, G^2,
G e, e^2; running sums, so the cost does not grow with the window). Each neighbour enters with
its *own* disparity, so a slanted surface or a neighbour across an edge still contributes a
residual at its own match. The correction is kept only where it is below ``max_step`` pixels,
the window has x-texture (gradient variance above ``min_gradient_var``) and ``delta`` is at
least ``min_significance`` standard errors from 0 (the standard error from the window's
residual sum of squares); elsewhere SGBM's value stays, and a pixel without a disparity gets
none. This is the Lucas-Kanade (1981) registration step restricted to the epipolar line.

``tests/support/stereo_oracle.py`` keeps a pixel-by-pixel form (each window solved with
``np.linalg.lstsq``) that the tests compare this kernel with.
"""

from __future__ import annotations

import numpy as np
from numba import njit

#: The default neighbourhood (pixels, odd): on seven Middlebury pairs 11 beat 5 and 7 (docs/stereo.md).
DEFAULT_WINDOW = 11
#: Corrections of this many pixels or more are not trusted (SGBM's match stays).
DEFAULT_MAX_STEP = 0.5
#: Windows whose x-gradient variance (grey levels^2 per pixel^2) is below this keep SGBM's value.
DEFAULT_MIN_GRADIENT_VAR = 1e-3
#: A correction is kept only when it is this many standard errors from 0 (else SGBM's value stays).
DEFAULT_MIN_SIGNIFICANCE = 2.0


def refine_disparity(
    left: np.ndarray,
    right: np.ndarray,
    disparity: np.ndarray,
    window: int = DEFAULT_WINDOW,
    max_step: float = DEFAULT_MAX_STEP,
    min_gradient_var: float = DEFAULT_MIN_GRADIENT_VAR,
    min_significance: float = DEFAULT_MIN_SIGNIFICANCE,
) -> np.ndarray:
    """The disparity (H, W) float32 pixels (NaN invalid) after one sub-pixel Lucas-Kanade step.

    ``left``, ``right``: the rectified gray pair (H, W) uint8, left the reference;
    ``disparity``: (H, W) float32, NaN where invalid (stays NaN). Raises ValueError on
    mismatched shapes or an even or non-positive ``window``.
    """
    if left.shape != right.shape or left.shape != disparity.shape or left.ndim != 2:
        raise ValueError(
            f"left {left.shape}, right {right.shape} and disparity {disparity.shape} must be one (H, W) shape"
        )
    if window < 1 or window % 2 == 0:
        raise ValueError(f"window must be odd and >= 1, got {window}")
    return _refine(
        np.ascontiguousarray(left, np.uint8),
        np.ascontiguousarray(right, np.uint8),
        np.ascontiguousarray(disparity, np.float32),
        window // 2,
        float(max_step),
        float(min_gradient_var),
        float(min_significance),
    )


#: Fast-math flags that keep NaN and inf semantics (the kernel tests for NaN disparities).
_FAST = {"contract", "arcp", "reassoc", "nsz"}

#: Per-pixel terms of the normal equations: count, G, e, G^2, G e, e^2.
_TERMS = 6


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST)
def _refine(left, right, disp, radius, max_step, min_gradient_var, min_significance):
    h, w = disp.shape
    out = disp.copy()
    # Rows stream through a ring of 2 radius + 1 rows of per-pixel terms; ``column`` holds the
    # vertical window sums of every column (float64: e^2 sums reach 1e7). A row leaving the
    # window and the row entering it share a ring slot.
    rows = 2 * radius + 1
    ring = np.zeros((rows, w * _TERMS), np.float32)
    column = np.zeros(w * _TERMS)
    for v in range(min(radius, h)):
        _row_terms(left, right, disp, v, ring[v % rows])
        column += ring[v % rows]
    for v in range(h):
        if v + radius < h:
            slot = ring[(v + radius) % rows]
            if v - radius - 1 >= 0:
                column -= slot
            _row_terms(left, right, disp, v + radius, slot)
            column += slot
        elif v - radius - 1 >= 0:
            column -= ring[(v - radius - 1) % rows]
            ring[(v - radius - 1) % rows] = 0.0
        centre = ring[v % rows]
        n = sg = se = sgg = sge = see = 0.0
        for u in range(min(radius, w)):
            j = u * _TERMS
            n += column[j]
            sg += column[j + 1]
            se += column[j + 2]
            sgg += column[j + 3]
            sge += column[j + 4]
            see += column[j + 5]
        for u in range(w):
            if u + radius < w:
                j = (u + radius) * _TERMS
                n += column[j]
                sg += column[j + 1]
                se += column[j + 2]
                sgg += column[j + 3]
                sge += column[j + 4]
                see += column[j + 5]
            if u - radius - 1 >= 0:
                j = (u - radius - 1) * _TERMS
                n -= column[j]
                sg -= column[j + 1]
                se -= column[j + 2]
                sgg -= column[j + 3]
                sge -= column[j + 4]
                see -= column[j + 5]
            if centre[u * _TERMS] == 0.0:
                continue
            delta = _step(n, sg, se, sgg, sge, see, min_gradient_var, min_significance)
            if abs(delta) < max_step:
                out[v, u] = disp[v, u] + np.float32(delta)
    return out


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST)
def _step(n, sg, se, sgg, sge, see, min_gradient_var, min_significance):
    """The least-squares correction of a window's sums, or inf where it is not trusted.

    Model: e = -G delta + b (b the brightness offset); det = n S_GG - S_G^2 is n^2 times the
    gradient variance; the residual sum of squares gives delta's standard error.
    """
    det = sgg * n - sg * sg
    if not (n > 2.0 and det > min_gradient_var * n * n):
        return np.inf
    scale = 1.0 / det
    delta = -(sge * n - sg * se) * scale
    offset = (se * sgg - sg * sge) * scale
    rss = max(see + delta * sge - offset * se, 0.0)
    # delta^2 > k^2 var(delta), var(delta) = rss / (n - 2) * n / det, without a division
    if delta * delta * (n - 2.0) * det <= min_significance * min_significance * rss * n:
        return np.inf
    return delta


@njit(cache=True, nogil=True, error_model="numpy", fastmath=_FAST)
def _row_terms(left, right, disp, v, terms):
    """Write row ``v``'s per-pixel terms into ``terms`` (W * _TERMS float32); zero where d is
    invalid or its match lacks a neighbour on each side (the gradient needs both)."""
    w = disp.shape[1]
    terms[:] = 0.0
    half = np.float32(0.5)
    # The right row and its central x-differences, once per row (columns 1 .. w - 2 are used).
    row = right[v].astype(np.float32)
    grad = np.zeros(w, np.float32)
    for x in range(1, w - 1):
        grad[x] = half * (row[x + 1] - row[x - 1])
    for u in range(1, w - 1):
        d = disp[v, u]
        if not np.isfinite(d):
            continue
        x = np.float32(u) - d
        if not (x >= 1.0 and x < w - 2):
            continue  # both samples need a neighbour on each side
        x0 = int(x)
        a = x - np.float32(x0)
        r0 = row[x0]
        g = half * (
            (grad[x0] + a * (grad[x0 + 1] - grad[x0]))
            + half * (np.float32(left[v, u + 1]) - np.float32(left[v, u - 1]))
        )
        e = np.float32(left[v, u]) - (r0 + a * (row[x0 + 1] - r0))
        j = u * _TERMS
        terms[j] = 1.0
        terms[j + 1] = g
        terms[j + 2] = e
        terms[j + 3] = g * g
        terms[j + 4] = g * e
        terms[j + 5] = e * e
