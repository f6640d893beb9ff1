"""Reading a YAML file with errors that name the file (and every non-finite number's key)."""

from __future__ import annotations

from pathlib import Path

import yaml

from swarm.formats.errors import refuse_non_finite


def read_yaml(path: Path, error: type[ValueError], *, finite: bool = True) -> object:
    """The parsed contents of ``path``; unreadable or invalid files raise ``error`` naming it.

    With ``finite`` (the default) a NaN or infinity anywhere (``.nan``, ``.inf``) is refused
    too, naming its key: no setting of the project means "not a number".
    """
    try:
        with open(path, encoding="utf-8") as f:
            data = yaml.safe_load(f)
    except IsADirectoryError as e:
        raise error(f"{path}: is a folder, not a YAML file") from e
    except FileNotFoundError as e:
        raise error(f"{path}: file not found") from e
    except OSError as e:
        raise error(f"{path}: cannot read: {e.strerror or e}") from e
    except UnicodeDecodeError as e:
        raise error(f"{path}: not a text file (byte {e.start} is not UTF-8)") from e
    except yaml.YAMLError as e:
        raise error(f"{path}: not valid YAML: {yaml_problem(e)}") from e
    if finite:
        refuse_non_finite(data, path, error)
    return data


def yaml_problem(exc: yaml.YAMLError) -> str:
    """PyYAML's error on one line: ``what, at line L, column C`` (1-based), else its text joined."""
    problem = getattr(exc, "problem", None)
    mark = getattr(exc, "problem_mark", None)
    if problem and mark is not None:
        return f"{problem}, at line {mark.line + 1}, column {mark.column + 1}"
    return " ".join(str(exc).split())
