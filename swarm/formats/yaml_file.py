"""Reading a YAML file with errors that name the file."""

from __future__ import annotations

from pathlib import Path

import yaml


def read_yaml(path: Path, error: type[ValueError]) -> object:
    """The parsed contents of ``path``; unreadable or invalid files raise ``error`` naming it."""
    try:
        with open(path, encoding="utf-8") as f:
            return yaml.safe_load(f)
    except OSError as e:
        raise error(f"{path}: cannot read: {e.strerror or e}") from e
    except yaml.YAMLError as e:
        raise error(f"{path}: not valid YAML: {e}") from e
