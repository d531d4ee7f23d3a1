"""Every teleop parameter in one validated model (the server's settings embed it)."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field, PositiveFloat, model_validator

from .body import BodyModel
from .frames import DEFAULT_QUATERNION_NORM_TOLERANCE
from .safety import DeadManMode


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class OneEuroSettings(_Strict):
    """One Euro filter parameters for joint angles in degrees; see teleop/one_euro.py for tuning."""

    min_cutoff_hz: float = Field(1.0, gt=0, description="cutoff at rest; lower = less jitter, more lag")
    beta: float = Field(0.05, ge=0, description="cutoff increase per deg/s of speed; higher = less lag when fast")
    d_cutoff_hz: float = Field(1.0, gt=0, description="cutoff of the speed estimate")


class BodySettings(_Strict):
    """The operator body model's defaults (teleop/body.py), until a calibration pose measures them."""

    eye_to_neck_back_m: float = Field(0.08, ge=0, le=0.3)
    eye_to_shoulder_drop_m: float = Field(0.20, gt=0, le=0.5)
    shoulder_half_width_m: float = Field(0.19, ge=0.05, le=0.4)
    arm_length_m: float = Field(0.60, ge=0.3, le=1.2, description="shoulder to the grip of a held controller")
    torso_yaw_follow: float = Field(
        0.0, ge=0, le=1, description="how much of the head's turn (since engage) the torso is assumed to follow"
    )

    def body_model(self) -> BodyModel:
        return BodyModel(self.eye_to_neck_back_m, self.eye_to_shoulder_drop_m, self.shoulder_half_width_m,
                         self.arm_length_m)


class TeleopSettings(_Strict):
    """Explicit-control parameters. Times in seconds (monotonic), angles in degrees."""

    watchdog_timeout_s: float = Field(0.2, gt=0, description="head pose silence after which the robot holds; the "
                                      "floor of the adaptive threshold (teleop/link.py)")
    watchdog_ceiling_s: float = Field(0.5, gt=0, description="the adaptive threshold never exceeds this (a "
                                      "watchdog_timeout_s above it wins)")
    watchdog_margin: float = Field(1.5, ge=1, le=4, description="threshold = margin x the quantile of recent "
                                   "head-pose silences")
    watchdog_quantile: float = Field(0.99, ge=0.5, lt=1)
    controller_timeout_s: float = Field(0.2, gt=0, description="controller pose silence after which that arm holds")
    joy_timeout_s: float | None = Field(
        None, gt=0, description="Joy silence after which the grip counts as released (None: clients that send Joy "
        "only on change keep working)",
    )
    deadman_mode: DeadManMode = Field(DeadManMode.HOLD, description="hold: follow while the grip is held; toggle: "
                                      "each grip press starts or stops following")
    grip_press_threshold: float = Field(0.6, gt=0, le=1)
    grip_release_threshold: float = Field(0.4, ge=0, lt=1)
    estop_both_sticks: bool = Field(True, description="clicking both thumbsticks together releases teleop")
    head_filter: OneEuroSettings = OneEuroSettings()
    arm_filter: OneEuroSettings = OneEuroSettings()
    velocity_caps_deg_s: dict[str, PositiveFloat] = Field(
        default_factory=dict, description="per-joint caps replacing the robot model's max_velocity"
    )
    velocity_scale: float = Field(1.0, gt=0, le=1, description="fraction of the caps teleop may use")
    ramp_duration_s: float = Field(2.0, ge=0, description="caps ramp up over this long after engage or resume")
    ramp_start_fraction: float = Field(0.1, gt=0, le=1)
    max_step_dt_s: float = Field(
        0.1, gt=0, description="longest dt one step may use, so a late step cannot license a big jump"
    )
    head_yaw_scale: float = Field(1.0, gt=0, le=3)
    head_pitch_scale: float = Field(1.0, gt=0, le=3)
    yaw_wrap_hysteresis_deg: float = Field(90.0, ge=0, le=180)
    gimbal_margin_deg: float = Field(5.0, gt=0, lt=45, description="within this of straight up/down, yaw is held")
    quaternion_norm_tolerance: float = Field(DEFAULT_QUATERNION_NORM_TOLERANCE, gt=0, le=0.1)
    body: BodySettings = BodySettings()
    robot_reach_m: float | None = Field(None, gt=0, description="override of the robot arm reach read from FK")
    ik_reuse_tolerance_m: float = Field(
        2e-4, ge=0, description="reuse the previous IK solution while the robot hand target moves less than this"
    )

    @model_validator(mode="after")
    def _thresholds(self) -> TeleopSettings:
        if self.grip_release_threshold >= self.grip_press_threshold:
            raise ValueError(
                f"grip_release_threshold ({self.grip_release_threshold}) must be below grip_press_threshold "
                f"({self.grip_press_threshold})"
            )
        return self
