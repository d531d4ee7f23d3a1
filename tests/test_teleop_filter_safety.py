"""One Euro filter, velocity cap, ramp, joint clamp and dead-man on their own."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from robot_models import load_qtrobot
from vr_teleop_server.teleop.one_euro import OneEuroFilter, smoothing_factor
from vr_teleop_server.teleop.safety import DeadMan, DeadManMode, VelocityRamp, cap_step, clamp_joints

MODEL = load_qtrobot()


def test_one_euro_first_step_by_hand():
    f = OneEuroFilter(min_cutoff=1.0, beta=0.5, d_cutoff=1.0)
    assert f(10.0, 0.0) == 10.0  # first sample passes through
    te = 0.01
    dx = (12.0 - 10.0) / te
    dx_hat = smoothing_factor(te, 1.0) * dx
    cutoff = 1.0 + 0.5 * abs(dx_hat)
    expected = 10.0 + smoothing_factor(te, cutoff) * 2.0
    assert f(12.0, te) == pytest.approx(expected)
    assert smoothing_factor(te, 1.0) == pytest.approx(1 / (1 + (1 / (2 * math.pi)) / te))


def test_one_euro_duplicate_and_backward_timestamps_hold():
    f = OneEuroFilter()
    f(0.0, 1.0)
    y = f(5.0, 1.1)
    assert f(100.0, 1.1) == y  # duplicate time: ignored
    assert f(-100.0, 1.05) == y  # out of order: ignored
    assert f(5.0, 1.2) != y  # time moves on: filtering continues


def test_one_euro_smooths_jitter_and_beta_cuts_lag():
    rng = np.random.default_rng(1)
    t = np.arange(0, 5, 1 / 90)
    still = 10 + rng.normal(0, 0.5, t.size)
    f = OneEuroFilter(1.0, 0.0, 1.0)
    out = np.array([f(x, ti) for x, ti in zip(still, t)])
    assert np.std(out[90:]) < 0.25 * np.std(still[90:])
    ramp = 60.0 * t  # a 60 deg/s move
    lags = {}
    for beta in (0.0, 0.05):
        f = OneEuroFilter(1.0, beta, 1.0)
        out = np.array([f(x, ti) for x, ti in zip(ramp, t)])
        lags[beta] = float(np.mean(ramp[180:] - out[180:]))
    assert lags[0.0] == pytest.approx(60.0 / (2 * math.pi), rel=0.1)  # ~1/(2 pi fc) s of lag at 60 deg/s
    assert lags[0.05] < 0.4 * lags[0.0]


def test_one_euro_irregular_dt_converges():
    f = OneEuroFilter()
    rng = np.random.default_rng(2)
    t = np.cumsum(rng.uniform(0.0005, 0.05, 500))
    out = [f(7.0, ti) for ti in t]
    assert out[-1] == pytest.approx(7.0)
    with pytest.raises(ValueError, match="min_cutoff"):
        OneEuroFilter(min_cutoff=0)


def test_cap_step_scales_the_whole_step_to_the_fastest_joint():
    new, capped = cap_step([0.0, 0.0], [30.0, 10.0], [100.0, 100.0], 0.1)  # allowed 10 deg per joint
    assert capped and new == pytest.approx([10.0, 10.0 / 3])  # direction kept
    new, capped = cap_step([0.0, 0.0], [3.0, -1.0], [100.0, 100.0], 0.1)
    assert not capped and new == [3.0, -1.0]  # small steps are not amplified
    new, capped = cap_step([0.0, 0.0], [10.0, 10.0], [50.0, 200.0], 0.1)  # per-joint caps: 5 and 20
    assert new == pytest.approx([5.0, 5.0])
    assert cap_step([1.0, 2.0], [5.0, 5.0], [1.0, 1.0], 0.0)[0] == [1.0, 2.0]


@settings(max_examples=300, deadline=None)
@given(st.lists(st.tuples(st.floats(-200, 200), st.floats(-200, 200), st.floats(1, 300)), min_size=1, max_size=4),
       st.floats(1e-4, 0.2))
def test_cap_step_property(rows, dt):
    prev, tgt, caps = (list(x) for x in zip(*rows))
    new, _ = cap_step(prev, tgt, caps, dt)
    for p, t, c, n in zip(prev, tgt, caps, new):
        assert abs(n - p) <= c * dt * (1 + 1e-9) + 1e-12
        assert abs(n - p) <= abs(t - p) + 1e-9  # never amplified
        assert (n - p) * (t - p) >= 0  # never reversed


def test_clamp_reports_joints():
    names = ("HeadYaw", "HeadPitch")
    values, hit = clamp_joints(MODEL, names, [75.0, 10.0])
    assert values == [60.0, 10.0] and hit == ["HeadYaw"]
    values, hit = clamp_joints(MODEL, ("LeftElbowRoll",), [0.0])
    assert values == [-7.0] and hit == ["LeftElbowRoll"]


def test_ramp():
    r = VelocityRamp(2.0, 0.1)
    assert r.factor(5.0) == 1.0  # never started: full caps
    r.restart(10.0)
    assert r.factor(10.0) == pytest.approx(0.1)
    assert r.factor(11.0) == pytest.approx(0.55)
    assert r.factor(13.0) == 1.0


def test_deadman_hold_mode():
    d = DeadMan(DeadManMode.HOLD, 0.6, 0.4)
    assert d.update(0.7)
    assert d.update(0.5)  # hysteresis: still held
    assert not d.update(0.3)
    assert not d.update(0.55)  # below the press threshold
    assert d.update(0.9)
    d.reset()  # engage while holding: must press anew
    assert not d.update(1.0)
    assert not d.update(0.0)
    assert d.update(1.0)


def test_deadman_toggle_mode():
    d = DeadMan(DeadManMode.TOGGLE, 0.6, 0.4)
    assert d.update(0.9)  # press: start
    assert d.update(0.0)  # release: keeps following
    assert d.update(0.0)
    assert not d.update(0.8)  # press again: stop
    assert not d.update(0.1)
    assert d.update(0.7)
    d.drop()
    assert not d.following
