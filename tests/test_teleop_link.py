"""The network-aware watchdog, pure (teleop/link.py and its use in TeleopMapper): the threshold adapts to the
pose stream's jitter within [floor, ceiling], stale poses are dropped by stamp, a backlog is not fresh, and hold
and resume never make the head jump."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from robot_models import load_qtrobot
from vr_teleop_server.teleop import TeleopMapper, TeleopSettings, WatchdogState
from vr_teleop_server.teleop.link import PoseLink, stamp_seconds

MODEL = load_qtrobot()
RATE = 90.0
CLOCK_OFFSET = 1_700_000_000.0  # the headset's wall clock, far from the server's monotonic one


def head_msg(stamp: float | None, yaw_left_deg: float = 0.0) -> dict:
    q = Rotation.from_rotvec([0, -math.radians(yaw_left_deg), 0]).as_quat()
    header = {"frame_id": "unity_left_handed"}
    if stamp is not None:
        header["stamp"] = {"secs": int(stamp), "nsecs": int(round((stamp % 1) * 1e9)) % 1_000_000_000}
    return {"header": header, "pose": {"position": {"x": 0.0, "y": 1.6, "z": 0.0},
                                       "orientation": dict(zip("xyzw", map(float, q)))}}


def test_stamps_of_both_ros_styles_and_none() -> None:
    assert stamp_seconds({"header": {"stamp": {"secs": 3, "nsecs": 500_000_000}}}) == 3.5
    assert stamp_seconds({"header": {"stamp": {"sec": 3, "nanosec": 250_000_000}}}) == 3.25
    assert stamp_seconds({"header": {"stamp": {"secs": 0, "nsecs": 0}}}) is None
    assert stamp_seconds({"pose": {}}) is None


def test_a_steady_stream_keeps_the_floor_and_is_never_late() -> None:
    link = PoseLink(0.2, 0.5)
    for i in range(1000):
        now = 5.0 + i / RATE + 0.03  # a constant path delay: no lateness
        a = link.arrive(CLOCK_OFFSET + i / RATE, now)
        assert a.accepted and a.late_s == pytest.approx(0.0, abs=1e-6) and a.effective_time == pytest.approx(now)
    assert link.threshold_s == 0.2


def test_tcp_like_stalls_raise_the_threshold_but_not_past_the_ceiling() -> None:
    """A stream held up 250 ms every half second (a retransmission on a lossy long path), its poses then arriving
    in a burst: the threshold learns to wait past such stalls, within the ceiling."""
    link = PoseLink(0.2, 0.5, margin=1.5)
    held: list[float] = []
    for i in range(2000):
        made = i / RATE
        arrive = made + 0.075
        phase = made % 0.5
        if phase < 0.25:  # made during a stall: arrives when it clears
            arrive = made - phase + 0.25 + 0.075
        a = link.arrive(CLOCK_OFFSET + made, arrive)
        assert a.accepted
        held.append(link.threshold_s)
    assert 0.25 * 1.5 * 0.9 <= link.threshold_s <= 0.5
    assert all(0.2 <= h <= 0.5 for h in held)
    link = PoseLink(0.2, 0.3, margin=1.5)
    for i in range(2000):
        link.arrive(None, i * 0.25)  # 4 Hz: every silence would need 375 ms
    assert link.threshold_s == 0.3


def test_older_poses_are_dropped_by_stamp_and_a_clock_restart_is_taken() -> None:
    link = PoseLink(0.2, 0.5)
    assert link.arrive(CLOCK_OFFSET + 1.0, 10.0).accepted
    assert not link.arrive(CLOCK_OFFSET + 0.99, 10.01).accepted  # overtaken: never replayed
    assert link.arrive(CLOCK_OFFSET + 1.0, 10.02).accepted  # the same stamp again: a client without a clock
    assert link.arrive(CLOCK_OFFSET + 1.01, 10.03).accepted
    assert link.stale_dropped == 1
    a = link.arrive(CLOCK_OFFSET - 3600.0, 10.04)  # the headset app restarted its clock
    assert a.accepted and a.late_s == 0.0


def test_a_backlog_after_an_outage_is_already_old() -> None:
    link = PoseLink(0.2, 0.5)
    for i in range(90):
        link.arrive(CLOCK_OFFSET + i / RATE, 1.0 + i / RATE)
    # 2 s of poses held back by the link, then delivered together
    burst = [link.arrive(CLOCK_OFFSET + (90 + k) / RATE, 3.0 + 1.0 + 0.001 * k / 180) for k in range(180)]
    assert all(a.accepted for a in burst)
    ages = [(4.0 + 0.001 * k / 180) - a.effective_time for k, a in enumerate(burst)]
    assert ages[0] == pytest.approx(2.0, abs=0.02)  # the oldest of the backlog is 2 s old
    assert ages[-1] < 0.02  # the newest was made just now


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.floats(0.0, 0.8), st.one_of(st.none(), st.floats(-3.0, 3.0))), min_size=1,
                max_size=300),
       st.floats(0.05, 0.6), st.floats(0.05, 1.0))
def test_any_stream_keeps_the_threshold_in_bounds_and_effective_times_in_order(
        events: list[tuple[float, float | None]], floor: float, ceiling: float) -> None:
    """Whatever the arrivals (gaps, missing, jumping or backward stamps): floor <= threshold <= max(floor, ceiling),
    effective times never go back nor beyond arrival, and every taken stamp is at least the one before (or far
    behind it: a clock restart)."""
    link = PoseLink(floor, ceiling, min_samples=5)
    now, stamp_clock = 0.0, 100.0
    last_eff, last_stamp = -math.inf, None
    for gap, stamp_jump in events:
        now += gap
        stamp = None if stamp_jump is None else stamp_clock + gap + stamp_jump
        a = link.arrive(stamp, now)
        assert floor <= link.threshold_s <= max(floor, ceiling) + 1e-12
        if a.accepted:
            assert last_eff <= a.effective_time <= now
            last_eff = a.effective_time
            if stamp is not None:
                if last_stamp is not None:
                    assert stamp >= last_stamp or last_stamp - stamp > link.clock_reset_s
                last_stamp = stamp
                stamp_clock = stamp
        else:
            assert stamp is not None and last_stamp is not None and 0 < last_stamp - stamp <= link.clock_reset_s


# ---- in the mapper ---------------------------------------------------------------------------------------------------
def _engaged(**kw) -> TeleopMapper:
    m = TeleopMapper(MODEL, TeleopSettings(**kw))
    m.on_head_pose(head_msg(CLOCK_OFFSET), 0.0)
    m.engage(0.0)
    return m


def test_one_late_pose_does_not_hold_a_real_stall_does_within_the_ceiling() -> None:
    """A lossy long path over TCP: every 45th pose is held up 250 ms (a retransmission), those behind it arriving
    with it. The first few such stalls hold the robot (the floor is 200 ms); once the threshold has learnt them they
    no longer do. Then the link drops: the robot holds within the ceiling."""
    m = _engaged(watchdog_timeout_s=0.2, watchdog_ceiling_s=0.5)
    events: list[tuple[float, float | None]] = []  # (time, made) for a pose, (time, None) for a control tick
    for i in range(1, 900):
        made = i / RATE
        held = i - i % 45
        late = held / RATE + 0.25 - made
        events.append((made + max(late, 0.0) + 0.075, made))
    end = events[-1][0]
    events += [(k / 30, None) for k in range(1, int((end + 1.0) * 30))]
    events.sort(key=lambda e: e[0])
    states = []
    for t, made in events:
        if made is not None:
            m.on_head_pose(head_msg(CLOCK_OFFSET + made, 10.0), t)
        states.append((t, m.step(t).state))
    during = [st for t, st in states if t <= end]
    first_half = [st for t, st in states if t <= end / 2]
    second_half = [st for t, st in states if end / 2 < t <= end]
    assert WatchdogState.STALLED in first_half  # at the floor, a 250 ms stall holds
    assert all(st is WatchdogState.ACTIVE for st in second_half)  # learnt: it no longer does
    assert 0.25 < m.watchdog_timeout_s <= 0.5 and during
    held_at = next(t for t, st in states if t > end and st is WatchdogState.STALLED)
    assert held_at - end <= 0.5 + 1 / 30  # the link dropped after the last pose: held within the ceiling


@pytest.mark.parametrize("backlog", [True, False])
def test_hold_and_resume_never_jump_and_resume_only_on_fresh_poses(backlog: bool) -> None:
    """The head follows a sweep, the link drops 2 s, then (over TCP) the backlog arrives in one burst before the
    fresh poses, or (unordered) only fresh ones come. The robot holds, stays stalled through the backlog, resumes
    on the first fresh pose, and no command moves a joint faster than its cap allows (ramped after resume)."""
    s = TeleopSettings()
    m = _engaged()
    caps = {n: MODEL.joint(n).max_velocity * s.velocity_scale for n in ("HeadYaw", "HeadPitch")}
    commands: list[tuple[float, tuple[float, ...], WatchdogState]] = []

    def intent(made: float) -> float:
        return 50 * math.sin(2 * math.pi * 0.3 * made)

    def deliver(made: float, now: float) -> None:
        m.on_head_pose(head_msg(CLOCK_OFFSET + made, intent(made)), now)
        out = m.step(now)
        commands.append((now, out.commands.get("head"), out.state))

    for i in range(1, 270):  # 3 s
        deliver(i / RATE, i / RATE + 0.075)
    down_at = 270 / RATE
    for k in range(1, 90):  # 2 s + a bit of silence: the tick sees it
        out = m.step(down_at + 0.075 + k / 30)
        commands.append((down_at + 0.075 + k / 30, out.commands.get("head"), out.state))
    up_at = down_at + 2.0
    first_fresh = None
    t_burst = up_at + 0.3
    if backlog:
        for j, i in enumerate(range(270, int(up_at * RATE))):  # made while the link was down, all at once
            deliver(i / RATE, t_burst + j * 1e-4)
            assert commands[-1][2] is WatchdogState.STALLED and commands[-1][1] is None
    for i in range(int(up_at * RATE) + 27, int(up_at * RATE) + 27 + 450):  # fresh poses
        deliver(i / RATE, i / RATE + 0.075 + (0.0 if backlog else 0.0))
        if first_fresh is None and commands[-1][2] is WatchdogState.ACTIVE:
            first_fresh = i / RATE
    assert first_fresh is not None
    assert any(c[2] is WatchdogState.STALLED for c in commands)
    moving = [(t, c) for t, c, _s in commands if c is not None]
    for (t0, c0), (t1, c1) in zip(moving, moving[1:]):
        dt = min(max(t1 - t0, 0.0), s.max_step_dt_s)
        for k, name in enumerate(("HeadYaw", "HeadPitch")):
            assert abs(c1[k] - c0[k]) <= caps[name] * dt + 1e-6, (t0, t1, c0, c1)
    # it catches up with the operator afterwards
    assert moving[-1][1][0] == pytest.approx(np.clip(intent(moving[-1][0] - 0.075), -60, 60), abs=5)


@settings(max_examples=15, deadline=None)
@given(outage=st.floats(0.05, 3.0), delay=st.floats(0.0, 0.2), jitter=st.floats(0.0, 0.03),
       backlog=st.booleans(), seed=st.integers(0, 2**16))
def test_any_outage_holds_and_resumes_without_a_jump(outage: float, delay: float, jitter: float, backlog: bool,
                                                     seed: int) -> None:
    """Whatever the outage, path delay and jitter, and whether the backlog is delivered: no command while held,
    no step beyond cap x dt (dt as the mapper counts it), the threshold within its bounds, and a hold longer than
    the ceiling always holds."""
    rng = np.random.default_rng(seed)
    s = TeleopSettings()
    m = _engaged()
    cap = MODEL.joint("HeadYaw").max_velocity * s.velocity_scale
    events: list[tuple[float, float | None]] = []
    down_from, down_to = 2.0, 2.0 + outage
    burst_at = down_to + delay
    for i in range(1, int((down_to + 2.0) * RATE)):
        made = i / RATE
        if down_from <= made < down_to:
            if backlog:
                events.append((burst_at + i * 1e-6, made))
            continue
        events.append((made + delay + abs(rng.normal(0, jitter)), made))
    events += [(k / 30, None) for k in range(1, int((down_to + 2.5) * 30))]
    events.sort(key=lambda e: e[0])
    last = None
    last_t = None
    held_seen = False
    for t, made in events:
        if made is not None:
            m.on_head_pose(head_msg(CLOCK_OFFSET + made, 50 * math.sin(2 * math.pi * 0.4 * made)), t)
        out = m.step(t)
        assert s.watchdog_timeout_s <= out.watchdog_timeout_s <= s.watchdog_ceiling_s
        if out.state is WatchdogState.STALLED:
            held_seen = True
            assert out.commands == {}
        head = out.commands.get("head")
        if head is not None:
            if last is not None:
                assert abs(head[0] - last[0]) <= cap * min(t - last_t, s.max_step_dt_s) + 1e-6
            last, last_t = head, t
        elif out.dt > 0 and last is not None:
            last_t = t  # a step that moved nothing still advances the mapper's clock
    if outage > s.watchdog_ceiling_s + 0.05:
        assert held_seen
