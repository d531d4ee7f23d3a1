"""robot_models: QTrobot's description (joints, limits, chain, camera), kinematics and the MuJoCo model."""

from .kinematics import ArmSolver, IKResult, arm_ik, forward_kinematics
from .qtrobot import CameraIntrinsics, ChainElement, Geometry, Joint, RobotModel, load_qtrobot

__all__ = [
    "ArmSolver", "CameraIntrinsics", "ChainElement", "Geometry", "IKResult", "Joint", "RobotModel",
    "arm_ik", "forward_kinematics", "load_qtrobot",
]
