"""Action: primitives on the Robot interface, each reported as a robot state update."""

from .primitives import ActionFailed, ActionModule

__all__ = ["ActionFailed", "ActionModule"]
