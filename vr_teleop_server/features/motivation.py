"""Motivation variables (curiosity, frustration, fatigue, pain) with limits, dynamics, events and services.

Configuration is data (motivation.yaml beside this file, or serve --motivation-config). The dynamics:
fatigue grows with engaged time and recovers at rest; frustration grows with every clamp on /vr_teleop/clamps and
every refused command (events of kind "refused" or "menu_failed") and decays; curiosity grows with each new face
(new_face(), for perception to call) and otherwise decays. Every variable decays towards its `rest` value (default:
its initial value for pain, its min otherwise) at decay_per_min.

Crossing a limit publishes a vr_teleop_msgs/Event (source "motivation", kind "motivation_high" or
"motivation_low", level warning; danger once the variable reaches its min or max; kind "motivation_ok", info, on
the way back; the detail names the variable). A limit on the side of the variable's rest value (fatigue's low 15,
when it rests at 0) never fires: what a teacher sees coloured is something to act on.
Services (vr_teleop_msgs/MotivationChange): /vr_teleop/motivation/increment, /set, /reset (empty name: all).
"""

from __future__ import annotations

import asyncio
import json
from pathlib import Path
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, model_validator

from client_protocol import names
from client_protocol.events import EventKind, EventLevel, MotivationLimit
from client_protocol.files import load_model_file

from ..core.bus import SERVER_NODE, Bus, BusError, Published
from ..core.events import declare_event_topic, publish_event
from ..core.tasks import cancel_and_wait

DEFAULT_CONFIG = Path(__file__).with_name("motivation.yaml")
REFUSAL_KINDS = (EventKind.REFUSED, EventKind.MENU_FAILED)
SIDE_KINDS = {"high": EventKind.MOTIVATION_HIGH, "low": EventKind.MOTIVATION_LOW, "ok": EventKind.MOTIVATION_OK}
RATE_HZ = 2.0


