"""One client's rosbridge session."""

from .session import Session

__all__ = ["Session"]
