"""Loading questionnaire definitions (items, groups, keys) from the package's data files or a user's YAML."""

from __future__ import annotations

from importlib import resources
from pathlib import Path
from typing import TypeVar

import yaml
from pydantic import BaseModel, ValidationError

DATA_PACKAGE = "vr_teleop_server.questionnaires"

ModelT = TypeVar("ModelT", bound=BaseModel)


class DefinitionError(ValueError):
    """A definition file that cannot be used; the message names the file and the field."""


def data_file(*parts: str):
    """A packaged data file (works from a source tree and from an installed wheel)."""
    return resources.files(DATA_PACKAGE).joinpath("data", *parts)


def load_definition(model: type[ModelT], default_name: str, path: str | Path | None = None) -> ModelT:
    """Validate a YAML definition: the packaged `default_name`, or the user's file at `path`."""
    if path is None:
        shown, source = f"package data {default_name}", data_file(default_name)
    else:
        shown, source = str(path), Path(path)
    try:
        document = yaml.safe_load(source.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise DefinitionError(f"{shown}: file not found") from None
    except yaml.YAMLError as exc:
        raise DefinitionError(f"{shown}: not valid YAML ({exc})") from None
    try:
        return model.model_validate(document)
    except ValidationError as exc:
        problems = "; ".join(
            f"{'.'.join(str(part) for part in error['loc']) or '(top level)'}: {error['msg']}"
            for error in exc.errors()
        )
        raise DefinitionError(f"{shown}: {problems}") from None
