"""What the session's parts share: the error a handler raises for a status reply, and frames' plain values."""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel


class ProtocolError(Exception):
    """A request this client made wrongly; the session answers it with a status op of `level`."""

    def __init__(self, message: str, level: str = "error") -> None:
        super().__init__(message)
        self.level = level


def json_value(value: Any) -> Any:
    return value.model_dump(mode="json", by_alias=True) if isinstance(value, BaseModel) else value
