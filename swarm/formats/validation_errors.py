"""Pydantic validation errors as lines users read: ``<file>: <dotted.field>: <problem>``."""

from __future__ import annotations

from pathlib import Path

from pydantic import ValidationError


def _dotted(loc: tuple) -> str:
    """``('robots', 0, 'start')`` -> ``robots[0].start``, dropping pydantic's union tags."""
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        elif not _is_type_tag(part):
            out += f".{part}" if out else str(part)
    return out or "(top level)"


def _is_type_tag(part: str) -> bool:
    return (
        "[" in part
        or part[:1].isupper()
        or part.startswith("function-")
        or part in {"str", "int", "float", "bool", "dict", "list", "tuple", "none", "literal"}
    )


def _problem(error: dict) -> str:
    kind, ctx = error["type"], error.get("ctx", {})
    got = error.get("input")
    shown = "" if isinstance(got, dict) else f" (got {got!r})"
    bounds = {
        "greater_than": ("gt", ">"),
        "greater_than_equal": ("ge", ">="),
        "less_than": ("lt", "<"),
        "less_than_equal": ("le", "<="),
    }
    if kind in bounds:
        key, op = bounds[kind]
        limit = ctx.get(key)
        limit = f"{limit:g}" if isinstance(limit, float) else limit
        return f"must be {op} {limit}{shown}"
    if kind == "missing":
        return "is required"
    if kind == "extra_forbidden":
        return "unknown field"
    if kind == "literal_error":
        return f"must be one of {ctx.get('expected')}{shown}"
    if kind == "finite_number":
        return f"must be a finite number{shown}"
    if kind == "value_error":
        return str(ctx.get("error", error["msg"]))
    return f"{error['msg'][0].lower()}{error['msg'][1:]}{shown}"


def describe_validation_error(err: ValidationError, source: str | Path | None) -> str:
    """One line per problem: ``<file>: <dotted.path>: <problem>``."""
    lines: list[str] = []
    for error in err.errors():
        line = f"{source or '<mission>'}: {_dotted(error['loc'])}: {_problem(error)}"
        if line not in lines:
            lines.append(line)
    return "\n".join(lines)
