"""Head mapping: known turns give known HeadYaw/HeadPitch, the +-180 wrap, and the gimbal singularity."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from robot_models import forward_kinematics, load_qtrobot
from vr_teleop_server.teleop import TeleopMapper, make_pose
from vr_teleop_server.teleop.head import HeadTracker, yaw_pitch_deg

MODEL = load_qtrobot()


def ros(yaw=0.0, pitch=0.0, roll=0.0):
    return Rotation.from_euler("ZYX", [yaw, pitch, roll], degrees=True)


def unity_head(yaw_right_deg=0.0, pitch_down_deg=0.0):
    """A Unity head quaternion: yaw about Unity's up (positive = right), then pitch about its right axis."""
    q = Rotation.from_rotvec([0, math.radians(yaw_right_deg), 0]) * Rotation.from_rotvec(
        [math.radians(pitch_down_deg), 0, 0])
    return q.as_quat()


def tracker(zero=None):
    t = HeadTracker()
    t.set_zero(zero or Rotation.identity())
    return t


def test_robot_convention_from_urdf_positive_pitch_looks_down_positive_yaw_looks_left():
    cam0 = forward_kinematics(MODEL, {})["camera"]
    cam_down = forward_kinematics(MODEL, {"HeadPitch": 20.0})["camera"]
    cam_left = forward_kinematics(MODEL, {"HeadYaw": 20.0})["camera"]
    # The optical frame looks along its z axis.
    assert cam_down[2, 2] < cam0[2, 2] - 0.3  # looking down
    assert cam_left[1, 2] > 0.3  # looking towards +y = left


def test_30_left_gives_plus_30_and_pitch_down_positive():
    yaw, pitch = tracker().update(ros(yaw=30))
    assert yaw == pytest.approx(30.0) and pitch == pytest.approx(0.0, abs=1e-9)
    yaw, pitch = tracker().update(ros(pitch=20))
    assert yaw == pytest.approx(0.0, abs=1e-9) and pitch == pytest.approx(20.0)
    yaw, pitch = tracker().update(ros(yaw=-25, pitch=-10, roll=30))  # roll is discarded
    assert yaw == pytest.approx(-25.0) and pitch == pytest.approx(-10.0)


def test_relative_to_calibrated_zero():
    zero = ros(yaw=100, pitch=5)
    yaw, pitch = tracker(zero).update(zero * ros(yaw=30, pitch=10))
    assert yaw == pytest.approx(30.0) and pitch == pytest.approx(10.0)


@settings(max_examples=200, deadline=None)
@given(st.floats(-179, 179), st.floats(-80, 80), st.floats(-179, 179))
def test_matches_scipy_zyx_away_from_the_singularity(y, p, r):
    rot = ros(y, p, r)
    yaw, pitch, _ = yaw_pitch_deg(rot)
    ey, ep, _ = rot.as_euler("ZYX", degrees=True)
    assert yaw == pytest.approx(ey, abs=1e-6) and pitch == pytest.approx(ep, abs=1e-6)


def test_wrap_through_180_does_not_flip_sides_and_rewraps_after_hysteresis():
    t = tracker()
    yaws = [t.update(ros(yaw=a))[0] for a in (90, 150, 179, -179, -170, -120)]  # keep turning left
    assert yaws[:3] == pytest.approx([90, 150, 179])
    assert yaws[3:] == pytest.approx([181, 190, 240])  # unwrapped: still "far left", no jump to the right
    assert t.update(ros(yaw=-80))[0] == pytest.approx(-80)  # 280 left = 80 right: past the hysteresis, re-wrapped
    t2 = tracker()
    assert [t2.update(ros(yaw=a))[0] for a in (-150, 170)] == pytest.approx([-150, -190])


def test_near_gimbal_lock_yaw_is_held_and_nothing_blows_up():
    t = tracker()
    t.update(ros(yaw=20, pitch=40))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # scipy's gimbal-lock warning would fail here
        for p in (88.0, 89.9, 90.0, 90.0):
            for y in (-170.0, 3.0, 95.0):
                yaw, pitch = t.update(ros(yaw=y, pitch=p, roll=y / 2))
                assert math.isfinite(yaw) and math.isfinite(pitch)
                assert yaw == pytest.approx(20.0)  # held: heading is undefined here
                assert pitch == pytest.approx(min(p, 90.0), abs=1e-3)
    assert t.update(ros(yaw=25, pitch=60))[0] == pytest.approx(25.0)  # leaves the singularity: follows again


def _settle(mapper, quat_unity, seconds=3.0, t0=0.0, rate=90.0):
    out = None
    for i in range(1, int(seconds * rate) + 1):
        t = t0 + i / rate
        mapper.on_head_pose(make_pose([0, 1.2, 0], quat_unity, "unity_left_handed"), t)
        out = mapper.step(t)
    return out


def test_mapper_30_left_and_80_left_clamped_from_unity():
    m = TeleopMapper(MODEL)
    m.on_head_pose(make_pose([0, 1.2, 0], unity_head(), "unity_left_handed"), 0.0)
    m.engage(0.0)
    out = _settle(m, unity_head(yaw_right_deg=-30))  # turning LEFT in Unity
    assert out.commands["head"][0] == pytest.approx(30.0, abs=1e-3)
    assert "HeadYaw" not in out.clamped
    out = _settle(m, unity_head(yaw_right_deg=-80), t0=3.0)
    assert out.commands["head"][0] == pytest.approx(60.0)
    assert "HeadYaw" in out.clamped and "HeadPitch" not in out.clamped
    out = _settle(m, unity_head(pitch_down_deg=20), t0=6.0)
    assert out.commands["head"] == pytest.approx((0.0, 20.0), abs=1e-3)
    out = _settle(m, unity_head(pitch_down_deg=-40), t0=9.0)  # looking far up: HeadPitch stops at -15
    assert out.commands["head"][1] == pytest.approx(-15.0) and out.clamped == ("HeadPitch",)
    assert np.isfinite(out.commands["head"]).all()
