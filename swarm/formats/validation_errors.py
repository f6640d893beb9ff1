"""Pydantic validation errors as lines users read: ``<file>: <dotted.field>: <problem>``."""

from __future__ import annotations

import difflib
import typing
from pathlib import Path

from pydantic import BaseModel, ValidationError

#: How close an unknown key must be to a field name to be named as its likely spelling.
_MISSPELT = 0.75


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


def _models_in(annotation) -> list[type[BaseModel]]:
    """The pydantic models an annotation can hold (``Rig``, ``list[Rig]``, ``Rig | str | None``)."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return [annotation]
    return [m for arg in typing.get_args(annotation) for m in _models_in(arg)]


def _sibling_fields(model: type[BaseModel], loc: tuple) -> list[str]:
    """The field names of the section holding the unknown key at ``loc`` (its last part), found
    by following ``loc`` through ``model``'s fields; [] when the path leaves the models."""
    models = [model]
    for part in loc[:-1]:
        if isinstance(part, int) or _is_type_tag(str(part)):
            continue  # a list index or a union tag: the same models
        models = [
            m
            for parent in models
            if part in parent.model_fields
            for m in _models_in(parent.model_fields[part].annotation)
        ]
    return sorted({name for m in models for name in m.model_fields})


def describe_validation_error(
    err: ValidationError, source: str | Path | None, model: type[BaseModel] | None = None
) -> str:
    """One line per problem: ``<file>: <dotted.path>: <problem>``. With the validated
    ``model``, an unknown key close to a field of its section names it: ``rig.widht: unknown
    field (did you mean width?)``."""
    lines: list[str] = []
    for error in err.errors():
        problem = _problem(error)
        if model is not None and error["type"] == "extra_forbidden":
            key = str(error["loc"][-1])
            near = difflib.get_close_matches(key, _sibling_fields(model, error["loc"]), n=1, cutoff=_MISSPELT)
            if near:
                problem += f" (did you mean {near[0]}?)"
        line = f"{source or '<mission>'}: {_dotted(error['loc'])}: {problem}"
        if line not in lines:
            lines.append(line)
    return "\n".join(lines)
