"""Regenerate robot_models/mjcf/qtrobot.xml from data/qtrobot.yaml."""

from . import main

main()
