"""Where the packaged instrument files are, and how a scorer's own view of an instrument is built and checked."""

from __future__ import annotations

from importlib import resources
from typing import Any, TypeVar

from pydantic import BaseModel, ValidationError

from client_protocol.files import describe_problems

DATA_PACKAGE = "vr_teleop_server.questionnaires"

ModelT = TypeVar("ModelT", bound=BaseModel)


class DefinitionError(ValueError):
    """A definition file that cannot be used; the message names the file and the field."""


def data_file(*parts: str):
    """A packaged data file (works from a source tree and from an installed wheel)."""
    return resources.files(DATA_PACKAGE).joinpath("data", *parts)


def view(model: type[ModelT], data: dict[str, Any], shown: str) -> ModelT:
    """A scorer's view of an instrument (SUS needs ten items ...); what it refuses names the file."""
    try:
        return model.model_validate(data)
    except ValidationError as exc:
        raise DefinitionError(f"{shown}: {describe_problems(exc)}") from None
