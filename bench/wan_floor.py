"""The least head tracking error any transport could give on each network profile, for bench/wan.py's figures.

The classroom session's head poses (`--quick`'s first 60 s; seed 0), each delivered after the profile's one-way
delay plus its jitter (a queue where the profile keeps order), lost at its loss rate, and nothing else: no
congestion window, no retransmission, no server. The robot's head is taken as the newest pose arrived (no filter,
no velocity caps: those are the same on every profile). Sampled at 30 Hz like bench/wan.py, degrees, the larger
of yaw and pitch, against the intent then and against the intent one delay earlier (bench/wan.py's "less the
link's delay"). No transport does better than these; what bench/wan.py measures above them is the transport's.

A third column asks what prediction at the headset would buy on the first measure: each pose sent as the head is
expected to be one delay later (its velocity over the last PREDICT_WINDOW_S held for the profile's one-way delay),
against the intent then. Not built into the senders; this says how far it could go.

    python bench/wan_floor.py [--seconds 60] [--seeds 5]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

ROOT = Path(__file__).resolve().parent.parent
sys.path[:0] = [str(ROOT)]

from netem import load_profiles  # noqa: E402
from testbed.sessions import classroom_steps  # noqa: E402


def head_angles(seconds: float) -> tuple[np.ndarray, np.ndarray]:
    """Send times and (yaw, pitch) in degrees of the session's head poses."""
    head = [s for s in classroom_steps(seconds) if s.kind == "publish" and s.topic == "/vr/head/pose"]
    t = np.array([s.t for s in head])
    q = np.array([[s.payload["pose"]["orientation"][k] for k in "xyzw"] for s in head])
    angles = np.degrees(np.unwrap(Rotation.from_quat(q).as_euler("YXZ")[:, :2], axis=0))  # Unity: yaw about y
    return t, angles


PREDICT_WINDOW_S = 0.05


def predicted(t: np.ndarray, angles: np.ndarray, lead_s: float) -> np.ndarray:
    """Each pose moved `lead_s` ahead at its velocity over the last PREDICT_WINDOW_S (constant velocity)."""
    k = np.searchsorted(t, t - PREDICT_WINDOW_S)
    velocity = (angles - angles[k]) / np.maximum(t - t[k], 1e-3)[:, None]
    return angles + velocity * lead_s


def floor(t: np.ndarray, angles: np.ndarray, profile, seed: int, less_delay: bool, predict: bool = False) -> np.ndarray:
    up = profile.up
    rng = np.random.default_rng(seed)
    delay = up.delay_ms / 1e3
    sent = predicted(t, angles, delay) if predict else angles
    arrival = t + delay + np.clip(rng.normal(0.0, up.jitter_ms / 1e3, t.size), -delay, None)
    if up.keep_order:
        arrival = np.maximum.accumulate(arrival)
    kept = rng.random(t.size) >= up.loss
    arrival, held = arrival[kept], sent[kept]
    grid = np.arange(arrival[0], t[-1], 1.0 / 30.0)
    command = held[np.searchsorted(arrival, grid, side="right") - 1]
    intent = angles[np.searchsorted(t, grid - (delay if less_delay else 0.0), side="right") - 1]
    return np.abs(command - intent).max(axis=1)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seconds", type=float, default=60.0)
    parser.add_argument("--seeds", type=int, default=5, help="draws of jitter and loss, pooled")
    args = parser.parse_args()
    t, angles = head_angles(args.seconds)
    speed = np.abs(np.diff(angles, axis=0)).max(axis=1) / np.diff(t)
    print(f"head speed p50 / p95 / max: {np.percentile(speed, 50):.0f} / {np.percentile(speed, 95):.0f} / "
          f"{speed.max():.0f} deg/s")
    print("| profile | floor against the intent then, p50 / p95 | floor less the link's delay, p50 / p95 "
          "| against the intent then, poses predicted one delay ahead, p50 / p95 |")
    print("|---|---|---|---|")
    for name, profile in load_profiles().items():
        cells = []
        for less, predict in ((False, False), (True, False), (False, True)):
            e = np.concatenate([floor(t, angles, profile, seed, less, predict) for seed in range(args.seeds)])
            cells.append(f"{np.percentile(e, 50):.2f} / {np.percentile(e, 95):.2f} deg")
        print(f"| `{name}` | " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
