"""Loading questionnaire definitions (items, groups, keys) from the package's data files or a user's YAML."""

from __future__ import annotations

from importlib import resources
from pathlib import Path
from typing import TypeVar

from pydantic import BaseModel

from client_protocol.files import load_model_file

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
    return load_model_file(model, source, shown=shown, error=DefinitionError)
