"""The link-quality verdict of the telemetry (media/link_quality.py): figures in, word and reasons out."""

from __future__ import annotations

import itertools

import pytest

from vr_teleop_server.media.link_quality import DEGRADED, GOOD, POOR, ControlLink, assess, pose_jitter


def holding(**changes) -> ControlLink:
    values = {"state": "active", "threshold_s": 0.2, "floor_s": 0.2, "ceiling_s": 0.5, "holds_last_minute": 0}
    return ControlLink(**{**values, **changes})


def test_nothing_measured_is_unknown_and_a_quick_link_is_good() -> None:
    assert assess(ws_rtt=-1.0) == ("", "")
    assert assess(ws_rtt=0.002, rtc_rtt=0.003, fraction_lost=0.0, pose_jitter_s=0.004, control=holding()) == (GOOD, "")


@pytest.mark.parametrize(("rtt", "expected"), [(0.099, GOOD), (0.100, DEGRADED), (0.249, DEGRADED), (0.250, POOR)])
def test_the_worse_round_trip_decides(rtt: float, expected: str) -> None:
    assert assess(ws_rtt=0.01, rtc_rtt=rtt)[0] == expected
    assert assess(ws_rtt=rtt, rtc_rtt=-1.0)[0] == expected


def test_loss_is_named_with_its_share() -> None:
    quality, warning = assess(ws_rtt=0.01, fraction_lost=0.05)
    assert quality == DEGRADED and "5% of media packets lost" in warning
    assert assess(ws_rtt=0.01, fraction_lost=0.12)[0] == POOR


def test_the_watchdog_speaks_for_the_holder_only() -> None:
    # a stretched threshold: degraded; at its ceiling: poor; a stall: poor, whatever the round trip says
    quality, warning = assess(ws_rtt=0.01, control=holding(threshold_s=0.3))
    assert quality == DEGRADED and "watchdog waits 300 ms" in warning
    assert assess(ws_rtt=0.01, control=holding(threshold_s=0.5))[0] == POOR
    quality, warning = assess(ws_rtt=0.01, control=holding(state="stalled"))
    assert quality == POOR and "the robot holds" in warning
    # jitter the watchdog's threshold cannot absorb: poor; the same jitter without control: not judged
    assert assess(ws_rtt=0.01, pose_jitter_s=0.25, control=holding(threshold_s=0.22))[0] == POOR
    assert assess(ws_rtt=0.01, pose_jitter_s=0.25) == (GOOD, "")


def test_recent_holds_count_and_every_reason_is_given_worst_first() -> None:
    quality, warning = assess(ws_rtt=0.12, control=holding(holds_last_minute=1))
    assert quality == DEGRADED and "held 1 time in" in warning and "round trip 120 ms" in warning
    quality, warning = assess(ws_rtt=0.12, control=holding(holds_last_minute=3))
    assert quality == POOR and warning.index("held 3 times") < warning.index("round trip")


def test_pose_jitter_is_the_late_tail_of_the_arrival_gaps() -> None:
    even = [i / 90 for i in range(200)]
    assert pose_jitter(even, now=even[-1]) == pytest.approx(0.0, abs=1e-9)
    # every tenth pose 100 ms late (a stall; the stream goes on from there): the 95th percentile of the gaps is
    # 100 ms above the usual gap
    late = list(itertools.accumulate(1 / 90 + (0.1 if i % 10 == 5 else 0.0) for i in range(200)))
    assert pose_jitter(late, now=late[-1]) == pytest.approx(0.1, abs=1e-6)
    # only the last 5 s count, and too few poses say nothing
    assert pose_jitter(even, now=even[-1] + 10) == -1.0
    assert pose_jitter(even[:5], now=even[4]) == -1.0
