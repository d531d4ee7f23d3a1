"""WebRTC media beside the rosbridge stream: the head camera as video encoded once per codec, the robot's audio out
and the operator's voice in, the operator's poses on the "poses" data channel (poses.py), the offer and clock
services, and the link telemetry.

Layer: with core and robot (imports the bus, access and the Robot interface; never features or the app)."""

from .service import MediaService

__all__ = ["MediaService"]
