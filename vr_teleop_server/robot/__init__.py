"""The robot: the Robot interface (degrees, the robot's base frame), its backends and gestures. Knows nothing of the bus."""
