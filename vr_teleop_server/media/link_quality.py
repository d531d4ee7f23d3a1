"""How good one client's link is for teleoperation, in one word and one sentence the operator can act on.

Pure: figures in, verdict out. The telemetry (telemetry.py) calls `assess` at each report for a client whose
operator holds control once its head poses have reached the server (before then there is no link to judge: a
page that has just opened, on a machine still busy loading it, is not told LINK POOR); the operator page's HUD shows
the word and the sentence, and warns when control is degraded.

Three levels (README "Link quality"): `good`, `degraded` (control works, but the operator should know: the robot
lags, or the watchdog had to stretch to the network's jitter, or it held lately), `poor` (control is not to be
trusted: the robot holds now, or would on the network's ordinary jitter, or the link loses or delays a lot). An
empty word means nothing is known yet (no round trip measured). The thresholds are below, in one place.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

GOOD, DEGRADED, POOR = "good", "degraded", "poor"
_RANK = {GOOD: 0, DEGRADED: 1, POOR: 2}

# Round trip (the WebSocket's ping, or the peer connection's RTCP, whichever is worse): a head turn shows on the
# panel one round trip (plus a frame) later; past ~100 ms people notice, past ~250 ms they overshoot.
RTT_DEGRADED_S = 0.100
RTT_POOR_S = 0.250
# Media packet loss (the newest receiver report's fraction): video freezes and audio gaps.
LOSS_DEGRADED = 0.02
LOSS_POOR = 0.10
# The watchdog held this many times in the last minute.
HOLDS_DEGRADED = 1
HOLDS_POOR = 3
JITTER_WINDOW_S = 5.0  # pose arrivals looked at for the jitter
JITTER_MIN_GAPS = 10


@dataclass(frozen=True)
class ControlLink:
    """The watchdog as it stands for the operator of one connection, while that operator holds control."""

    state: str               # teleop_state's state: active, stalled, ...
    threshold_s: float       # the adaptive silence threshold in force
    floor_s: float           # the configured watchdog timeout (the threshold's floor)
    ceiling_s: float         # the threshold's hard ceiling
    holds_last_minute: int   # watchdog holds (stalled) in the last 60 s


def pose_jitter(arrivals: Sequence[float], now: float, window_s: float = JITTER_WINDOW_S) -> float:
    """How much later than usual a pose arrives: the 95th percentile of the gaps between pose arrivals in the last
    `window_s`, less their median (seconds); -1 with too few poses to say."""
    times = [t for t in arrivals if now - t <= window_s]
    if len(times) <= JITTER_MIN_GAPS:
        return -1.0
    gaps = np.diff(np.asarray(times))
    return float(np.percentile(gaps, 95) - np.median(gaps))


def assess(*, ws_rtt: float, rtc_rtt: float = -1.0, fraction_lost: float = 0.0, pose_jitter_s: float = -1.0,
           control: ControlLink | None = None) -> tuple[str, str]:
    """(quality, warning): the worst level any figure reaches, and every figure below `good` in words (empty when
    good). Figures below 0 are not known and count for nothing."""
    found: list[tuple[str, str]] = []
    rtt = max(ws_rtt, rtc_rtt)
    if rtt >= RTT_POOR_S:
        found.append((POOR, f"round trip {rtt * 1e3:.0f} ms: the robot lags your head"))
    elif rtt >= RTT_DEGRADED_S:
        found.append((DEGRADED, f"round trip {rtt * 1e3:.0f} ms"))
    if fraction_lost >= LOSS_POOR:
        found.append((POOR, f"{fraction_lost:.0%} of media packets lost"))
    elif fraction_lost >= LOSS_DEGRADED:
        found.append((DEGRADED, f"{fraction_lost:.0%} of media packets lost"))
    if control is not None:
        if control.state == "stalled":
            found.append((POOR, "head poses are not arriving: the robot holds"))
        if control.holds_last_minute >= HOLDS_POOR:
            found.append((POOR, f"the robot held {control.holds_last_minute} times in the last minute"))
        elif control.holds_last_minute >= HOLDS_DEGRADED:
            found.append((DEGRADED, f"the robot held {control.holds_last_minute} time"
                                    f"{'s' if control.holds_last_minute > 1 else ''} in the last minute"))
        if pose_jitter_s >= control.threshold_s:
            found.append((POOR, f"poses arrive up to {pose_jitter_s * 1e3:.0f} ms late: the watchdog "
                                f"({control.threshold_s * 1e3:.0f} ms) will hold the robot"))
        elif control.threshold_s > control.floor_s * 1.05:
            level = POOR if control.threshold_s >= control.ceiling_s else DEGRADED
            found.append((level, f"pose jitter: the watchdog waits {control.threshold_s * 1e3:.0f} ms"
                                 f"{' (its ceiling)' if level == POOR else ''}"))
    if not found:
        return (GOOD if rtt >= 0 else ""), ""
    worst = max(found, key=lambda f: _RANK[f[0]])[0]
    return worst, "; ".join(text for level, text in sorted(found, key=lambda f: -_RANK[f[0]]))
