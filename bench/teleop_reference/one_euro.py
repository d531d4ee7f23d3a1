"""The One Euro filter (Casiez, Roussel, Vogel, CHI 2012), one per joint, in degrees.

A first-order low-pass whose cutoff rises with speed: still hands get heavy smoothing (no jitter), fast
moves get little (no lag). With Te the time since the last sample:

    alpha(fc) = 1 / (1 + tau/Te),  tau = 1 / (2 pi fc)
    dx  = low-pass of (x - x_prev)/Te at d_cutoff
    fc  = min_cutoff + beta |dx|
    out = low-pass of x at fc

Defaults for joint angles in degrees at 90 Hz: min_cutoff 1.0 Hz (the paper's default; about 160 ms lag at
rest, below the robot's own response), beta 0.05 per deg/s (a 60 deg/s head turn raises the cutoff to 4 Hz,
about 40 ms lag), d_cutoff 1.0 Hz. Tuning, as the paper suggests: set beta 0, lower min_cutoff until a still
controller no longer makes the joint tremble; then move fast and raise beta until the lag is gone.

Time comes from the caller (monotonic seconds), so the filter copes with irregular rates. A sample whose time
is not after the previous one (a duplicate or out-of-order timestamp) is ignored: the previous output is
returned and the state is untouched.
"""

from __future__ import annotations

import math


def smoothing_factor(te: float, cutoff_hz: float) -> float:
    tau = 1.0 / (2.0 * math.pi * cutoff_hz)
    return 1.0 / (1.0 + tau / te)


class OneEuroFilter:
    """One scalar signal. Call with (value, time); `reset` to restart from a known value."""

    __slots__ = ("min_cutoff", "beta", "d_cutoff", "_x", "_dx", "_t")

    def __init__(self, min_cutoff: float = 1.0, beta: float = 0.05, d_cutoff: float = 1.0) -> None:
        if min_cutoff <= 0 or d_cutoff <= 0 or beta < 0:
            raise ValueError(
                f"One Euro parameters: min_cutoff ({min_cutoff}) and d_cutoff ({d_cutoff}) must be > 0 Hz, "
                f"beta ({beta}) >= 0"
            )
        self.min_cutoff = min_cutoff
        self.beta = beta
        self.d_cutoff = d_cutoff
        self._x: float | None = None
        self._dx = 0.0
        self._t = 0.0

    @property
    def value(self) -> float | None:
        return self._x

    def reset(self, x: float | None = None, t: float = 0.0) -> None:
        """Start afresh: the next sample passes through unchanged (or is smoothed from `x` if given)."""
        self._x = None if x is None else float(x)
        self._dx = 0.0
        self._t = t

    def __call__(self, x: float, t: float) -> float:
        if self._x is None:
            self._x, self._dx, self._t = float(x), 0.0, t
            return self._x
        te = t - self._t
        if not te > 0.0:  # duplicate or out-of-order time: hold
            return self._x
        dx = (x - self._x) / te
        self._dx += smoothing_factor(te, self.d_cutoff) * (dx - self._dx)
        cutoff = self.min_cutoff + self.beta * abs(self._dx)
        self._x += smoothing_factor(te, cutoff) * (x - self._x)
        self._t = t
        return self._x
