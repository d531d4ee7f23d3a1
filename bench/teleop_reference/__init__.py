"""The teleop step as it was before issue 28 (commit 377e5c0), kept verbatim as bench/teleop.py's reference.

Only the imports changed: the settings model and the robot model come from the live packages (neither is on the
per-frame path). Not used by the server; do not fix or speed up: it is the baseline the bench divides by.
"""

from .mapper import TeleopMapper

__all__ = ["TeleopMapper"]
