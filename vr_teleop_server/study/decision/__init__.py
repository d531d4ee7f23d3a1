"""Decision: Wizard of Oz (teleop), a py_trees behaviour tree from the study file (scripted), and scripted with
teleoperated steps (semi); the /decision/* services reach whichever runs the trial."""

from .base import Decision, DecisionContext, DecisionHost
from .scripted import ScriptedDecision, SemiAutonomousDecision, build_tree
from .teleop import TeleopDecision

MODULES: dict[str, type[Decision]] = {
    "scripted": ScriptedDecision,
    "teleop": TeleopDecision,
    "semi": SemiAutonomousDecision,
}

__all__ = ["MODULES", "Decision", "DecisionContext", "DecisionHost", "ScriptedDecision", "SemiAutonomousDecision",
           "TeleopDecision", "build_tree"]
