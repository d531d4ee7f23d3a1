"""The server's event kinds, each with the one model its `detail` follows (vr_teleop_msgs/Event).

On the wire an event stays `source, kind, level, detail` with `detail` a JSON object in a string, so clients that
read today's vr_teleop_msgs/Event keep working; here is where a kind and its detail's fields are defined, once.
The server validates every event it publishes against its kind's model; pages and tools read the typed fields (a
state such as "a gesture is being recorded" is a field, never a sentence to parse). `vr-teleop schema` writes a
JSON Schema per kind (event.<kind>.json) and the protocol reference lists them.
"""

from __future__ import annotations

import enum
import json
from dataclasses import dataclass
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, WithJsonSchema

from .vocabulary import AutonomyLevel, literal


class EventLevel(enum.StrEnum):
    INFO = "info"
    WARNING = "warning"
    DANGER = "danger"


class EventKind(enum.StrEnum):
    # explicit control (source teleop)
    ENGAGE = "engage"
    RELEASE = "release"
    REFUSED = "refused"
    ESTOP = "estop"
    RECENTER = "recenter"
    CALIBRATE = "calibrate"
    HEAD_ON = "head_on"
    HEAD_OFF = "head_off"
    ARMS_ON = "arms_on"
    ARMS_OFF = "arms_off"
    WATCHDOG_RELEASED = "watchdog_released"
    WATCHDOG_ACTIVE = "watchdog_active"
    WATCHDOG_STALLED = "watchdog_stalled"
    WATCHDOG_DISCONNECTED = "watchdog_disconnected"
    WATCHDOG_ESTOPPED = "watchdog_estopped"
    ROBOT_LOST = "robot_lost"
    ROBOT_BACK = "robot_back"
    # menus (source menu)
    SELECT = "select"
    MENU_FAILED = "menu_failed"
    # gesture recording (source gestures)
    GESTURE_RECORDING = "gesture_recording"
    # motivation limits (source motivation)
    MOTIVATION_HIGH = "motivation_high"
    MOTIVATION_LOW = "motivation_low"
    MOTIVATION_OK = "motivation_ok"
    # the robot backend (source backend)
    RECONNECTED = "reconnected"
    DISCONNECTED = "disconnected"
    CAMERA_UNAVAILABLE = "camera_unavailable"
    MOTOR_ERROR = "motor_error"
    MOTOR_OK = "motor_ok"
    VOICE_ACTIVITY = "voice_activity"
    # the robot's own behaviour (source autonomy)
    AUTONOMY_LEVEL = "autonomy_level"
    AUTONOMY_ACTION_FAILED = "autonomy_action_failed"
    # the experimenter's labels on /study/labels (source experimenter)
    HUMAN_ACTION_START = "human_action_start"
    HUMAN_ACTION_STOP = "human_action_stop"
    INTERVENTION = "intervention"


