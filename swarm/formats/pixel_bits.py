"""16-bit images' significant bits: a 10- or 12-bit camera's values sit in the low bits of 16-bit
samples (0..1023, 0..4095), whose top 8 bits would be black. ``SignificantBits`` finds the bits
from the brightest pixel of images spread over a whole recording (bags, ASL folders, stereo pairs), and
``to_8_bits`` scales by them.
"""

from __future__ import annotations

import numpy as np


class SignificantBits:
    """The significant bits of a recording's 16-bit images (8, 10, 12, 14 or 16), from the
    brightest pixel of up to ``samples`` images of each topic, spread evenly over its
    ``message_counts`` messages (a camera that starts in the dark and sees light later is judged
    by both)."""

    BITS = (8, 10, 12, 14, 16)

    def __init__(self, message_counts: dict[str, int], samples: int = 30) -> None:
        self._picked = {  # a count the bag's index does not give (0): the first images
            name: set(np.linspace(0, count - 1, min(samples, count)).round().astype(int).tolist())
            if count > 0
            else set(range(samples))
            for name, count in message_counts.items()
        }
        self.peak = 0  # the brightest 16-bit value seen
        self.images = 0  # 16-bit images looked at

    def wants(self, name: str, index: int) -> bool:
        """Whether message ``index`` (from 0, in the order read) of topic ``name`` is a sample."""
        return index in self._picked.get(name, ())

    def add(self, image: np.ndarray) -> None:
        """Look at a sampled image (8-bit ones say nothing about 16-bit values and are skipped)."""
        if image.dtype == np.uint16:
            self.peak = max(self.peak, int(image.max()))
            self.images += 1

    @property
    def bits(self) -> int | None:
        """The bits the brightest sampled pixel needs; None when no 16-bit image was sampled."""
        if not self.images:
            return None
        return next(b for b in self.BITS if self.peak < 2**b)


def to_8_bits(image: np.ndarray, bits: int | None) -> np.ndarray:
    """A 16-bit image scaled to 8 bits by its ``bits`` significant bits (None: 16), brighter values
    saturating at 255; an 8-bit image as it is."""
    if image.dtype != np.uint16:
        return image
    shift = (bits or 16) - 8
    return np.minimum(image >> shift, 255).astype(np.uint8)
