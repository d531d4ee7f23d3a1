"""Pydantic models of every message on the wire: rosbridge v2 ops and the ROS message types the project uses."""
