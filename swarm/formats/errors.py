"""The errors of user input: every file or value a user hands the project.

Each is raised with a message of one line per problem, ``FILE: FIELD: what is wrong``; the
command line prints it as ``error: ...`` and exits with status 2 (``swarm.cli``). Catch
:class:`InputError` to handle them all.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from pathlib import Path


class InputError(ValueError):
    """A file, field or value from a user that cannot be used; the message names where and why."""


class FloorPlanError(InputError):
    """A floor plan (project YAML or ROS ``map.yaml`` and its image) that cannot be read."""


class CalibrationError(InputError):
    """An unusable calibration: the message names the file, the field and the problem."""


class RecordingError(InputError):
    """An unusable recording or camera stream: the message names the file or topic (and column or field)."""


def non_finite_numbers(data: object, where: str = "") -> Iterator[tuple[str, float]]:
    """(dotted field, value) of every NaN or infinite float inside parsed YAML/JSON ``data``.

    Mappings give ``a.b``, sequences ``a[0]``; ``where`` is the prefix of the top level.
    """
    if isinstance(data, float):
        if not math.isfinite(data):
            yield where or "(top level)", data
    elif isinstance(data, dict):
        for key, value in data.items():
            yield from non_finite_numbers(value, f"{where}.{key}" if where else str(key))
    elif isinstance(data, list | tuple):
        for i, value in enumerate(data):
            yield from non_finite_numbers(value, f"{where}[{i}]")


def refuse_non_finite(data: object, source: str | Path | None, error: type[ValueError]) -> None:
    """Raise ``error`` naming every key of ``data`` that holds NaN or an infinity.

    NaN and infinities are never a setting: a map saver that wrote ``origin: [0, 0, .nan]``
    would otherwise turn every wall into NaN. (Depth images and point clouds are not read
    through here; there NaN keeps its meaning of "no return".)
    """
    bad = list(non_finite_numbers(data))
    if bad:
        lines = [
            f"{source or '<input>'}: {field}: must be a finite number (got {value})" for field, value in bad
        ]
        raise error("\n".join(lines))


def user_path(text: str, base_dir: Path) -> Path:
    """A path written in a user's file: ``~`` and ``~user`` expanded, relative ones taken from ``base_dir``.

    (ROS map_server does not expand ``~``; a ``map.yaml`` that relies on it loads here only.)
    """
    path = Path(text).expanduser()
    return path if path.is_absolute() else base_dir / path
