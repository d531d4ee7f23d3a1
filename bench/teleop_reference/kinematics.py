"""Forward kinematics of QTrobot's URDF chain and an analytic inverse for each 3-joint arm.

Angles are degrees at this module's boundary (as the robot API uses them) and radians inside.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from robot_models.qtrobot import ChainElement, RobotModel, load_qtrobot

SIDES = ("left", "right")


def _origin(el: ChainElement) -> np.ndarray:
    t = np.eye(4)
    # URDF rpy: fixed-axis roll about x, then pitch about y, then yaw about z (R = Rz Ry Rx): scipy's extrinsic "xyz".
    t[:3, :3] = Rotation.from_euler("xyz", el.rpy_deg, degrees=True).as_matrix()
    t[:3, 3] = el.xyz
    return t


def forward_kinematics(
    model_or_chain: RobotModel | Sequence[ChainElement], angles_deg: Mapping[str, float]
) -> dict[str, np.ndarray]:
    """4x4 transforms (metres, base frame: x forward, y left, z up) of every chain element's frame.

    Keys include "camera" (optical frame: z forward, x right, y down), "right_hand" and "left_hand", and each
    joint's frame after its rotation. A joint missing from `angles_deg` is taken at 0 degrees, the URDF's zero
    configuration, because a bare chain has no home pose; pass model.home_pose() merged with your angles
    to get the resting pose instead. Unknown names in `angles_deg` raise KeyError, so typos do not pass silently.
    """
    chain = model_or_chain.chain if isinstance(model_or_chain, RobotModel) else tuple(model_or_chain)
    revolute = {el.name for el in chain if el.type == "revolute"}
    unknown = set(angles_deg) - revolute
    if unknown:
        raise KeyError(f"unknown joints {sorted(unknown)}; valid joints: {', '.join(sorted(revolute))}")
    frames: dict[str, np.ndarray] = {"base_link": np.eye(4)}
    for el in chain:
        t = frames[el.parent] @ _origin(el)
        if el.type == "revolute":
            rot = np.eye(4)
            angle = math.radians(float(angles_deg.get(el.name, 0.0)))
            rot[:3, :3] = Rotation.from_rotvec(np.asarray(el.axis, dtype=float) * angle).as_matrix()
            t = t @ rot
        frames[el.name] = t
    del frames["base_link"]
    return frames


@dataclass(frozen=True)
class IKResult:
    """Joint angles (degrees, full joint names, always within limits); `reached` if the hand is on the target."""

    angles_deg: dict[str, float]
    reached: bool
    error_m: float


@dataclass(frozen=True)
class _ArmGeometry:
    """One arm's constants, read from the chain so that nothing here repeats the URDF's numbers."""

    names: tuple[str, str, str]  # ShoulderPitch, ShoulderRoll, ElbowRoll
    base_to_pitch: np.ndarray  # 4x4, pitch joint frame at angle 0
    offset: float  # roll joint's distance along the pitch axis
    l1: float  # roll joint -> elbow
    l2: float  # elbow -> hand
    lower: np.ndarray
    upper: np.ndarray


def _arm_geometry(model: RobotModel, side: str) -> _ArmGeometry:
    if side not in SIDES:
        raise ValueError(f"arm side must be 'left' or 'right', got {side!r}")
    prefix = side.capitalize()
    names = (f"{prefix}ShoulderPitch", f"{prefix}ShoulderRoll", f"{prefix}ElbowRoll")
    by_name = {el.name: el for el in model.chain}
    hand = next(el for el in model.chain if el.parent == names[2] and el.type == "fixed")
    # The solver assumes the URDF's structure (pitch about y; roll and elbow about parallel axes, links along y);
    # check it so that a changed yaml fails loudly instead of giving wrong angles.
    ok = (
        by_name[names[0]].axis == (0.0, 1.0, 0.0)
        and by_name[names[1]].axis == (1.0, 0.0, 0.0) and by_name[names[2]].axis == (1.0, 0.0, 0.0)
        and by_name[names[1]].xyz[0] == by_name[names[1]].xyz[2] == 0.0
        and by_name[names[2]].xyz[0] == by_name[names[2]].xyz[2] == 0.0 and by_name[names[2]].rpy_deg == (0, 0, 0)
        and hand.xyz[0] == hand.xyz[2] == 0.0
        and np.allclose(_origin(by_name[names[1]])[:3, 1], [0, 1, 0])
    )
    if not ok:
        raise ValueError(f"{side} arm chain does not have QTrobot's pitch-roll-roll structure; "
                         "the analytic IK cannot solve it")
    lower = np.array([model.joint(n).lower for n in names])
    upper = np.array([model.joint(n).upper for n in names])
    return _ArmGeometry(names, _origin(by_name[names[0]]), by_name[names[1]].xyz[1], by_name[names[2]].xyz[1],
                        hand.xyz[1], lower, upper)


def _arm_hand_local(g: _ArmGeometry, q: np.ndarray) -> np.ndarray:
    """Hand position in the pitch joint's zero frame, for angles q (radians)."""
    q1, q2, q3 = q
    z_r = np.array([-math.cos(q1), 0.0, math.sin(q1)])  # the roll frame's z after pitch q1
    y = np.array([0.0, 1.0, 0.0])
    u = g.offset + g.l1 * math.cos(q2) + g.l2 * math.cos(q2 + q3)
    v = g.l1 * math.sin(q2) + g.l2 * math.sin(q2 + q3)
    return u * y + v * z_r


