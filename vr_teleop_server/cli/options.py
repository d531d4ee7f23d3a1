"""Command-line options made from a settings model's fields: each field marked `Cli(...)` (core/settings.py) is an
option of its group, named after the field, with the field's description as its help, a Literal's values as its
choices and the field's default as its default. So a setting, its help and its default are written once."""

from __future__ import annotations

import argparse
import enum
import os
import types
import typing
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel
from pydantic.fields import FieldInfo
from pydantic_core import PydanticUndefined

from ..core.settings import Cli


def cli_fields(model: type[BaseModel]) -> list[tuple[str, FieldInfo, Cli]]:
    """(name, field, its Cli marker) of every field marked as an option, in the model's order."""
    out = []
    for name, field in model.model_fields.items():
        cli = next((m for m in field.metadata if isinstance(m, Cli)), None)
        if cli is not None:
            out.append((name, field, cli))
    return out


def _flag(name: str, cli: Cli) -> str:
    return cli.flag if cli.flag is not None else "--" + name.replace("_", "-")


def _plain(annotation: Any) -> Any:
    """X for `X | None`."""
    if typing.get_origin(annotation) in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(annotation) if a is not type(None)]
        if len(args) == 1:
            return args[0]
    return annotation


def choices_of(kind: Any) -> list[Any] | None:
    """A Literal's values, or an enum's."""
    if typing.get_origin(kind) is Literal:
        return list(typing.get_args(kind))
    if isinstance(kind, type) and issubclass(kind, enum.Enum):
        return [m.value for m in kind]
    return None


def _default_text(default: Any) -> str:
    if default is None or default is False or default == () or default is PydanticUndefined:
        return ""
    return " (default %(default)s)"


def add_options(model: type[BaseModel], groups: dict[str, argparse._ArgumentGroup]) -> None:
    """An option per marked field of `model`, in `groups[field's group]`."""
    for name, field, cli in cli_fields(model):
        flag = _flag(name, cli)
        if not flag:
            continue  # read from the environment only (a secret)
        kind = _plain(field.annotation)
        default = field.get_default(call_default_factory=True)
        kwargs: dict[str, Any] = {"dest": name, "help": (field.description or "") + _default_text(default)}
        if kind is bool:
            kwargs["action"] = "store_true"
        elif typing.get_origin(kind) is tuple:
            kwargs.update(action="append", default=list(default), metavar=cli.metavar)
        else:
            kwargs.update(default=default, metavar=cli.metavar, choices=choices_of(kind))
            if kind in (int, float, Path):
                kwargs["type"] = kind
        groups[cli.group].add_argument(flag, **kwargs)


def values_from(model: type[BaseModel], args: argparse.Namespace) -> dict[str, Any]:
    """The marked fields' values from parsed options (an unset secret from its environment variable)."""
    values: dict[str, Any] = {}
    for name, field, cli in cli_fields(model):
        value = getattr(args, name, None)
        if cli.env and not value:
            value = os.environ.get(cli.env) or None
        if typing.get_origin(_plain(field.annotation)) is tuple:
            value = tuple(value or ())
        values[name] = value
    return values
