"""Numbers as users read them: never ``-0.0`` or ``-0.00``.

A coordinate or a shift that rounds to zero from below prints as ``-0.0`` in Python
(``round(-1e-9, 6)``, ``f"{-0.001:.2f}"``); in a message, a file name or a config it reads as
a sign that means something. :func:`shown` rounds and drops the sign of a zero.
"""

from __future__ import annotations


def shown(value: float, digits: int | None = None) -> float:
    """``value`` as a float, rounded to ``digits`` decimals when given, ``-0.0`` made ``0.0``."""
    v = float(value) if digits is None else round(float(value), digits)
    return v + 0.0  # IEEE 754: -0.0 + 0.0 == +0.0; any other value is unchanged
