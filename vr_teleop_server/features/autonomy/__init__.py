"""Supervised autonomy (issue #34): autonomy levels, attention to the person who speaks, SPARC-style proposals the
teacher decides, and learning from her decisions. docs/guides/autonomy.md is the user's account."""

from .attention import AttentionConfig, load_config
from .feature import AUTONOMY_NODE, Autonomy
from .learner import Learner
from .rules import Rules, check_actions, load_rules

__all__ = ["AUTONOMY_NODE", "AttentionConfig", "Autonomy", "Learner", "Rules", "check_actions",
           "load_config", "load_rules"]
