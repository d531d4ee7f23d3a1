"""The commands a menu item may run, with their arguments: the vocabulary menu files are checked against.

Each command is carried out by the server as an ordinary call on its bus (vr_teleop_server/features/menu_service.py,
whose MENU_HANDLERS holds a handler per Command), so a menu selection does exactly what the same call from a client
would.
"""

from __future__ import annotations

import enum
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any, Literal

from client_protocol.vocabulary import AutonomyLevel
from pydantic import BaseModel, ConfigDict, Field

PARTS = ("head", "left_arm", "right_arm")


class Command(enum.StrEnum):
    """What a menu item does when it is selected (COMMANDS gives each one's arguments)."""
    SHOW_EMOTION = "show_emotion"
    SAY = "say"
    STOP_SPEECH = "stop_speech"
    CONFIGURE_SPEECH = "configure_speech"
    SET_LANGUAGE = "set_language"
    PLAY_CLIP = "play_clip"
    RECORD_CLIP = "record_clip"
    PLAY_GESTURE = "play_gesture"
    STOP_GESTURE = "stop_gesture"
    RECORD_TOGGLE = "record_toggle"
    SAVE_RECORDING = "save_recording"
    SET_ARMS_CONTROL = "set_arms_control"
    SET_HEAD_CONTROL = "set_head_control"
    ENGAGE = "engage"
    ESTOP = "estop"
    HOME = "home"
    SET_MOTORS = "set_motors"
    SHOW_STATUS = "show_status"
    CHANGE_MOTIVATION = "change_motivation"
    SET_AUTONOMY = "set_autonomy"
    SET_COMFORT_VIGNETTE = "set_comfort_vignette"


@dataclass(frozen=True)
class MenuEntry:
    """A menu item that runs a command, as the menus are published now (generated items too)."""
    label: str
    command: Command
    args: Mapping[str, Any] = field(default_factory=dict)  # the item's own (read-only); a selection may add to them


class _Args(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class NoArgs(_Args):
    pass


class EmotionArgs(_Args):
    name: str = Field(min_length=1, description="LuxAI emotion, e.g. happy or QT/happy")
    say: str = Field("", max_length=200, description="words the robot says as it shows the emotion; the menus fill "
                     "them in, in the robot's language, from the menu's words file (menu.words)")


class SayArgs(_Args):
    text: str = Field(min_length=1, max_length=2000)
    pupil: str = Field("", max_length=100, description="whom {pupil} names (default: the pupil the robot attends to)")


class SpeechConfigArgs(_Args):
    language: str = Field("", description="espeak-ng language or voice, e.g. en-GB, fr; empty keeps the current")
    pitch: int = Field(0, ge=0, le=100, description="0 keeps the current; espeak's 1..100, 50 is normal")
    speed: int = Field(0, ge=0, le=400, description="0 keeps the current; percent of the normal rate")


class LanguageArgs(_Args):
    language: Literal["en", "de", "fr", "lb"] = Field(description="English, German, French or Luxembourgish")


class ClipArgs(_Args):
    name: str = Field(min_length=1, description="a clip of the library (`serve --clips DIR`)")


class GestureArgs(_Args):
    name: str = Field(min_length=1)
    speed: float = Field(1.0, ge=0.1, le=10.0, description="1 plays as recorded; the velocity caps still hold")


class RecordArgs(_Args):
    parts: list[Literal["head", "left_arm", "right_arm"]] = Field(default_factory=lambda: list(PARTS), min_length=1)
    name: str = Field("", description="name to save under when recording stops; empty: a timestamped name")


class SaveArgs(_Args):
    name: str = Field("", description="empty: a timestamped name")


class SwitchArgs(_Args):
    enable: bool | None = Field(None, description="true, false, or absent to toggle")


class EngageArgs(_Args):
    enable: bool = True


class HomeArgs(_Args):
    parts: list[Literal["head", "left_arm", "right_arm"]] = Field(default_factory=list, description="empty: all")


class MotorsArgs(_Args):
    mode: Literal["on", "off", "brake"]
    parts: list[Literal["head", "left_arm", "right_arm"]] = Field(default_factory=list, description="empty: all")


class StatusArgs(_Args):
    which: Literal["hardware", "motors", "dialog", "motivation"]


class MotivationArgs(_Args):
    name: str = Field("", description="curiosity, frustration, fatigue or pain; empty with reset: all")
    op: Literal["increment", "set", "reset"] = "increment"
    value: float = 0.0


class AutonomyArgs(_Args):
    level: AutonomyLevel


class VignetteArgs(_Args):
    enable: bool | None = Field(None, description="true, false, or absent to toggle; the operator page's own "
                                "display (the comfort vignette and the robot's reticle): the server only records it")


COMMANDS: dict[Command, type[_Args]] = {
    Command.SHOW_EMOTION: EmotionArgs,
    Command.SAY: SayArgs,
    Command.STOP_SPEECH: NoArgs,
    Command.CONFIGURE_SPEECH: SpeechConfigArgs,
    Command.SET_LANGUAGE: LanguageArgs,
    Command.PLAY_CLIP: ClipArgs,
    Command.RECORD_CLIP: NoArgs,  # start recording the selecting client's voice as a clip, or stop and keep it
    Command.PLAY_GESTURE: GestureArgs,
    Command.STOP_GESTURE: NoArgs,
    Command.RECORD_TOGGLE: RecordArgs,  # start recording, or stop and save the running one
    Command.SAVE_RECORDING: SaveArgs,
    Command.SET_ARMS_CONTROL: SwitchArgs,
    Command.SET_HEAD_CONTROL: SwitchArgs,
    Command.ENGAGE: EngageArgs,
    Command.ESTOP: NoArgs,
    Command.HOME: HomeArgs,
    Command.SET_MOTORS: MotorsArgs,
    Command.SHOW_STATUS: StatusArgs,
    Command.CHANGE_MOTIVATION: MotivationArgs,
    Command.SET_AUTONOMY: AutonomyArgs,
    Command.SET_COMFORT_VIGNETTE: VignetteArgs,  # handled by the operator page itself; the server records the choice
}
