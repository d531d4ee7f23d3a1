"""Generate the gestures we ship (wave, nod, point_forward) as LuxAI gesture XML next to this file.

Run `python -m robot_models.gestures.make_gestures` after editing KEYFRAMES (or the robot description), and
check the XML in; `--check` exits 1 if the checked-in files differ from what this script would write.

Each gesture is a list of keyframes (seconds, joint angles); every joint moves between consecutive keyframes
along a minimum-jerk profile (10s^3 - 15s^4 + 6s^5), so velocity and acceleration are zero at every keyframe
and nothing jerks. Keyframes give only the joints that change; the others hold. The result is sampled at
20 Hz, LuxAI's recording rate. Every gesture starts and ends on the home pose of its parts, stays within the
joint limits, and peaks at no more than PEAK_FRACTION of each joint's velocity cap (a minimum-jerk segment
of amplitude A and length T peaks at 1.875 A / T), so at speed 1 the robot follows it without its rate limiter
bending the path.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from robot_models import RobotModel, load_qtrobot
from robot_models.gestures import GESTURE_DIR, format_gesture_xml

RATE_HZ = 20.0
PEAK_FRACTION = 0.8

# name -> (parts, keyframes). Times in seconds from the start; angles in degrees. The first and last keyframes
# are the home pose (filled in from the robot description, so they are written as {} here).
# Conventions of the description: RightShoulderPitch -90 hangs the arm down, 0 points it forward, +90 up;
# RightShoulderRoll towards 0 lifts it out to the side; RightElbowRoll -35 is straight, more negative bends the
# forearm inwards. HeadPitch > 0 looks down.
KEYFRAMES: dict[str, tuple[tuple[str, ...], tuple[tuple[float, Mapping[str, float]], ...]]] = {
    "wave": (("right_arm",), (
        (0.0, {}),
        # raise the arm forward and out, forearm bent: 120 deg of pitch in 2.4 s peaks at 94 deg/s
        (2.4, {"RightShoulderPitch": 30.0, "RightShoulderRoll": -30.0, "RightElbowRoll": -60.0}),
        # three waves of the forearm: 35 deg in 0.8 s peaks at 82 deg/s
        (3.2, {"RightElbowRoll": -25.0}),
        (4.0, {"RightElbowRoll": -60.0}),
        (4.8, {"RightElbowRoll": -25.0}),
        (5.6, {"RightElbowRoll": -60.0}),
        (6.4, {"RightElbowRoll": -25.0}),
        (7.2, {"RightElbowRoll": -60.0}),
        (9.6, {}),
    )),
    "nod": (("head",), (
        (0.0, {}),
        # twice down 15 deg and back up, 0.5 s each way: peaks at 56 deg/s
        (0.5, {"HeadPitch": 15.0}),
        (1.0, {"HeadPitch": 0.0}),
        (1.5, {"HeadPitch": 15.0}),
        (2.0, {}),
    )),
    "point_forward": (("right_arm",), (
        (0.0, {}),
        # straight arm forward at shoulder height, turned slightly inwards: 90 deg in 2 s peaks at 84 deg/s
        (2.0, {"RightShoulderPitch": 0.0, "RightShoulderRoll": -60.0, "RightElbowRoll": -30.0}),
        (3.5, {}),  # hold
        (5.5, {}),
    )),
}


def _minimum_jerk(s: np.ndarray) -> np.ndarray:
    return s * s * s * (10.0 - 15.0 * s + 6.0 * s * s)


def sample_keyframes(model: RobotModel, parts: Sequence[str],
                     keyframes: Sequence[tuple[float, Mapping[str, float]]]) -> list[tuple[float, dict[str, float]]]:
    """20 Hz points of one gesture; raises ValueError if it leaves the limits or exceeds the velocity budget."""
    joints = [n for part in parts for n in model.part_joints(part)]
    home = {n: model.joint(n).home for n in joints}
    poses, held = [], dict(home)
    for i, (_, pose) in enumerate(keyframes):
        if i in (0, len(keyframes) - 1) and pose:
            raise ValueError("first and last keyframes are the home pose; leave them empty")
        held = dict(home) if i == len(keyframes) - 1 else {**held, **pose}
        poses.append([held[n] for n in joints])
    times = np.array([t for t, _ in keyframes])
    if times[0] != 0.0 or np.any(np.diff(times) <= 0):
        raise ValueError(f"keyframe times must start at 0 and increase, got {times.tolist()}")
    key = np.array(poses)  # keyframe x joint
    t = np.arange(0.0, times[-1] + 1e-9, 1.0 / RATE_HZ)
    seg = np.clip(np.searchsorted(times, t, side="right") - 1, 0, len(times) - 2)
    s = np.clip((t - times[seg]) / (times[seg + 1] - times[seg]), 0.0, 1.0)
    q = key[seg] + (key[seg + 1] - key[seg]) * _minimum_jerk(s)[:, None]  # sample x joint

    for j, name in enumerate(joints):
        joint = model.joint(name)
        if q[:, j].min() < joint.lower or q[:, j].max() > joint.upper:
            raise ValueError(f"{name} leaves its limits [{joint.lower}, {joint.upper}]")
        peak = np.max(np.abs(np.diff(key[:, j])) * 1.875 / np.diff(times))
        if peak > PEAK_FRACTION * joint.max_velocity:
            raise ValueError(f"{name} peaks at {peak:.0f} deg/s, over {PEAK_FRACTION:.0%} of its "
                             f"{joint.max_velocity:g} deg/s cap; give that segment more time")
    return [(float(ti), dict(zip(joints, map(float, row)))) for ti, row in zip(t, q)]


def render_all(model: RobotModel | None = None) -> dict[str, str]:
    """File name -> XML text of every shipped gesture."""
    model = model or load_qtrobot()
    return {f"{name}.xml": format_gesture_xml(name, parts, sample_keyframes(model, parts, keyframes))
            for name, (parts, keyframes) in KEYFRAMES.items()}


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=GESTURE_DIR, help="directory to write (default: this package)")
    parser.add_argument("--check", action="store_true", help="compare with the files in --out instead of writing")
    args = parser.parse_args(argv)
    stale = []
    for filename, text in render_all().items():
        path = args.out / filename
        if args.check:
            if not path.is_file() or path.read_text(encoding="utf-8") != text:
                stale.append(str(path))
        else:
            path.write_text(text, encoding="utf-8")
            print(f"wrote {path}")
    if stale:
        print(f"out of date (run python -m robot_models.gestures.make_gestures): {', '.join(stale)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
