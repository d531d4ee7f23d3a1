"""The words the server and its clients share about autonomy and about who moves the robot, one enum each.

Each is a `StrEnum`: a member is the very string on the wire (`AutonomyLevel.SUPERVISED == "supervised"`), so a
client that reads or sends the plain strings keeps working, and the server's code names a member instead of
spelling the string (a test scans the server for the strings compared against). docs/reference/protocol.md lists
them for client developers.
"""

from __future__ import annotations

import enum
from typing import Annotated, Any

from pydantic import WithJsonSchema


class AutonomyLevel(enum.StrEnum):
    """How much the robot does by itself: /vr_teleop/autonomy/level's and /vr_teleop/autonomy/state's `level`, the
    autonomy_level event's `level` and `was`, `serve --autonomy`."""

    TELEOPERATED = "teleoperated"  # nothing moves unless someone moves it
    SUPERVISED = "supervised"  # the robot attends and proposes; the teacher decides
    AUTONOMOUS = "autonomous"  # it does what it proposes


class Decision(enum.StrEnum):
    """The teacher's word on a pending proposal: /vr_teleop/autonomy/decide's `decision`."""

    ACCEPT = "accept"
    REJECT = "reject"
    FORBID = "forbid"  # never in this situation

    @property
    def outcome(self) -> Outcome:
        return _DECIDED[self]


class Outcome(enum.StrEnum):
    """How a proposal ended, or an action the teacher took herself (/vr_teleop/autonomy/outcomes' `outcome`)."""

    ACCEPTED = "accepted"
    REJECTED = "rejected"
    FORBIDDEN = "forbidden"
    TIMED_OUT_EXECUTED = "timed_out_executed"  # nobody decided in time and the rules say execute
    SUPERSEDED = "superseded"  # a newer proposal replaced it
    DROPPED = "dropped"  # not carried out: timed out (rules say drop), nobody watching, teleoperated, a stop
    TEACHER_INITIATED = "teacher_initiated"  # not a proposal: the teacher chose the action from her menus


_DECIDED = {Decision.ACCEPT: Outcome.ACCEPTED, Decision.REJECT: Outcome.REJECTED,
            Decision.FORBID: Outcome.FORBIDDEN}


class Initiator(enum.StrEnum):
    """Who began what an outcome reports (its `initiator`)."""

    ROBOT = "robot"  # a proposal
    TEACHER = "teacher"  # her own action


class Decider(enum.StrEnum):
    """An outcome's `decided_by` when no person decided (otherwise it is the operator's name)."""

    AUTONOMY = "autonomy"  # the autonomous level carries out its own proposal
    TIMEOUT = "timeout"  # the proposal's time-out
    SERVER = "server"  # superseded, or dropped (nobody watching, teleoperated, an emergency stop)


class Owner(enum.StrEnum):
    """Who moves a part of the robot: /vr_teleop/autonomy/state's `owners[].owner`. The claimants come first, the
    strongest first: an emergency stop, the operator holding control, a running study trial, a gesture playing, a
    client of LuxAI's API. Autonomy claims nothing: it is shown on the head while it drives a free head."""

    ESTOP = "estop"  # an emergency stop, until someone engages or sets the autonomy level again
    OPERATOR = "operator"  # the operator holding control, on the parts they follow
    TRIAL = "trial"  # a running study trial
    GESTURE = "gesture"  # a gesture being played
    CLIENT = "client"  # a client of LuxAI's API (a script), while it commands and a grace after
    AUTONOMY = "autonomy"
    NONE = "none"


CLAIMANTS: tuple[Owner, ...] = (Owner.ESTOP, Owner.OPERATOR, Owner.TRIAL, Owner.GESTURE, Owner.CLIENT)


class Part(enum.StrEnum):
    """A part of the robot someone may own (/vr_teleop/autonomy/state's `owners[].part`): the robot model's joint
    groups, and two that are not joints."""

    HEAD = "head"
    RIGHT_ARM = "right_arm"
    LEFT_ARM = "left_arm"
    VOICE = "voice"  # a sentence being said
    FACE = "face"  # an emotion being shown


ARMS: tuple[Part, ...] = (Part.LEFT_ARM, Part.RIGHT_ARM)
VOCABULARIES: tuple[type[enum.StrEnum], ...] = (AutonomyLevel, Decision, Outcome, Initiator, Decider, Owner, Part)


def literal(kind: type[enum.StrEnum]) -> Any:
    """`kind` as a model field's type whose JSON Schema is the values inline (`{"enum": [...], "type": "string"}`,
    a Literal's), not a named definition: the published schemas (client_protocol/schemas) read as before."""
    return Annotated[kind, WithJsonSchema({"enum": [m.value for m in kind], "type": "string"})]
