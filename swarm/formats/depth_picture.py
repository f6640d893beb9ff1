"""Depth images as pictures: one colour rule and a colour bar in metres.

Used by ``swarm sim render`` (depth.png) and ``swarm stereo depth --png``. Near is red,
far is blue (OpenCV's turbo map, linear in metres from ``near`` to ``far``); pixels
without a return (NaN, or depth <= 0) are black. A bar on the right gives the scale with
tick labels in metres; when some depths lie beyond an end of the scale (and take its
colour), that end's label says so: ">=5 m", "<=0.93 m".
"""

from __future__ import annotations

import math

import cv2
import numpy as np

#: Small images are enlarged (nearest neighbour) to at least this height, so the bar's labels read.
MIN_HEIGHT = 240
BAR_WIDTH = 84
#: The part of OpenCV's turbo map used, far to near: its dark ends are left out, so that far is
#: plainly blue and near plainly red.
TURBO_SPAN = (30, 225)


def depth_picture(depth: np.ndarray, near: float, far: float) -> np.ndarray:
    """A BGR uint8 picture of ``depth`` (H x W, metres) with a colour bar from ``near`` to ``far`` m.

    Depths outside [near, far] take the end colours, and the bar's end labels then read
    "<=near m" / ">=far m". Returns an image of height max(H, ~240) and width (scaled W) + 84.
    Raises ValueError unless 0 <= near < far, finite.
    """
    if not (math.isfinite(near) and math.isfinite(far) and 0 <= near < far):
        raise ValueError(f"depth picture: need 0 <= near < far, finite (got {near}, {far})")
    depth = np.asarray(depth, dtype=np.float64)
    seen = np.isfinite(depth) & (depth > 0)
    scale = np.clip((far - np.where(seen, depth, far)) / (far - near), 0.0, 1.0)  # 1 = near
    picture = _turbo(scale)
    picture[~seen] = 0
    factor = max(1, math.ceil(MIN_HEIGHT / depth.shape[0]))
    if factor > 1:
        picture = cv2.resize(picture, None, fx=factor, fy=factor, interpolation=cv2.INTER_NEAREST)
    labels = tick_labels(
        near, far, nearer=bool(np.any(depth[seen] < near)), farther=bool(np.any(depth[seen] > far))
    )
    return np.hstack([picture, colour_bar(picture.shape[0], near, far, labels)])


def tick_labels(near: float, far: float, nearer: bool = False, farther: bool = False) -> list[str]:
    """The bar's 5 tick labels, near to far, in metres; an end that also stands for depths
    beyond it (``nearer``, ``farther``: some pixels lie there) reads "<=" or ">="."""
    labels = [f"{near + (far - near) * i / 4:.3g} m" for i in range(5)]
    if nearer:
        labels[0] = "<=" + labels[0]
    if farther:
        labels[-1] = ">=" + labels[-1]
    return labels


def colour_bar(height: int, near: float, far: float, labels: list[str] | None = None) -> np.ndarray:
    """The bar: near (red) at the top, far (blue) at the bottom, 5 ticks labelled in metres
    (``labels``, default ``tick_labels(near, far)``)."""
    labels = tick_labels(near, far) if labels is None else labels
    bar = np.full((height, BAR_WIDTH, 3), 255, np.uint8)
    top, bottom = 18, height - 8
    strip = np.linspace(1.0, 0.0, bottom - top)  # 1 = near at the top
    colours = _turbo(strip.reshape(-1, 1))
    bar[top:bottom, 6:20] = colours.reshape(-1, 1, 3)
    font = cv2.FONT_HERSHEY_SIMPLEX
    cv2.putText(bar, "depth", (4, 12), font, 0.38, (0, 0, 0), 1, cv2.LINE_AA)
    for i, label in enumerate(labels):
        y = top + round((bottom - top - 1) * i / 4)
        cv2.line(bar, (20, y), (25, y), (0, 0, 0), 1)
        cv2.putText(bar, label, (27, y + 4), font, 0.36, (0, 0, 0), 1, cv2.LINE_AA)
    return bar


def _turbo(scale: np.ndarray) -> np.ndarray:
    """BGR colours of ``scale`` in [0, 1] (0 = far, blue; 1 = near, red)."""
    lo, hi = TURBO_SPAN
    return cv2.applyColorMap((lo + (hi - lo) * scale).astype(np.uint8), cv2.COLORMAP_TURBO)
