"""Who moves each part of the robot: one arbiter that every mover tells when it starts and stops (design.md,
"Who moves the robot").

Claimants, strongest first: an emergency stop (until someone engages or sets the autonomy level again), the
operator who holds control (the parts they follow, from engage until release, through any watchdog hold), a
running study trial, a gesture being played. The robot's own autonomy has no claim: it may move a part only while
nobody claims it, and asks before each command.
"""

from __future__ import annotations

from collections.abc import Callable, Iterable

# strongest first
CLAIMANTS = ("estop", "operator", "trial", "gesture")


class Ownership:
    def __init__(self, parts: Iterable[str]) -> None:
        self.parts = tuple(parts)
        self._claims: dict[str, dict[str, str]] = {part: {} for part in self.parts}  # part -> claimant -> who
        self.changed: list[Callable[[], None]] = []  # called after every change (autonomy republishes its state)

    def claim(self, claimant: str, parts: Iterable[str], who: str = "") -> None:
        if claimant not in CLAIMANTS:
            raise ValueError(f"unknown claimant {claimant!r}; claimants are {', '.join(CLAIMANTS)}")
        for part in parts:
            self._claims[self._part(part)][claimant] = who
        self._notify()

    def release(self, claimant: str, parts: Iterable[str] | None = None, who: str | None = None) -> None:
        """Ends `claimant`'s claims (on `parts`, default all); with `who`, only the claims made for it (an older
        gesture's end leaves a newer one's claim)."""
        for part in self.parts if parts is None else parts:
            claims = self._claims[self._part(part)]
            if who is None or claims.get(claimant) == who:
                claims.pop(claimant, None)
        self._notify()

    def owner(self, part: str) -> str:
        """The strongest claimant of `part`, or "none"."""
        claims = self._claims[self._part(part)]
        return next((c for c in CLAIMANTS if c in claims), "none")

    def holder(self, part: str) -> str:
        """Who the strongest claim is for (the operator's key, the gesture's name...), "" if none."""
        owner = self.owner(part)
        return self._claims[part].get(owner, "") if owner != "none" else ""

    def free(self, part: str) -> bool:
        return self.owner(part) == "none"

    def owners(self) -> dict[str, str]:
        return {part: self.owner(part) for part in self.parts}

    def _part(self, part: str) -> str:
        if part not in self._claims:
            raise KeyError(f"unknown part {part!r}; parts are {', '.join(self.parts)}")
        return part

    def _notify(self) -> None:
        for listener in tuple(self.changed):
            listener()
