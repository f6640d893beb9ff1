"""The exploration strategies a robot can follow (docs/design.md section 3), named once.

- ``"entropy"``: the paper's entropy-gradient target (eq. 27-35);
- ``"frontier"``: the nearest reachable frontier (Yamauchi 1997);
- ``"random"``: a uniformly random reachable cell.

No imports: the command line reads these names without loading the navigation maths.
"""

from __future__ import annotations

from typing import Literal

Strategy = Literal["entropy", "frontier", "random"]
STRATEGIES: tuple[Strategy, ...] = ("entropy", "frontier", "random")


def check_strategy(strategy: str) -> Strategy:
    """``strategy`` itself when it is one of STRATEGIES; ValueError naming them otherwise."""
    if strategy not in STRATEGIES:
        raise ValueError(f"unknown exploration strategy {strategy!r}; expected one of {STRATEGIES}")
    return strategy  # type: ignore[return-value]
