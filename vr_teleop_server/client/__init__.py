"""The package's own rosbridge client (Python, asyncio), which the replay tool, the study's simulated people, the
benches and the tests use: one place for the rosbridge v2 frames and for the refusal rule (docs/guides/
other-clients.md, "The package's Python client")."""

from .rosbridge import CallFailed, Client, Refused, RosbridgeError, Subscription, connect, outcome

__all__ = ["CallFailed", "Client", "Refused", "RosbridgeError", "Subscription", "connect", "outcome"]
