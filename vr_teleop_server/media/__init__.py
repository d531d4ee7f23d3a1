"""WebRTC media beside the rosbridge stream: the head camera as video encoded once per codec, the robot's audio out
and the operator's voice in, the offer and clock services, and the link telemetry.

Layer: with core and robot (imports the bus, access and the Robot interface; never features or the app)."""

from .service import MediaService

__all__ = ["MediaService"]
