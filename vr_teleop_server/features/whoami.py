"""`/vr_teleop/whoami`: tells a connection who the server takes it to be (its name, role, operator key, and whether
that operator holds control), so that a client can compare itself with /vr_teleop/teleop_state's holder."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from client_protocol import names

from ..core.bus import Bus


class WhoAmI:
    def __init__(self, bus: Bus, identity: Callable[[str], dict[str, Any]]) -> None:
        """`identity(owner)`: {connection, role, operator, holding} of a session (the app knows its sessions)."""
        self.bus = bus
        self.identity = identity

    def start(self) -> None:
        self.bus.provide(names.WHOAMI_SERVICE, "vr_teleop_msgs/WhoAmI", self._whoami)

    async def stop(self) -> None:
        """The service goes with the bus."""

    async def _whoami(self, _request: Any) -> dict[str, Any]:
        who = self.identity(self.bus.caller())
        return {"success": True, "message": f"{who['connection']}: {who['role']}", **who}