class EventDetail(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Holder(EventDetail):
    holder: str | None = Field(None, description="the operator holding control (null: nobody)")


class HolderBy(Holder):
    by: str = Field(description="the connection that asked (/vr_teleop_server: the server itself)")


class Refused(Holder):
    client: str = Field(description="the connection whose message was refused")
    topic: str = Field(description="the topic it published on")


class EStop(HolderBy):
    how: str | None = Field(None, description="how it was asked for, when not by the service (`both thumbsticks`)")


class Watchdog(Holder):
    threshold_s: float | None = Field(None, description="the head-pose age beyond which the robot holds")
    pose_age_s: float | None = Field(None, description="the newest head pose's age when the state changed")
    pose_made_age_s: float | None = Field(None, description="the same, from when the headset made it")


class Calibration(EventDetail):
    by: str
    shoulder_half_width_m: float
    arm_length_m: float
    eye_to_shoulder_drop_m: float


class PartSwitch(EventDetail):
    by: str
    part: Literal["head", "arms"] = Field(description="the part switched")
    enabled: bool = Field(description="whether the part now follows the operator")


class MenuSelection(EventDetail):
    id: str = Field(description="the menu item's id")
    command: str
    by: str
    result: str = Field(description="what happened, for people to read")


class MenuFailure(EventDetail):
    id: str
    command: str
    by: str
    reason: str


class GestureRecording(EventDetail):
    recording: bool = Field(description="whether a gesture is being recorded now")
    parts: list[str] = Field(default_factory=list, description="the parts recorded (while recording)")


class MotivationLimit(EventDetail):
    variable: str = Field(description="the motivation variable (motivation.yaml's names)")
    value: float
    side: Literal["high", "low", "ok"]
    limit: float | None = Field(None, description="the limit crossed (null on the way back)")


class BackendLink(EventDetail):
    robot_url: str


class CameraProblem(EventDetail):
    problem: str


class MotorFault(EventDetail):
    motor: str
    faults: list[str] = Field(description="QTrobot v3's fault flags (overload_limit, voltage_limit...)")


class Motor(EventDetail):
    motor: str


class VoiceActivity(EventDetail):
    activity: bool = Field(description="whether someone is speaking near the robot")
    direction_deg: float | None = Field(None, description="the microphone array's direction estimate")


class AutonomyLevelChanged(EventDetail):
    level: literal(AutonomyLevel) = Field(title="Level", description="the level now")  # type: ignore[valid-type]
    # published as a plain string before it was typed: its schema stays so
    was: Annotated[AutonomyLevel, WithJsonSchema({"type": "string"})] = Field(title="Was",
                                                                               description="the level before")
    by: str = Field(description="the operator (or connection, or the server) that set it")


class ActionFailed(EventDetail):
    id: str = Field(description="the proposal whose action did not run")
    action: str = Field(description="its menu item")
    reason: str


class Label(EventDetail):
    model_config = ConfigDict(extra="allow", frozen=True)  # a label may carry the experimenter's own notes

    action: str = ""
    wall_time: float | None = Field(None, description="the experimenter's clock, Unix seconds")


@dataclass(frozen=True)
class KindSpec:
    model: type[EventDetail]
    source: str
    doc: str
    # The kind as the wire spells it, when it is not the enum's value: a pattern over the detail's fields. Motivation
    # events have always named their variable in the kind (`frustration_high`), and clients match on that.
    wire: str = ""

    def wire_kind(self, kind: EventKind, detail: EventDetail) -> str:
        return self.wire.format(**detail.model_dump()) if self.wire else kind.value


K = EventKind
KINDS: dict[EventKind, KindSpec] = {
    K.ENGAGE: KindSpec(Holder, "teleop", "an operator took control"),
    K.RELEASE: KindSpec(HolderBy, "teleop", "control was released; the robot holds its pose"),
    K.REFUSED: KindSpec(Refused, "teleop", "a stream from a client not holding control was refused"),
    K.ESTOP: KindSpec(EStop, "teleop", "soft e-stop: the robot holds and control is taken away"),
    K.RECENTER: KindSpec(HolderBy, "teleop", "the holder's head orientation became straight ahead"),
    K.CALIBRATE: KindSpec(Calibration, "teleop", "the operator's body was measured"),
    K.HEAD_ON: KindSpec(PartSwitch, "teleop", "the head follows the operator again"),
    K.HEAD_OFF: KindSpec(PartSwitch, "teleop", "the head holds"),
    K.ARMS_ON: KindSpec(PartSwitch, "teleop", "the arms follow the operator again"),
    K.ARMS_OFF: KindSpec(PartSwitch, "teleop", "the arms hold"),
    K.WATCHDOG_RELEASED: KindSpec(Watchdog, "teleop", "the watchdog's state became released"),
    K.WATCHDOG_ACTIVE: KindSpec(Watchdog, "teleop", "fresh head poses: the robot follows"),
    K.WATCHDOG_STALLED: KindSpec(Watchdog, "teleop", "head poses stopped: the robot holds until they resume"),
    K.WATCHDOG_DISCONNECTED: KindSpec(Watchdog, "teleop", "the holder went away: the robot holds"),
    K.WATCHDOG_ESTOPPED: KindSpec(Watchdog, "teleop", "the watchdog's state became estopped"),
    K.ROBOT_LOST: KindSpec(Holder, "teleop", "the robot backend is disconnected: the robot holds"),
    K.ROBOT_BACK: KindSpec(Holder, "teleop", "the robot backend is back; engage again to move it"),
    K.SELECT: KindSpec(MenuSelection, "menu", "a menu item's command ran"),
    K.MENU_FAILED: KindSpec(MenuFailure, "menu", "a menu item's command did not run"),
    K.GESTURE_RECORDING: KindSpec(GestureRecording, "gestures", "a gesture recording started or stopped"),
    K.MOTIVATION_HIGH: KindSpec(MotivationLimit, "motivation", "a variable rose past its high limit (danger "
                                                               "at its max)", "{variable}_high"),
    K.MOTIVATION_LOW: KindSpec(MotivationLimit, "motivation", "a variable fell past its low limit (danger at "
                                                              "its min)", "{variable}_low"),
    K.MOTIVATION_OK: KindSpec(MotivationLimit, "motivation", "a variable is back within its limits",
                              "{variable}_ok"),
    K.RECONNECTED: KindSpec(BackendLink, "backend", "the connection to the robot is back"),
    K.DISCONNECTED: KindSpec(BackendLink, "backend", "the connection to the robot was lost"),
    K.CAMERA_UNAVAILABLE: KindSpec(CameraProblem, "backend", "the robot's camera cannot be read"),
    K.MOTOR_ERROR: KindSpec(MotorFault, "backend", "a motor reports faults"),
    K.MOTOR_OK: KindSpec(Motor, "backend", "a motor's faults cleared"),
    K.VOICE_ACTIVITY: KindSpec(VoiceActivity, "backend", "a voice started, stopped or moved near the robot"),
    K.AUTONOMY_LEVEL: KindSpec(AutonomyLevelChanged, "autonomy", "the autonomy level changed"),
    K.AUTONOMY_ACTION_FAILED: KindSpec(ActionFailed, "autonomy", "a proposal's action could not be run"),
    K.HUMAN_ACTION_START: KindSpec(Label, "experimenter", "the experimenter marks a human action's start"),
    K.HUMAN_ACTION_STOP: KindSpec(Label, "experimenter", "the experimenter marks a human action's end"),
    K.INTERVENTION: KindSpec(Label, "experimenter", "the experimenter marks an intervention"),
}


def detail_json(kind: EventKind | str, detail: EventDetail | dict[str, Any]) -> tuple[str, str]:
    """The kind as the wire spells it and the detail as the wire's JSON text, checked against the kind's model;
    ValueError (pydantic's ValidationError is one) names what is wrong."""
    try:
        kind = EventKind(kind)
    except ValueError:
        raise ValueError(f"unknown event kind {kind!r}; the kinds are client_protocol.events.EventKind") from None
    model = KINDS[kind].model
    if not isinstance(detail, model):
        detail = model.model_validate(detail.model_dump() if isinstance(detail, BaseModel) else detail)
    return KINDS[kind].wire_kind(kind, detail), json.dumps(detail.model_dump(mode="json"), sort_keys=True)


def parse_detail(kind: EventKind | str, text: str) -> EventDetail:
    """An event's detail as its kind's model (ValueError on an unknown kind or a detail that does not fit)."""
    return KINDS[EventKind(kind)].model.model_validate_json(text or "{}")