class VariableConfig(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    min: float
    max: float
    low: float | None = None
    high: float | None = None
    initial: float
    rest: float | None = Field(None, description="the value decay moves towards (default: min, or initial if "
                                                 "the range spans zero)")
    decay_per_min: float = Field(0.0, ge=0)
    engaged_per_min: float = 0.0
    rest_per_min: float = Field(0.0, ge=0, description="fall per minute while control is not engaged")
    per_clamp: float = 0.0
    per_refusal: float = 0.0
    per_new_face: float = 0.0

    @model_validator(mode="after")
    def _ordered(self) -> VariableConfig:
        if not self.min < self.max:
            raise ValueError(f"min ({self.min:g}) must be below max ({self.max:g})")
        for label in ("low", "high", "initial", "rest"):
            value = getattr(self, label)
            if value is not None and not self.min <= value <= self.max:
                raise ValueError(f"{label} ({value:g}) must lie within min..max ({self.min:g}..{self.max:g})")
        if self.low is not None and self.high is not None and not self.low < self.high:
            raise ValueError(f"low ({self.low:g}) must be below high ({self.high:g})")
        return self

    @property
    def rest_value(self) -> float:
        if self.rest is not None:
            return self.rest
        return self.initial if self.min < 0 < self.max else self.min


class MotivationConfig(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)

    update_period_s: float = Field(1.0, gt=0, le=60)
    variables: dict[str, VariableConfig] = Field(min_length=1)


def load_config(path: Path | None = None) -> MotivationConfig:
    path = path or DEFAULT_CONFIG
    return load_model_file(MotivationConfig, path)


class Motivation:
    def __init__(self, bus: Bus, config: MotivationConfig | None = None) -> None:
        self.bus = bus
        self.config = config or load_config()
        self.values = {name: v.initial for name, v in self.config.variables.items()}
        self._levels = {name: self._level(name) for name in self.values}
        self._engaged = False
        self._last_update: float | None = None  # the loop's time of the last update
        self._tasks: list[asyncio.Task[None]] = []

    # ---- lifetime -----------------------------------------------------------------------------------------------
    def start(self) -> None:
        bus = self.bus
        declare_event_topic(bus)
        bus.declare_topic(names.MOTIVATION_STATUS_TOPIC, "vr_teleop_msgs/Motivation", persistent=True)
        bus.declare_topic(names.CLAMP_TOPIC, "vr_teleop_msgs/Clamp", persistent=True)
        bus.declare_topic(names.TELEOP_STATE_TOPIC, "vr_teleop_msgs/TeleopState", persistent=True)
        bus.subscribe(SERVER_NODE, names.CLAMP_TOPIC, None, lambda _p: self._bump("per_clamp"))
        bus.subscribe(SERVER_NODE, names.EVENT_TOPIC, None, self._on_event)
        bus.subscribe(SERVER_NODE, names.TELEOP_STATE_TOPIC, None, self._on_state)
        bus.provide(names.MOTIVATION_INCREMENT_SERVICE, "vr_teleop_msgs/MotivationChange", self._increment)
        bus.provide(names.MOTIVATION_SET_SERVICE, "vr_teleop_msgs/MotivationChange", self._set)
        bus.provide(names.MOTIVATION_RESET_SERVICE, "vr_teleop_msgs/MotivationChange", self._reset)
        self._tasks = [asyncio.ensure_future(self._dynamics()), asyncio.ensure_future(self._publish_loop())]

    async def stop(self) -> None:
        tasks, self._tasks = self._tasks, []
        await cancel_and_wait(*tasks)

    # ---- inputs -------------------------------------------------------------------------------------------------
    def _on_event(self, published: Published) -> None:
        if published.data["kind"] in REFUSAL_KINDS:
            self._bump("per_refusal")

    def _on_state(self, published: Published) -> None:
        self._engaged = bool(published.data["engaged"])

    def new_face(self) -> None:
        """A face not seen before came into view (for perception to call)."""
        self._bump("per_new_face")

    def _bump(self, rule: str) -> None:
        for name, cfg in self.config.variables.items():
            step = getattr(cfg, rule)
            if step:
                self._change(name, self.values[name] + step)

    async def _dynamics(self) -> None:
        while True:
            if self._last_update is None:
                self._last_update = asyncio.get_running_loop().time()
            await asyncio.sleep(self.config.update_period_s)
            now = asyncio.get_running_loop().time()
            minutes = (now - self._last_update) / 60.0
            self._last_update = now
            for name, cfg in self.config.variables.items():
                value = self.values[name]
                if self._engaged:
                    value += cfg.engaged_per_min * minutes
                else:
                    value -= cfg.rest_per_min * minutes
                rest = cfg.rest_value
                if cfg.decay_per_min and value != rest:
                    step = min(abs(value - rest), cfg.decay_per_min * minutes)
                    value += step if value < rest else -step
                self._change(name, value)

    async def _publish_loop(self) -> None:
        while True:
            self.publish()
            await asyncio.sleep(1.0 / RATE_HZ)

    # ---- values, levels, events ---------------------------------------------------------------------------------
    def _level(self, name: str) -> tuple[str, bool]:
        """('high'|'low'|'ok', at the extreme). A limit counts only on the far side of where the variable rests:
        a level is something to act on, never a value at rest (fatigue 0 is under its low limit 15, but a rested
        robot is nothing to warn about)."""
        cfg, value = self.config.variables[name], self.values[name]
        rest = cfg.rest_value
        if cfg.high is not None and value >= cfg.high > rest:
            return "high", value >= cfg.max
        if cfg.low is not None and value <= cfg.low < rest:
            return "low", value <= cfg.min
        return "ok", False

    def _change(self, name: str, value: float) -> float:
        cfg = self.config.variables[name]
        self.values[name] = min(cfg.max, max(cfg.min, value))
        level = self._level(name)
        if level != self._levels[name]:
            self._levels[name] = level
            side, extreme = level
            limit = cfg.high if side == "high" else cfg.low if side == "low" else None
            publish_event(self.bus, "motivation", SIDE_KINDS[side],
                          EventLevel.INFO if side == "ok" else EventLevel.DANGER if extreme else EventLevel.WARNING,
                          MotivationLimit(variable=name, value=round(self.values[name], 3), side=side, limit=limit))
            self.publish()
        return self.values[name]

    def message(self) -> dict[str, Any]:
        names = list(self.config.variables)
        cfgs = [self.config.variables[n] for n in names]
        return {"header": {"stamp": self.bus.registry.now()}, "name": names,
                "value": [self.values[n] for n in names], "min": [c.min for c in cfgs], "max": [c.max for c in cfgs],
                "has_low": [c.low is not None for c in cfgs], "low": [c.low or 0.0 for c in cfgs],
                "has_high": [c.high is not None for c in cfgs], "high": [c.high or 0.0 for c in cfgs],
                "level": [self._levels[n][0] for n in names]}

    def publish(self) -> None:
        self.bus.publish(names.MOTIVATION_STATUS_TOPIC, self.message())

    # ---- services -----------------------------------------------------------------------------------------------
    def _variable(self, name: str) -> str:
        if name not in self.config.variables:
            raise BusError(f"unknown motivation variable {name!r}; variables are "
                           f"{', '.join(self.config.variables)}")
        return name

    def _reply(self, name: str, wanted: float) -> dict[str, Any]:
        value = self._change(name, wanted)
        cfg = self.config.variables[name]
        note = "" if value == wanted else f" (clamped to {cfg.min:g}..{cfg.max:g})"
        return {"success": True, "message": f"{name} = {value:g}{note}", "value": value}

    async def _increment(self, request: Any) -> dict[str, Any]:
        name = self._variable(request.name)
        return self._reply(name, self.values[name] + request.value)

    async def _set(self, request: Any) -> dict[str, Any]:
        return self._reply(self._variable(request.name), request.value)

    async def _reset(self, request: Any) -> dict[str, Any]:
        names = [self._variable(request.name)] if request.name else list(self.config.variables)
        for name in names:
            self._change(name, self.config.variables[name].initial)
        return {"success": True, "message": json.dumps({n: self.values[n] for n in names}), "value":
                self.values[names[0]] if len(names) == 1 else 0.0}
