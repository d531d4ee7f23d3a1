"""Robot backends: implementations of vr_teleop_server.robot.interface.Robot (the MuJoCo stand-in; the real robot later)."""