def _arm_jacobian(g: _ArmGeometry, q: np.ndarray) -> np.ndarray:
    """d(hand position)/d(q), 3x3, same frame as _arm_hand_local."""
    q1, q2, q3 = q
    z_r = np.array([-math.cos(q1), 0.0, math.sin(q1)])
    dz_r = np.array([math.sin(q1), 0.0, math.cos(q1)])
    y = np.array([0.0, 1.0, 0.0])
    s2, c2, s23, c23 = math.sin(q2), math.cos(q2), math.sin(q2 + q3), math.cos(q2 + q3)
    v = g.l1 * s2 + g.l2 * s23
    j1 = v * dz_r
    j2 = (-g.l1 * s2 - g.l2 * s23) * y + (g.l1 * c2 + g.l2 * c23) * z_r
    j3 = (-g.l2 * s23) * y + (g.l2 * c23) * z_r
    return np.column_stack([j1, j2, j3])


def _planar_solutions(g: _ArmGeometry, p: np.ndarray) -> list[np.ndarray]:
    """All analytic (pitch, roll, elbow) in radians putting the hand at local point p (p assumed reachable)."""
    px, py, pz = p
    r = math.hypot(px, pz)
    u = py - g.offset
    d2 = u * u + r * r
    c3 = np.clip((d2 - g.l1**2 - g.l2**2) / (2 * g.l1 * g.l2), -1.0, 1.0)
    base = math.atan2(-pz, px) if r > 1e-12 else 0.0
    sols = []
    # Pitch `base` puts the target at in-plane coordinate v = -r; base +- pi at v = +r.
    for q1, v in ((base, -r), (base + math.pi, r), (base - math.pi, r)):
        for q3 in (-math.acos(c3), math.acos(c3)):
            q2 = math.atan2(v, u) - math.atan2(g.l2 * math.sin(q3), g.l1 + g.l2 * math.cos(q3))
            q2 = math.atan2(math.sin(q2), math.cos(q2))
            sols.append(np.array([q1, q2, q3]))
    return sols


def _clamp_to_reach(g: _ArmGeometry, p: np.ndarray) -> np.ndarray:
    """Move p, along its direction from the roll joint, into the shell the elbow's range can reach."""
    lo3, hi3 = g.lower[2], g.upper[2]
    # Reach d^2 = l1^2 + l2^2 + 2 l1 l2 cos q3 shrinks as |q3| grows on [0, pi]; the elbow range may or may not
    # include 0 (full extension), so find the extreme |q3| it allows.
    abs_lo = 0.0 if lo3 <= 0.0 <= hi3 else min(abs(lo3), abs(hi3))
    abs_hi = max(abs(lo3), abs(hi3))
    d_max = math.sqrt(g.l1**2 + g.l2**2 + 2 * g.l1 * g.l2 * math.cos(math.radians(abs_lo)))
    d_min = math.sqrt(g.l1**2 + g.l2**2 + 2 * g.l1 * g.l2 * math.cos(math.radians(min(abs_hi, 180.0))))
    centre = np.array([0.0, g.offset, 0.0])
    w = p - centre
    d = float(np.linalg.norm(w))
    if d < 1e-12:
        return centre + np.array([0.0, d_min, 0.0])
    if d > d_max:
        return centre + w * (d_max / d)
    if d < d_min:
        return centre + w * (d_min / d)
    return p


