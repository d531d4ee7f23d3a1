"""Explicit control: the operator's headset and controller poses mapped onto QTrobot's 8 joints.

Pure and socket-free: the server feeds TeleopMapper with parsed messages and monotonic times and sends what
step() returns. See mapper.py for the rules (engage, dead-man, watchdog) and each module for its part.
"""

from .body import BodyModel
from .frames import Pose, make_pose, pose_from_message, unity_to_ros_position, unity_to_ros_quaternion
from .head import HeadTracker
from .mapper import ArmIK, TeleopError, TeleopMapper, TeleopOutput
from .one_euro import OneEuroFilter
from .safety import DeadMan, DeadManMode, WatchdogState, cap_step
from .settings import BodySettings, OneEuroSettings, TeleopSettings

__all__ = [
    "ArmIK", "BodyModel", "BodySettings", "DeadMan", "DeadManMode", "HeadTracker", "OneEuroFilter",
    "OneEuroSettings", "Pose", "TeleopError", "TeleopMapper", "TeleopOutput", "TeleopSettings", "WatchdogState",
    "cap_step", "make_pose", "pose_from_message", "unity_to_ros_position", "unity_to_ros_quaternion",
]
