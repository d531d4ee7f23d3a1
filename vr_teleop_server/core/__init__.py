"""The rosbridge server: transport, per-client sessions, the bus, wire encodings, access, rosapi, the event channel.

Depends on client_protocol only; the features, the robot and the tools sit above it.
"""
