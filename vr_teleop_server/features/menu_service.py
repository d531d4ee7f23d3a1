"""The radial menus on the bus: trees published on the latched /vr_teleop/menus, selections executed by id.

A selection comes as a service call (/vr_teleop/menu/select, vr_teleop_msgs/MenuSelect) or on the topic
/vr_teleop/menu/selection (std_msgs/String holding the item id). Each command is carried out as an ordinary bus
call made on behalf of the selecting client (so "take control" makes *that* client the holder), and announced on
/vr_teleop/events (source "menu": kind "select", or "menu_failed" with the reason). Generated items (gestures,
emotions, sentences) are made when the menus are published, and the menus are published again when the gesture
library changes or the robot's language does (the sentences, and the words an emotion says, are that language's).
"""

from __future__ import annotations

import asyncio
import json
import logging
import re
from collections.abc import Awaitable, Callable
from typing import Any

from pydantic import ValidationError

from client_protocol import names
from client_protocol.events import EventKind, EventLevel, MenuFailure, MenuSelection
from menus import (COMMANDS, REFERENCE_LANGUAGE, Command, Item, LoadedMenu, MenuEntry, fill_sentence, language_sentences,
                   language_words, walk)
from robot_models.types import MotorMode

from ..core.bus import SERVER_NODE, Bus, BusError, Published

from ..core.events import declare_event_topic, publish_event

log = logging.getLogger(__name__)

CALL_TIMEOUT_S = 60.0  # a sentence or a gesture may take a while; the reply comes when it is done


def _slug(text: str) -> str:
    return re.sub(r"[^a-z0-9]+", "_", text.lower()).strip("_")[:40] or "item"


