"""The VR telepresence server: transport, sessions, bus, backends, CLI and study tools."""
