"""The rosbridge server's core (issue 17 moves transport, session, bus, wire, access, rosapi and events here)."""