class MenuService:
    def __init__(self, bus: Bus, menus: list[LoadedMenu], *, gestures: Callable[[], list[str]],
                 emotions: tuple[str, ...], status: Callable[[str], dict[str, Any]],
                 luxai: Any | None, language: Callable[[], str] = lambda: REFERENCE_LANGUAGE,
                 clips: Callable[[], list[str]] = list, unavailable: Callable[[], set[str]] = set,
                 variables: Callable[[], dict[str, str]] = dict) -> None:
        self.bus = bus
        self.menus = menus
        self._gestures = gestures
        self._emotions = emotions
        self._status = status
        self._luxai_api = luxai  # gesture recording (start_recording / save_recording / recording) and its news
        self._language = language  # the robot's language: the sentences are that language's list
        self._clips = clips
        self._unavailable = unavailable  # commands this server cannot run (no clip library): their items are left out
        self._variables = variables  # the sentences' variables' values now ({pupil}, {teacher}); publish() on a change
        self._items: dict[str, MenuEntry] = {}  # the items that run a command, by id, generated ones too
        self._arms_on = True
        self._head_on = True

    def start(self) -> None:
        declare_event_topic(self.bus)
        self.bus.declare_topic(names.MENUS_TOPIC, "vr_teleop_msgs/Menus", state=True, persistent=True)
        self.bus.declare_topic(names.MENU_SELECTION_TOPIC, "std_msgs/String", persistent=True)
        self.bus.subscribe(SERVER_NODE, names.MENU_SELECTION_TOPIC, None, self._on_selection)
        self.bus.provide(names.MENU_SELECT_SERVICE, "vr_teleop_msgs/MenuSelect", self._select_service)
        if self._luxai_api is not None:
            self._luxai_api.gestures_changed.append(self.publish)  # a saved gesture joins the menus at once
        self.publish()

    async def stop(self) -> None:
        if self._luxai_api is not None and self.publish in self._luxai_api.gestures_changed:
            self._luxai_api.gestures_changed.remove(self.publish)

    # ---- the trees ----------------------------------------------------------------------------------------------
    def _generated(self, item: Item, menu: LoadedMenu) -> list[tuple[str, MenuEntry]]:
        """(id, entry) of the items a `generate` item stands for."""
        if item.generate == "gestures":
            rows = [(name, MenuEntry(name, Command.PLAY_GESTURE, {"name": name})) for name in self._gestures()]
        elif item.generate == "emotions":
            rows = [(name, MenuEntry(name, Command.SHOW_EMOTION, self._emotion_args({"name": name}, menu)))
                    for name in self._emotions]
        elif item.generate == "clips":
            rows = [(name, MenuEntry(name, Command.PLAY_CLIP, {"name": name})) for name in self._clips()]
        else:
            pairs = language_sentences(menu.path.parent / str(item.source), self._language())
            values = self._variables()  # the label filled in as it would be said now; the item keeps the variables
            rows = [(key, MenuEntry(fill_sentence(text, values, keep_missing=True), Command.SAY, {"text": text}))
                    for key, text in pairs]
        out, seen = [], set()
        for key, entry in rows:
            ident = f"{item.id}.{_slug(key)}"
            while ident in seen:
                ident += "_"
            seen.add(ident)
            out.append((ident, entry))
        return out

    def publish(self) -> None:
        items: list[dict[str, Any]] = []
        table: dict[str, MenuEntry] = {}
        unavailable = self._unavailable()
        for menu in self.menus:
            for parent, position, item in walk(menu.items, menu.info.id):
                generated = self._generated(item, menu) if item.generate else []
                if item.generate and not generated:
                    continue  # an empty list (no clips yet) is left out: a menu item leads somewhere
                if item.command in unavailable:
                    continue  # nor is an item that could only be refused
                args = self._emotion_args(item.args, menu) if item.command == Command.SHOW_EMOTION else item.args
                items.append({"id": item.id, "menu": menu.info.id, "parent": parent, "label": item.label,
                              "slot": item.slot, "position": position, "icon": item.icon,
                              "command": item.command.value if item.command else "",
                              "args": json.dumps(args) if item.command else ""})
                if item.command:
                    table[item.id] = MenuEntry(item.label, item.command, dict(args))
                for pos, (ident, entry) in enumerate(generated):
                    items.append({"id": ident, "menu": menu.info.id, "parent": item.id, "label": entry.label,
                                  "slot": "list", "position": pos, "icon": "", "command": entry.command.value,
                                  "args": json.dumps(entry.args)})
                    table[ident] = entry
        self._items = table
        self.bus.publish(names.MENUS_TOPIC, {
            "header": {"stamp": self.bus.registry.now()},
            "menus": [{"id": m.info.id, "label": m.info.label, "controller": m.info.controller,
                       "button": m.info.button, "icon": m.info.icon} for m in self.menus],
            "items": items}, latch=True)

    def _emotion_args(self, args: dict[str, Any], menu: LoadedMenu) -> dict[str, Any]:
        """A show_emotion's args with the words the emotion says in the robot's language (the menu's words file)."""
        if menu.info.words is None or "say" in args:
            return dict(args)
        words = language_words(menu.path.parent / menu.info.words, self._language())
        said = words.get(str(args["name"]).rpartition("/")[2])
        return {**args, "say": said} if said else dict(args)

    def check_language(self, language: str) -> None:
        """ValueError (MenuError) naming the file when a menu has no sentence list, or no emotion words, for
        `language`."""
        for menu in self.menus:
            if menu.info.words is not None:
                language_words(menu.path.parent / menu.info.words, language)
            for _parent, _position, item in walk(menu.items, menu.info.id):
                if item.source is not None:
                    language_sentences(menu.path.parent / item.source, language)

    def entry(self, item_id: str) -> MenuEntry | None:
        """The item with this id if it runs a command, None for any other id."""
        return self._items.get(item_id)

    def ids(self) -> set[str]:
        return set(self._items)

    # ---- selections ---------------------------------------------------------------------------------------------
    async def _select_service(self, request: Any) -> dict[str, Any]:
        message = await self.select(request.id, request.args, Bus.caller())
        return {"success": True, "message": message}

    def _on_selection(self, published: Published) -> None:
        async def run() -> None:
            try:
                await self.select(published.data["data"], "", published.sender)
            except BusError as exc:
                self.bus.report(published.sender, "error", f"{published.topic}: {exc}")

        asyncio.ensure_future(run())

    async def select(self, item_id: str, args_json: str, caller: str) -> str:
        """Runs an item's command for `caller`; returns what happened, or raises BusError saying why not."""
        entry = self._items.get(item_id)
        if entry is None:
            raise self._failed(item_id, "", caller, f"unknown menu item {item_id!r}; the items are on "
                                                    f"{names.MENUS_TOPIC}")
        command, args = entry.command, entry.args
        try:
            extra = json.loads(args_json) if args_json.strip() else {}
            if not isinstance(extra, dict):
                raise ValueError("args must be a JSON object")
            parsed = COMMANDS[command](**{**args, **extra})
        except (ValueError, ValidationError) as exc:
            text = str(exc) if not isinstance(exc, ValidationError) else "; ".join(
                f"{'.'.join(map(str, e['loc']))}: {e['msg']}" for e in exc.errors())
            raise self._failed(item_id, command, caller, f"bad args for {command}: {text}") from None
        try:
            message = await MENU_HANDLERS[command](self, parsed, caller)
        except BusError as exc:
            raise self._failed(item_id, command, caller, str(exc)) from None
        publish_event(self.bus, "menu", EventKind.SELECT, EventLevel.INFO,
                      MenuSelection(id=item_id, command=command, by=caller, result=message))
        return message

    def _failed(self, item_id: str, command: str, caller: str, reason: str) -> BusError:
        publish_event(self.bus, "menu", EventKind.MENU_FAILED, EventLevel.WARNING,
                      MenuFailure(id=item_id, command=command, by=caller, reason=reason))
        return BusError(f"menu item {item_id!r}: {reason}")

    async def _call(self, service: str, args: dict[str, Any], caller: str) -> Any:
        # refusals raised, not answered: the menu words them in its own response ("menu item X: why")
        return await self.bus.call_service(service, args, CALL_TIMEOUT_S, caller=caller, refusal_response=False)

    async def _luxai(self, service: str, args: dict[str, Any], caller: str, done: str) -> str:
        response = await self._call(service, args, caller)
        if not response.status:
            raise BusError(f"{service} answered status false")
        return done

    async def _trigger(self, service: str, args: dict[str, Any], caller: str) -> str:
        response = await self._call(service, args, caller)
        if not response.success:
            raise BusError(response.message)
        return response.message

    # ---- the commands (one method per menus.Command, registered in MENU_HANDLERS) -------------------------------
    async def _do_show_emotion(self, a: Any, caller: str) -> str:
        shown = await self._luxai(names.EMOTION_SHOW_SERVICE, {"name": a.name}, caller, f"showing {a.name}")
        if not a.say:
            return shown
        response = await self._call(names.SPEECH_SAY_SERVICE, {"message": a.say}, caller)
        return f"{shown}, saying {a.say!r}" if response.status else f"{shown}; stopped while saying {a.say!r}"

    async def _do_say(self, a: Any, caller: str) -> str:
        try:  # the variables as they are now; {pupil} the one picked, if any
            text = fill_sentence(a.text, {**self._variables(), **({"pupil": a.pupil} if a.pupil else {})})
        except ValueError as exc:
            raise BusError(str(exc)) from None
        response = await self._call(names.SPEECH_SAY_SERVICE, {"message": text}, caller)
        return f"said {text!r}" if response.status else f"stopped while saying {text!r}"

    async def _do_stop_speech(self, _a: Any, caller: str) -> str:
        return await self._luxai(names.SPEECH_STOP_SERVICE, {}, caller, "speech stopped")

    async def _do_configure_speech(self, a: Any, caller: str) -> str:
        return await self._luxai(names.SPEECH_CONFIG_SERVICE, {"language": a.language, "pitch": a.pitch,
                                                             "speed": a.speed}, caller, "speech configured")

    async def _do_set_language(self, a: Any, caller: str) -> str:
        return await self._trigger(names.SPEECH_LANGUAGE_SERVICE, {"language": a.language}, caller)

    async def _do_play_clip(self, a: Any, caller: str) -> str:
        return await self._trigger(names.CLIP_PLAY_SERVICE, {"name": a.name}, caller)

    async def _do_record_clip(self, _a: Any, caller: str) -> str:
        return await self._trigger(names.CLIP_RECORD_SERVICE, {}, caller)

    async def _do_play_gesture(self, a: Any, caller: str) -> str:
        response = await self._call(names.GESTURE_PLAY_SERVICE, {"name": a.name, "speed": a.speed}, caller)
        return f"played {a.name}" if response.status else f"{a.name} was stopped"

    async def _do_stop_gesture(self, _a: Any, caller: str) -> str:
        return await self._luxai(names.GESTURE_STOP_SERVICE, {}, caller, "gesture stopped")

    async def _do_record_toggle(self, a: Any, caller: str) -> str:
        if not self._luxai_api.recording:
            await self._luxai(names.GESTURE_RECORD_SERVICE, {"parts": a.parts}, caller, "")
            return f"recording {', '.join(a.parts)}; select again to stop and save"
        return await self._do_save_recording(a, caller)

    async def _do_save_recording(self, a: Any, caller: str) -> str:
        name = self._luxai_api.save_recording(a.name)  # publishes the menus again, with the new gesture
        return f"saved as {name}"

    async def _switch(self, service: str, a: Any, current: bool, caller: str) -> bool:
        enable = (not current) if a.enable is None else a.enable
        await self._trigger(service, {"data": enable}, caller)
        return enable

    async def _do_set_arms_control(self, a: Any, caller: str) -> str:
        self._arms_on = await self._switch(names.ARMS_SERVICE, a, self._arms_on, caller)
        return f"arms control {'on' if self._arms_on else 'off'}"

    async def _do_set_head_control(self, a: Any, caller: str) -> str:
        self._head_on = await self._switch(names.HEAD_SERVICE, a, self._head_on, caller)
        return f"head control {'on' if self._head_on else 'off'}"

    async def _do_engage(self, a: Any, caller: str) -> str:
        return await self._trigger(names.ENGAGE_SERVICE, {"data": a.enable}, caller)

    async def _do_estop(self, _a: Any, caller: str) -> str:
        return await self._trigger(names.ESTOP_SERVICE, {}, caller)

    async def _do_home(self, a: Any, caller: str) -> str:
        return await self._luxai(names.MOTORS_HOME_SERVICE, {"parts": a.parts}, caller, "going home")

    async def _do_set_motors(self, a: Any, caller: str) -> str:
        return await self._luxai(names.MOTORS_CONTROL_MODE_SERVICE,
                                 {"parts": a.parts, "mode": int(MotorMode[a.mode.upper()])}, caller, f"motors {a.mode}")

    async def _do_show_status(self, a: Any, _caller: str) -> str:
        return json.dumps(self._status(a.which), default=str)

    async def _do_set_autonomy(self, a: Any, caller: str) -> str:
        return await self._trigger(names.AUTONOMY_LEVEL_SERVICE, {"level": a.level}, caller)

    async def _do_set_comfort_vignette(self, a: Any, _caller: str) -> str:
        # The operator page's own display: the page switches it when the item is selected and sends the state it
        # chose; the server only answers and records it (the menu's select event), for the session's log.
        return "comfort vignette " + ("toggled" if a.enable is None else "on" if a.enable else "off")

    async def _do_change_motivation(self, a: Any, caller: str) -> str:
        service = {"set": names.MOTIVATION_SET_SERVICE, "increment": names.MOTIVATION_INCREMENT_SERVICE,
                   "reset": names.MOTIVATION_RESET_SERVICE}[a.op]
        return await self._trigger(service, {"name": a.name, "value": a.value}, caller)


