"""The impairment of one direction of the link, as pure logic: packet in (size, arrival time) -> drop, or when to
deliver it. No sockets, no clock: the forwarder passes the time in, so this is testable on its own.

Per packet, in this order (as a real path does it): the link may be cut (`down`); the bottleneck serialises it
at `rate_kbit` behind what is already queued, and drops it if the queue already holds more than `queue_ms` of
backlog; the path loses it (independently, or in Gilbert-Elliott bursts); it then travels `delay_ms` plus a
normal jitter; with `keep_order` it may not overtake the packet ahead; a `reorder` fraction is held back so the
ones behind overtake it.
"""

from __future__ import annotations

import dataclasses
import math
import random
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

PROFILES_FILE = Path(__file__).with_name("profiles.yaml")
DIRECTIONS = ("up", "down")  # up: client -> server; down: server -> client


@dataclass(frozen=True)
class DirectionParams:
    """One direction's impairment; every time one-way (see profiles.yaml for the meaning of each key)."""

    delay_ms: float = 0.0
    jitter_ms: float = 0.0
    keep_order: bool = True
    loss: float = 0.0
    burst: float = 1.0
    rate_kbit: float = 0.0
    queue_ms: float = 1000.0
    reorder: float = 0.0
    reorder_ms: float = 10.0
    down: bool = False

    def __post_init__(self) -> None:
        for name in ("delay_ms", "jitter_ms", "rate_kbit", "queue_ms", "reorder_ms"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value >= 0):
                raise ValueError(f"{name}: expected a number >= 0, got {value!r}")
        for name in ("loss", "reorder"):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and 0.0 <= value < 1.0):
                raise ValueError(f"{name}: expected a fraction in [0, 1), got {value!r}")
        if not (isinstance(self.burst, (int, float)) and self.burst >= 1.0):
            raise ValueError(f"burst: expected a mean burst length >= 1 packet, got {self.burst!r}")

    @classmethod
    def from_dict(cls, values: dict[str, Any], where: str = "") -> DirectionParams:
        known = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(values) - known)
        if unknown:
            raise ValueError(f"{where}: unknown key(s) {', '.join(unknown)}; known: {', '.join(sorted(known))}")
        try:
            return cls(**values)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"{where}: {exc}") from None

    def replace(self, **changes: Any) -> DirectionParams:
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)


@dataclass(frozen=True)
class Profile:
    name: str
    up: DirectionParams
    down: DirectionParams
    rtt: str = ""

    def direction(self, which: str) -> DirectionParams:
        return {"up": self.up, "down": self.down}[which]

    @property
    def rtt_ms(self) -> float:
        return self.up.delay_ms + self.down.delay_ms

    @property
    def rtt_jitter_ms(self) -> float:
        return math.hypot(self.up.jitter_ms, self.down.jitter_ms)


def load_profiles(path: Path | None = None) -> dict[str, Profile]:
    """Every profile of the file (default: the packaged profiles.yaml); errors name the profile and the key."""
    path = path or PROFILES_FILE
    data = yaml.safe_load(path.read_text(encoding="utf-8"))
    if not isinstance(data, dict):
        raise ValueError(f"{path}: expected a mapping of profile names to profiles")
    out = {}
    for name, spec in data.items():
        if not isinstance(spec, dict) or set(spec) - {"rtt", "both", "up", "down"}:
            raise ValueError(f"{path}: profile {name!r}: expected keys rtt, both, up, down")
        both = spec.get("both") or {}
        dirs = {d: DirectionParams.from_dict({**both, **(spec.get(d) or {})}, f"{path}: {name}.{d}")
                for d in DIRECTIONS}
        out[name] = Profile(name, dirs["up"], dirs["down"], str(spec.get("rtt", "")))
    return out


def load_profile(name: str, path: Path | None = None) -> Profile:
    profiles = load_profiles(path)
    if name not in profiles:
        raise ValueError(f"unknown network profile {name!r}; choose one of {', '.join(profiles)}")
    return profiles[name]


class GilbertElliott:
    """Two-state loss: Good (nothing lost) and Bad (everything lost), with mean loss `loss` and mean burst
    `burst` packets. burst == 1 degenerates to independent (Bernoulli) losses."""

    __slots__ = ("loss", "burst", "bad", "_rng")

    def __init__(self, loss: float, burst: float, rng: random.Random) -> None:
        self.loss, self.burst, self.bad, self._rng = loss, burst, False, rng

    def lost(self) -> bool:
        if self.loss <= 0.0:
            return False
        if self.burst <= 1.0:
            return self._rng.random() < self.loss
        r = 1.0 / self.burst  # Bad -> Good
        p = self.loss * r / (1.0 - self.loss)  # Good -> Bad, so that p / (p + r) = loss
        if self.bad:
            self.bad = self._rng.random() >= r
        else:
            self.bad = self._rng.random() < p
        return self.bad


@dataclass
class Counters:
    packets: int = 0
    delivered: int = 0
    lost: int = 0  # path loss (random or burst)
    queue_dropped: int = 0  # tail drop at the bandwidth bottleneck
    cut: int = 0  # dropped while the link was down
    reordered: int = 0

    def to_dict(self) -> dict[str, int]:
        return dataclasses.asdict(self)


class Direction:
    """Decides each packet's fate for one direction; `params` may be swapped at any time (set())."""

    def __init__(self, params: DirectionParams, seed: int | None = None) -> None:
        self._rng = random.Random(seed)
        self.counters = Counters()
        self._busy_until = 0.0  # when the bottleneck finishes serialising what it holds
        self._last_delivery = 0.0  # the latest delivery time given to an in-order packet
        self.set(params)

    def set(self, params: DirectionParams) -> None:
        self.params = params
        self._loss = GilbertElliott(params.loss, params.burst, self._rng)

    def admit(self, size: int, now: float) -> float | None:
        """Returns when (same clock as `now`, seconds) to deliver a packet of `size` bytes arriving now, or None
        when it is dropped."""
        p = self.params
        c = self.counters
        c.packets += 1
        if p.down:
            c.cut += 1
            return None
        t = now
        if p.rate_kbit > 0:
            start = max(now, self._busy_until)
            if start - now > p.queue_ms / 1e3:
                c.queue_dropped += 1
                return None
            self._busy_until = start + size * 8 / (p.rate_kbit * 1e3)
            t = self._busy_until
        if self._loss.lost():
            c.lost += 1
            return None
        delay = p.delay_ms
        if p.jitter_ms > 0:
            delay = max(0.0, self._rng.gauss(delay, p.jitter_ms))
        t += delay / 1e3
        if p.reorder > 0 and self._rng.random() < p.reorder:
            c.reordered += 1
            c.delivered += 1
            return t + p.reorder_ms / 1e3  # held back; does not hold back the packets behind it
        if p.keep_order:
            t = max(t, self._last_delivery)
            self._last_delivery = t
        c.delivered += 1
        return t


class Stacked:
    """Two links one after the other in one direction (a home's Wi-Fi, then the delay profile's WAN): a packet
    leaves the first when it says and arrives at the second then, so their delays, queues and losses add up as on
    a real path. Either may drop it."""

    def __init__(self, first: Direction, second: Direction) -> None:
        self.first, self.second = first, second

    def admit(self, size: int, now: float) -> float | None:
        t = self.first.admit(size, now)
        return None if t is None else self.second.admit(size, t)
