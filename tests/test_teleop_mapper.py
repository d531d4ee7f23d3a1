"""TeleopMapper as a whole: engage rules, watchdog, dead-man modes, e-stop, and safety under hostile streams."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pydantic import ValidationError
from scipy.spatial.transform import Rotation

from robot_models import load_qtrobot
from vr_teleop_server.teleop import (
    DeadManMode, TeleopError, TeleopMapper, TeleopSettings, WatchdogState, make_pose,
)

MODEL = load_qtrobot()
EYES = [0.0, 1.2, 0.0]
LEFT_FWD = [-0.19, 1.0, 0.46]  # Unity: left hand ahead of the left shoulder
RIGHT_FWD = [0.19, 1.0, 0.46]


def head_msg(yaw_left_deg=0.0, pos=EYES):
    q = Rotation.from_rotvec([0, -math.radians(yaw_left_deg), 0]).as_quat()
    return {"header": {"frame_id": "unity_left_handed"}, "pose": {"position": dict(zip("xyz", pos)),
                                                      "orientation": dict(zip("xyzw", q))}}


def ctrl(pos):
    return make_pose(pos, [0, 0, 0, 1], "unity_left_handed")


def joy(m, side, grip, t, click=0):
    m.on_joy(side, [0.0, 0.0, 0.0, grip], [0, 0, click, 0], t)


def feed(m, t, yaw=0.0, left=LEFT_FWD, right=RIGHT_FWD, controllers=True):
    m.on_head_pose(head_msg(yaw), t)
    if controllers:
        m.on_controller_pose("left", ctrl(left), t)
        m.on_controller_pose("right", ctrl(right), t)


def engaged(**kw):
    m = TeleopMapper(MODEL, TeleopSettings(**kw))
    feed(m, 0.0)
    m.engage(0.0)
    return m


def test_engage_needs_fresh_head_pose_and_reports_it():
    m = TeleopMapper(MODEL)
    with pytest.raises(TeleopError, match="no head pose"):
        m.engage(0.0)
    m.on_head_pose(head_msg(), 0.0)
    with pytest.raises(TeleopError, match="no head pose in the last 0.2 s"):
        m.engage(1.0)
    m.engage(0.1)
    assert m.state is WatchdogState.ACTIVE


def test_not_engaged_sends_nothing_and_engage_starts_from_current_joints():
    m = TeleopMapper(MODEL)
    feed(m, 0.0, yaw=40)
    out = m.step(0.01)
    assert out.commands == {} and out.state is WatchdogState.RELEASED and out.holding
    m.engage(0.01, current_joints={"HeadYaw": -20.0, "HeadPitch": 99.0})
    assert m.last_command["HeadYaw"] == -20.0 and m.last_command["HeadPitch"] == 25.0  # clamped
    feed(m, 0.02, yaw=40)
    out = m.step(0.02)
    cap = MODEL.joint("HeadYaw").max_velocity * 0.1 * 0.01  # ramp starts at 10% of the cap
    assert out.commands["head"][0] == pytest.approx(-20.0, abs=cap + 1e-9)  # no jump from the current pose
    with pytest.raises(KeyError, match="unknown joint"):
        m.engage(0.02, current_joints={"Nose": 1.0})


def test_watchdog_fires_on_stalled_stream_and_fresh_poses_resume_with_ramp():
    m = engaged()
    t = 0.0
    for _ in range(90):
        t += 1 / 90
        feed(m, t, yaw=20)
        out = m.step(t)
    assert out.state is WatchdogState.ACTIVE and "head" in out.commands
    stall_start = t
    last = None
    while t < stall_start + 0.5:  # no poses
        t += 1 / 90
        out = m.step(t)
        if t - stall_start <= 0.2:
            assert out.state is WatchdogState.ACTIVE  # the newest pose still counts
        else:
            assert out.state is WatchdogState.STALLED and out.holding and out.commands == {}
            assert out.pose_age_s["head"] == pytest.approx(t - stall_start)
            last = last or dict(m.last_command)
            assert m.last_command == last  # held
    assert out.state is WatchdogState.STALLED
    t += 1 / 90
    feed(m, t, yaw=-50)
    out = m.step(t)
    assert out.state is WatchdogState.ACTIVE
    assert out.ramp["head"] == pytest.approx(0.1)  # ramp restarted: eases back in
    assert abs(out.commands["head"][0] - last["HeadYaw"]) <= 90 * 0.1 * out.dt + 1e-9


def test_disconnect_needs_a_new_engage():
    m = engaged()
    m.disconnect()
    feed(m, 0.05)
    out = m.step(0.05)
    assert out.state is WatchdogState.DISCONNECTED and out.commands == {}
    m.engage(0.05)
    feed(m, 0.06)
    assert "head" in m.step(0.06).commands


@pytest.mark.parametrize("mode", [DeadManMode.HOLD, DeadManMode.TOGGLE])
def test_deadman_modes_through_the_mapper(mode):
    m = engaged(deadman_mode=mode)
    t = 0.0

    def tick(grip_left):
        nonlocal t
        t += 1 / 90
        feed(m, t)
        joy(m, "left", grip_left, t)
        joy(m, "right", 0.0, t)
        return m.step(t)

    assert tick(0.0).arms_following == {"left": False, "right": False}
    out = tick(1.0)
    assert out.arms_following["left"] and "left_arm" in out.commands and "right_arm" not in out.commands
    out = tick(0.0)  # let go
    if mode is DeadManMode.HOLD:
        assert not out.arms_following["left"] and "left_arm" not in out.commands
    else:
        assert out.arms_following["left"]
        tick(1.0)
        out = tick(0.0)  # second press stops following
        assert not out.arms_following["left"]


def test_grip_held_while_engaging_must_be_pressed_anew():
    m = TeleopMapper(MODEL)
    feed(m, 0.0)
    joy(m, "left", 1.0, 0.0)
    m.engage(0.0)
    feed(m, 0.01)
    joy(m, "left", 1.0, 0.01)
    assert not m.step(0.01).arms_following["left"]
    for t, g in ((0.02, 0.0), (0.03, 1.0)):
        feed(m, t)
        joy(m, "left", g, t)
        out = m.step(t)
    assert out.arms_following["left"]


def test_controller_silence_holds_only_that_arm():
    m = engaged()
    t = 0.0
    for i in range(60):
        t += 1 / 90
        feed(m, t, controllers=False)
        m.on_controller_pose("left", ctrl(LEFT_FWD), t)
        if i < 5:
            m.on_controller_pose("right", ctrl(RIGHT_FWD), t)
        joy(m, "left", 1.0, t)
        joy(m, "right", 1.0, t)
        out = m.step(t)
    assert out.arms_following == {"left": True, "right": False}
    assert out.pose_age_s["right"] > 0.2 and out.state is WatchdogState.ACTIVE


def test_both_sticks_clicked_is_a_soft_estop():
    m = engaged()
    feed(m, 0.01)
    joy(m, "left", 0.0, 0.01, click=1)
    assert m.state is WatchdogState.ACTIVE
    joy(m, "right", 0.0, 0.01, click=1)
    assert m.state is WatchdogState.ESTOPPED
    assert m.step(0.02).commands == {}


def test_disabled_part_holds_and_duplicate_time_moves_nothing():
    m = engaged()
    m.set_part_enabled("head", False)
    feed(m, 0.01, yaw=30)
    out = m.step(0.01)
    assert "head" not in out.commands
    m.set_part_enabled("head", True)
    feed(m, 0.02, yaw=30)
    assert "head" in m.step(0.02).commands
    out = m.step(0.02)
    assert out.commands == {} and out.dt == 0.0
    with pytest.raises(KeyError, match="unknown part"):
        m.set_part_enabled("tail", True)


def test_bad_joy_and_settings_are_rejected_with_names():
    m = TeleopMapper(MODEL)
    with pytest.raises(ValueError, match="left joy axes: expected at least 4"):
        m.on_joy("left", [0.0, 0.0], [0, 0, 0, 0], 0.0)
    with pytest.raises(ValueError, match="right joy axes: contains NaN"):
        m.on_joy("right", [0.0, 0.0, 0.0, float("nan")], [0, 0, 0, 0], 0.0)
    with pytest.raises(ValueError, match="side must be 'left' or 'right'"):
        m.on_joy("middle", [0.0] * 4, [0] * 4, 0.0)
    with pytest.raises(ValidationError, match="grip_release_threshold"):
        TeleopSettings(grip_press_threshold=0.3, grip_release_threshold=0.5)
    with pytest.raises(ValidationError):
        TeleopSettings(watchdog_timeout=1.0)  # misspelt: extra fields are refused
    with pytest.raises(ValueError, match="velocity_caps_deg_s: unknown joint 'Nose'"):
        TeleopMapper(MODEL, TeleopSettings(velocity_caps_deg_s={"HeadYaw": 1.0, "Nose": 2.0}))


def test_output_message_is_json():
    m = engaged()
    feed(m, 0.01)
    joy(m, "left", 1.0, 0.01)
    msg = m.step(0.01).to_message()
    json.dumps(msg)
    assert msg["state"] == "active" and msg["arms_following"]["left"] is True and "left_arm" in msg["commands"]


# ----- property: whatever arrives, commands stay within limits and within the velocity cap -------------------
near = st.floats(-0.8, 0.8, allow_nan=False)
weird = st.sampled_from([float("nan"), float("inf"), -float("inf"), 1e9, -1e9, 0.0])
offset = st.one_of(*[near] * 8, weird)  # mostly plausible, sometimes garbage
unit_quat = st.lists(st.floats(-1, 1), min_size=4, max_size=4).filter(lambda q: np.linalg.norm(q) > 0.2).map(
    lambda q: list(np.asarray(q) / np.linalg.norm(q)))
quat = st.one_of(*[unit_quat] * 5, st.lists(st.one_of(st.floats(-2, 2), weird), min_size=4, max_size=4))
gap = st.sampled_from([0.0, 0.001, 0.001, 0.011, 0.011, 0.011, 0.011, 0.05, 0.3, 1.5])
KINDS = ["head"] * 6 + ["left"] * 3 + ["right"] * 3 + ["joy_left", "joy_right"] * 2 + ["step"] * 6 + [
    "burst", "engage", "engage", "release", "disconnect"]
event = st.tuples(gap, st.sampled_from(KINDS), st.lists(offset, min_size=3, max_size=3), quat,
                  st.sampled_from(["unity_left_handed", "world"]), st.sampled_from([0.0, 0.5, 1.0, 1.0]))


start_pose = st.fixed_dictionaries({  # where the robot is at engage: anywhere, often right at a limit
    j.name: st.one_of(st.floats(j.lower, j.upper), st.just(j.lower), st.just(j.upper)) for j in MODEL.joints})


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(event, min_size=5, max_size=80), st.sampled_from(["hold", "toggle"]), start_pose)
def test_any_stream_keeps_commands_in_limits_and_under_the_velocity_cap(events, mode, start):
    """NaN, jumps, 1 kHz bursts, stalls, garbage quaternions, engage/release at random: never out of bounds."""
    m = TeleopMapper(MODEL, TeleopSettings(deadman_mode=mode))
    caps = {n: MODEL.joint(n).max_velocity for n in MODEL.names}
    base = {"head": np.array([0.0, 1.2, 0.0]), "left": np.array([-0.2, 1.0, 0.3]), "right": np.array([0.2, 1.0, 0.3])}

    def msg(pos, q, frame):
        return {"header": {"frame_id": frame}, "pose": {"position": dict(zip("xyz", map(float, pos))),
                                                        "orientation": dict(zip("xyzw", q))}}

    def check_step(now):
        before = m.last_command
        out = m.step(now)
        assert 0.0 <= out.dt <= m.settings.max_step_dt_s
        for part, values in out.commands.items():
            for name, v in zip(MODEL.parts[part], values):
                j = MODEL.joint(name)
                assert math.isfinite(v) and j.lower <= v <= j.upper, (name, v)
                allowed = caps[name] * out.ramp[part] * out.dt
                assert abs(v - before[name]) <= allowed + 1e-9, (name, v, before[name], allowed)
        moved = {n for n in MODEL.names if m.last_command[n] != before[n]}
        assert moved <= set(out.targets)  # nothing moves without being commanded

    t = 0.0
    m.on_head_pose(msg(base["head"], [0, 0, 0, 1], "unity_left_handed"), t)
    m.engage(t, current_joints=start)
    for dt, kind, pos, q, frame, grip in events:
        t += dt
        try:
            if kind in ("head", "left", "right"):
                p = base[kind] + np.asarray(pos) if kind != "head" or frame == "unity_left_handed" else np.asarray(pos)
                (m.on_head_pose(msg(p, q, frame), t) if kind == "head"
                 else m.on_controller_pose(kind, msg(p, q, frame), t))
            elif kind.startswith("joy_"):
                m.on_joy(kind[4:], [0.0, 0.0, 0.0, grip], [0, 0, 0, 0], t)
            elif kind == "engage":
                m.engage(t, current_joints={"HeadYaw": pos[0] * 80} if math.isfinite(pos[0]) else None)
            elif kind == "release":
                m.release()
            elif kind == "disconnect":
                m.disconnect()
            elif kind == "burst":  # 1 kHz poses and steps: a head swinging fast and a hand sweeping sideways
                for i in range(20):
                    t += 0.001
                    m.on_head_pose(msg(base["head"], Rotation.from_euler("y", 9 * i, degrees=True).as_quat(),
                                       "unity_left_handed"), t)
                    m.on_controller_pose("left", msg(base["left"] + [-0.03 * i, 0.02 * i, 0], [0, 0, 0, 1], "unity_left_handed"), t)
                    m.on_controller_pose("right", msg(base["right"] + [0, -0.03 * i, 0.02 * i], [0, 0, 0, 1], "unity_left_handed"), t)
                    m.on_joy("left", [0.0, 0.0, 0.0, float(i % 7 != 0)], [0, 0, 0, 0], t)
                    m.on_joy("right", [0.0, 0.0, 0.0, float(i % 5 != 0)], [0, 0, 0, 0], t)
                    check_step(t)
                continue
        except (ValueError, TeleopError):
            pass  # rejected input: the mapper must simply keep its last good state
        check_step(t)
