"""Who moves each part of the robot: one arbiter that every mover tells when it starts and stops (design.md,
"Who moves the robot").

Parts: the robot's (head, arms) and two that are not joints, the voice (a sentence being said) and the face (an
emotion being shown). Claimants, strongest first: an emergency stop (until someone engages or sets the autonomy level
again), the operator who holds control (the parts they follow, from engage until release, through any watchdog
hold), a running study trial, a gesture being played, and a client of LuxAI's API (a script, the 2018 Unity client)
for as long as it commands a part and a grace after (`hold`). The robot's own autonomy has no claim: it may move a
part only while nobody claims it, and asks before each command.
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import Callable, Iterable, Iterator

from client_protocol.vocabulary import CLAIMANTS, Owner, Part

from .bus import SERVER_NODE

CLIENT_GRACE_S = 5.0  # the packaged client_grace_s (features/autonomy/data/attention.yaml says why)


def client_of(sender: str) -> str | None:
    """The client behind a command, or None for the server's own nodes (autonomy, the menus it selects from)."""
    return None if not sender or sender.startswith((SERVER_NODE, "/rosapi")) else sender


class Ownership:
    def __init__(self, parts: Iterable[str], client_grace_s: float = CLIENT_GRACE_S) -> None:
        """`parts`: the robot model's (its joint groups), each a Part; the voice and the face are added."""
        self.parts = tuple(dict.fromkeys((*(Part(p) for p in parts), Part.VOICE, Part.FACE)))
        self.client_grace_s = client_grace_s
        self._claims: dict[Part, dict[Owner, str]] = {part: {} for part in self.parts}  # part -> claimant -> who
        self._holds: dict[tuple[Owner, Part], int] = {}  # (claimant, part) -> commands running now
        self._ends: dict[tuple[Owner, Part], asyncio.TimerHandle] = {}  # (claimant, part) -> the grace's end
        self.changed: list[Callable[[], None]] = []  # called after every change (autonomy republishes its state)

    def claim(self, claimant: Owner, parts: Iterable[Part], who: str = "") -> None:
        if claimant not in CLAIMANTS:
            raise ValueError(f"unknown claimant {claimant!r}; claimants are {', '.join(CLAIMANTS)}")
        for part in parts:
            self._claims[self._part(part)][claimant] = who
        self._notify()

    def release(self, claimant: Owner, parts: Iterable[Part] | None = None, who: str | None = None) -> None:
        """Ends `claimant`'s claims (on `parts`, default all); with `who`, only the claims made for it (an older
        gesture's end leaves a newer one's claim)."""
        for part in self.parts if parts is None else parts:
            claims = self._claims[self._part(part)]
            if who is None or claims.get(claimant) == who:
                claims.pop(claimant, None)
        self._notify()

    def hold(self, claimant: Owner, parts: Iterable[Part], who: str, grace_s: float) -> Callable[[], None]:
        """Claims `parts` for `who` now, while a command runs; the returned function ends the command, after which
        the claim lasts `grace_s` more (on the running loop's clock), unless `who` or another commands again. A
        script's pauses between commands shorter than the grace never give a part away."""
        parts = tuple(self._part(p) for p in parts)
        for part in parts:
            key = (claimant, part)
            self._holds[key] = self._holds.get(key, 0) + 1
            end = self._ends.pop(key, None)
            if end is not None:
                end.cancel()
        self.claim(claimant, parts, who)
        done = False

        def finished() -> None:
            nonlocal done
            if done:
                return
            done = True
            loop = asyncio.get_running_loop()
            for part in parts:
                key = (claimant, part)
                self._holds[key] -= 1
                if self._holds[key] <= 0:
                    del self._holds[key]
                    self._ends[key] = loop.call_later(grace_s, self._grace_over, key)

        return finished

    @contextlib.contextmanager
    def commanding(self, sender: str, parts: Iterable[Part]) -> Iterator[None]:
        """A client's command (a LuxAI API call, a clip it plays, its voice through the robot) owns `parts` while it
        runs and `client_grace_s` after; the server's own commands claim nothing."""
        client = client_of(sender)
        done = self.hold(Owner.CLIENT, parts, client, self.client_grace_s) if client is not None else None
        try:
            yield
        finally:
            if done is not None:
                done()

    def _grace_over(self, key: tuple[Owner, Part]) -> None:
        self._ends.pop(key, None)
        claimant, part = key
        if key not in self._holds:
            self._claims[part].pop(claimant, None)
            self._notify()

    def close(self) -> None:
        """Cancels the graces' timers (the server stops)."""
        for end in self._ends.values():
            end.cancel()
        self._ends.clear()

    def owner(self, part: Part) -> Owner:
        """The strongest claimant of `part`, or Owner.NONE."""
        claims = self._claims[self._part(part)]
        return next((c for c in CLAIMANTS if c in claims), Owner.NONE)

    def holder(self, part: Part) -> str:
        """Who the strongest claim is for (the operator's key, the gesture's name...), "" if none."""
        owner = self.owner(part)
        return self._claims[part].get(owner, "") if owner != Owner.NONE else ""

    def free(self, part: Part) -> bool:
        return self.owner(part) == Owner.NONE

    def owners(self) -> dict[Part, Owner]:
        return {part: self.owner(part) for part in self.parts}

    def stopped(self) -> bool:
        """Whether an emergency stop holds the robot."""
        return Owner.ESTOP in self.owners().values()

    def _part(self, part: Part) -> Part:
        if part not in self._claims:
            raise KeyError(f"unknown part {part!r}; parts are {', '.join(self.parts)}")
        return part

    def _notify(self) -> None:
        for listener in tuple(self.changed):
            listener()
