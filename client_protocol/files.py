"""Data files (YAML, and JSON, which is YAML too) into pydantic models, with every error worded one way:
`FILE: PLACE: PROBLEM`, several problems joined by "; ".

It lives in client_protocol, the leaf every other package may import (menus, robot_models, the server), next to
the wording of validation errors the wire already uses; it imports nothing but yaml and pydantic.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

import yaml
from pydantic import BaseModel, ValidationError

ModelT = TypeVar("ModelT", bound=BaseModel)


def read_document(path: Path | Any, *, shown: str | None = None, error: type[Exception] = ValueError) -> Any:
    """The parsed YAML of `path` (a Path, or an importlib.resources Traversable for packaged data)."""
    shown = shown or str(path)
    try:
        text = path.read_text(encoding="utf-8")
    except FileNotFoundError:
        raise error(f"{shown}: file not found") from None
    except OSError as exc:
        raise error(f"{shown}: cannot read: {exc.strerror or exc}") from None
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise error(f"{shown}: not valid YAML ({exc})") from None


def place_of(loc: tuple[Any, ...]) -> str:
    return ".".join(str(part) for part in loc) or "(top level)"


def describe_problems(exc: ValidationError, place: Callable[[tuple[Any, ...]], str] = place_of) -> str:
    """`PLACE: PROBLEM` for each error of `exc`, joined by "; "; `place` words where (default: a dotted path)."""
    return "; ".join(f"{place(tuple(err['loc']))}: {str(err['msg']).removeprefix('Value error, ')}"
                     for err in exc.errors(include_url=False))


def load_model_file(model: type[ModelT], path: Path | Any, *, shown: str | None = None,
                    error: type[Exception] = ValueError,
                    place: Callable[[Any], Callable[[tuple[Any, ...]], str]] | None = None) -> ModelT:
    """`path` read, parsed and validated as `model`; any failure raises `error` with `FILE: PLACE: PROBLEM`.

    `place(document)`, if given, returns how to word an error's location in that document (the menus name the
    item by its id rather than by its index)."""
    shown = shown or str(path)
    document = read_document(path, shown=shown, error=error)
    try:
        return model.model_validate(document)
    except ValidationError as exc:
        words = place(document) if place is not None else place_of
        raise error(f"{shown}: {describe_problems(exc, words)}") from None
