"""The commands a menu item may run, with their arguments: the vocabulary menu files are checked against.

Each command is carried out by the server as an ordinary call on its bus (see vr_teleop_server/menu_service.py),
so a menu selection does exactly what the same call from a client would.
"""

from __future__ import annotations

from typing import Literal

from client_protocol.vocabulary import AutonomyLevel
from pydantic import BaseModel, ConfigDict, Field

PARTS = ("head", "left_arm", "right_arm")


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


COMMANDS: dict[str, type[_Args]] = {
    "show_emotion": EmotionArgs,
    "say": SayArgs,
    "stop_speech": NoArgs,
    "configure_speech": SpeechConfigArgs,
    "set_language": LanguageArgs,
    "play_clip": ClipArgs,
    "record_clip": NoArgs,  # start recording the selecting client's voice as a clip, or stop and keep it
    "play_gesture": GestureArgs,
    "stop_gesture": NoArgs,
    "record_toggle": RecordArgs,  # start recording, or stop and save the running one
    "save_recording": SaveArgs,
    "set_arms_control": SwitchArgs,
    "set_head_control": SwitchArgs,
    "engage": EngageArgs,
    "estop": NoArgs,
    "home": HomeArgs,
    "set_motors": MotorsArgs,
    "show_status": StatusArgs,
    "change_motivation": MotivationArgs,
    "set_autonomy": AutonomyArgs,
    "set_comfort_vignette": VignetteArgs,  # handled by the operator page itself; the server records the choice
}