def _nearest_within_limits(g: _ArmGeometry, p: np.ndarray, q0: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                           iterations: int = 40) -> np.ndarray:
    """The angles within [lo, hi] whose hand comes nearest p: Levenberg-Marquardt projected onto the bounds.

    Three joints and an analytic Jacobian make this a few 3x3 solves; scipy's bounded least_squares gives the same
    answers but costs milliseconds per call in overhead, too much twice per 90 Hz frame (bench/teleop.py).
    """
    q = np.clip(q0, lo, hi)
    r = _arm_hand_local(g, q) - p
    cost = float(r @ r)
    damping = 1e-3
    for _ in range(iterations):
        jac = _arm_jacobian(g, q)
        # Joints at a bound that the gradient pushes further out cannot move: drop them from this step.
        grad = jac.T @ r
        free = ~(((q <= lo + 1e-12) & (grad > 0)) | ((q >= hi - 1e-12) & (grad < 0)))
        if not free.any():
            break
        jf = jac[:, free]
        step = np.zeros(3)
        step[free] = np.linalg.solve(jf.T @ jf + damping * np.eye(int(free.sum())), -jf.T @ r)
        trial = np.clip(q + step, lo, hi)
        r_trial = _arm_hand_local(g, trial) - p
        cost_trial = float(r_trial @ r_trial)
        if cost_trial < cost:
            converged = cost - cost_trial < 1e-14
            q, r, cost = trial, r_trial, cost_trial
            damping = max(damping / 3, 1e-9)
            if converged:
                break
        else:
            damping *= 4
            if damping > 1e6:
                break
    return q


def arm_ik(
    side: str,
    target_xyz: Sequence[float] | np.ndarray,
    model: RobotModel | None = None,
    *,
    prefer: Mapping[str, float] | None = None,
    tolerance_m: float = 1e-4,
) -> IKResult:
    """Arm angles putting the hand at `target_xyz` (base frame, metres).

    ShoulderRoll and ElbowRoll turn about parallel axes, so ShoulderPitch is chosen to put the target in their
    plane and the rest is a planar two-link problem (law of cosines). The roll joint sits 0.0445 m along the
    pitch axis, so the plane's origin is that joint and the two links are 0.07708 m and 0.184 m; lumping the
    offset into the first link (L1 = 0.1216 m) is exact only at ShoulderRoll 0. Out-of-reach targets are moved
    to the reachable shell along their direction from the roll joint. Of the analytic branches within the
    joint limits, the one nearest `prefer` (default: the home pose) wins; when none is within limits, a bounded
    bounded Levenberg-Marquardt search finds the nearest point the arm can reach. Angles are always within the limits.
    Pass `model` in a control loop: loading the packaged yaml on every call is wasteful.
    """
    model = model or load_qtrobot()
    g = _arm_geometry(model, side)
    target = np.asarray(target_xyz, dtype=float).reshape(3)
    if not np.all(np.isfinite(target)):
        raise ValueError(f"IK target must be 3 finite numbers, got {target.tolist()}")
    base_to_pitch = g.base_to_pitch
    p = (np.linalg.inv(base_to_pitch) @ np.append(target, 1.0))[:3]
    pref_deg = np.array([(prefer or {}).get(n, model.joint(n).home) for n in g.names])
    lo, hi = np.radians(g.lower), np.radians(g.upper)

    def wrap_into_limits(q: np.ndarray) -> np.ndarray:
        q = q.copy()
        for i in range(3):  # a revolute angle may be expressed +-2pi; use the representative within limits
            for k in (0.0, 2 * math.pi, -2 * math.pi):
                if lo[i] - 1e-9 <= q[i] + k <= hi[i] + 1e-9:
                    q[i] += k
                    break
        return q

    goal = _clamp_to_reach(g, p)
    candidates = [wrap_into_limits(q) for q in _planar_solutions(g, goal)]
    valid = [q for q in candidates if np.all(q >= lo - 1e-9) and np.all(q <= hi + 1e-9)]
    if valid:
        best = min(valid, key=lambda q: float(np.sum((np.degrees(q) - pref_deg) ** 2)))
        best = np.clip(best, lo, hi)
        # A branch within limits that reaches `goal` beats a search; check it really lands there.
        if np.linalg.norm(_arm_hand_local(g, best) - goal) > 1e-6:
            best = None
    else:
        best = None
    if best is None:
        # Search from the clipped branch landing nearest the target, and from the preferred pose when that is
        # no worse: enough to find the nearest reachable point in practice, at a bounded cost for 90 Hz control.
        def miss(q: np.ndarray) -> float:
            return float(np.linalg.norm(_arm_hand_local(g, q) - p))

        clipped = sorted((np.clip(q, lo, hi) for q in candidates), key=miss)
        preferred = np.clip(np.radians(pref_deg), lo, hi)
        starts = [clipped[0]] + ([preferred] if miss(preferred) < miss(clipped[0]) + 0.02 else [])
        fits = [_nearest_within_limits(g, p, x0, lo, hi) for x0 in starts]
        best = min(fits, key=miss)
    error = float(np.linalg.norm(_arm_hand_local(g, best) - p))
    angles = {n: float(math.degrees(a)) for n, a in zip(g.names, best)}
    angles = {n: model.clamp(n, a) for n, a in angles.items()}
    return IKResult(angles_deg=angles, reached=error <= tolerance_m, error_m=error)