# What each command of the vocabulary (menus.COMMANDS, the arguments' models) runs: one entry per command.
MENU_HANDLERS: dict[Command, Callable[[MenuService, Any, str], Awaitable[str]]] = {
    Command.SHOW_EMOTION: MenuService._do_show_emotion,
    Command.SAY: MenuService._do_say,
    Command.STOP_SPEECH: MenuService._do_stop_speech,
    Command.CONFIGURE_SPEECH: MenuService._do_configure_speech,
    Command.SET_LANGUAGE: MenuService._do_set_language,
    Command.PLAY_CLIP: MenuService._do_play_clip,
    Command.RECORD_CLIP: MenuService._do_record_clip,
    Command.PLAY_GESTURE: MenuService._do_play_gesture,
    Command.STOP_GESTURE: MenuService._do_stop_gesture,
    Command.RECORD_TOGGLE: MenuService._do_record_toggle,
    Command.SAVE_RECORDING: MenuService._do_save_recording,
    Command.SET_ARMS_CONTROL: MenuService._do_set_arms_control,
    Command.SET_HEAD_CONTROL: MenuService._do_set_head_control,
    Command.ENGAGE: MenuService._do_engage,
    Command.ESTOP: MenuService._do_estop,
    Command.HOME: MenuService._do_home,
    Command.SET_MOTORS: MenuService._do_set_motors,
    Command.SHOW_STATUS: MenuService._do_show_status,
    Command.CHANGE_MOTIVATION: MenuService._do_change_motivation,
    Command.SET_AUTONOMY: MenuService._do_set_autonomy,
    Command.SET_COMFORT_VIGNETTE: MenuService._do_set_comfort_vignette,
}
