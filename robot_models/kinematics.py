"""Forward kinematics of QTrobot's URDF chain and an analytic inverse for each 3-joint arm.

Angles are degrees at this module's boundary (as the robot API uses them) and radians inside.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from .qtrobot import ChainElement, RobotModel, load_qtrobot

SIDES = ("left", "right")
_TWO_PI = 2 * math.pi


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


class ArmSolver:
    """One arm's inverse kinematics, with the chain's constants read once; plain floats throughout.

    The control loop solves twice per 90 Hz frame, so everything per call is scalar arithmetic on Python floats:
    NumPy's per-call overhead on 3-vectors (microseconds each) was most of the cost (bench/teleop.py).

    ShoulderRoll and ElbowRoll turn about parallel axes, so ShoulderPitch is chosen to put the target in their
    plane and the rest is a planar two-link problem (law of cosines). The roll joint sits 0.0445 m along the
    pitch axis, so the plane's origin is that joint and the two links are 0.07708 m and 0.184 m; lumping the
    offset into the first link (L1 = 0.1216 m) is exact only at ShoulderRoll 0. Out-of-reach targets are moved
    to the reachable shell along their direction from the roll joint. Of the analytic branches within the
    joint limits, the one nearest `prefer` (default: the home pose) wins; when none is within limits, a bounded
    Levenberg-Marquardt search finds the nearest point the arm can reach. Angles are always within the limits.
    """

    __slots__ = ("side", "names", "_rot", "_trans", "offset", "l1", "l2", "lower", "upper", "_lo_deg", "_hi_deg",
                 "_home", "_d_min", "_d_max")

    def __init__(self, model: RobotModel, side: str) -> None:
        if side not in SIDES:
            raise ValueError(f"arm side must be 'left' or 'right', got {side!r}")
        prefix = side.capitalize()
        names = (f"{prefix}ShoulderPitch", f"{prefix}ShoulderRoll", f"{prefix}ElbowRoll")
        by_name = {el.name: el for el in model.chain}
        hand = next(el for el in model.chain if el.parent == names[2] and el.type == "fixed")
        # The solver assumes the URDF's structure (pitch about y; roll and elbow about parallel axes, links along
        # y); check it so that a changed yaml fails loudly instead of giving wrong angles.
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
        base_to_pitch = _origin(by_name[names[0]])  # pitch joint frame at angle 0
        self.side = side
        self.names = names
        self._rot = tuple(float(v) for v in base_to_pitch[:3, :3].ravel())  # row-major
        self._trans = tuple(float(v) for v in base_to_pitch[:3, 3])
        self.offset = float(by_name[names[1]].xyz[1])  # roll joint's distance along the pitch axis
        self.l1 = float(by_name[names[2]].xyz[1])  # roll joint -> elbow
        self.l2 = float(hand.xyz[1])  # elbow -> hand
        joints = [model.joint(n) for n in names]
        self._lo_deg = tuple(float(j.lower) for j in joints)
        self._hi_deg = tuple(float(j.upper) for j in joints)
        self._home = tuple(float(j.home) for j in joints)
        self.lower = tuple(math.radians(v) for v in self._lo_deg)
        self.upper = tuple(math.radians(v) for v in self._hi_deg)
        # Reach d^2 = l1^2 + l2^2 + 2 l1 l2 cos q3 shrinks as |q3| grows on [0, pi]; the elbow range may or may not
        # include 0 (full extension), so find the extreme |q3| it allows.
        lo3, hi3 = self._lo_deg[2], self._hi_deg[2]
        abs_lo = 0.0 if lo3 <= 0.0 <= hi3 else min(abs(lo3), abs(hi3))
        abs_hi = max(abs(lo3), abs(hi3))
        l1, l2 = self.l1, self.l2
        self._d_max = math.sqrt(l1 * l1 + l2 * l2 + 2 * l1 * l2 * math.cos(math.radians(abs_lo)))
        self._d_min = math.sqrt(l1 * l1 + l2 * l2 + 2 * l1 * l2 * math.cos(math.radians(min(abs_hi, 180.0))))

    # ----- the arm's geometry in the pitch joint's zero frame (radians) -----------------------------------------
    def to_local(self, x: float, y: float, z: float) -> tuple[float, float, float]:
        """A base-frame point in the pitch joint's zero frame."""
        r, t = self._rot, self._trans
        dx, dy, dz = x - t[0], y - t[1], z - t[2]
        return (r[0] * dx + r[3] * dy + r[6] * dz, r[1] * dx + r[4] * dy + r[7] * dz, r[2] * dx + r[5] * dy + r[8] * dz)

    def hand_local(self, q1: float, q2: float, q3: float) -> tuple[float, float, float]:
        """Hand position in the pitch joint's zero frame: u along the pitch axis (y), v along the roll frame's z,
        which pitch q1 turns to (-cos q1, 0, sin q1)."""
        l1, l2 = self.l1, self.l2
        u = self.offset + l1 * math.cos(q2) + l2 * math.cos(q2 + q3)
        v = l1 * math.sin(q2) + l2 * math.sin(q2 + q3)
        return (-v * math.cos(q1), u, v * math.sin(q1))

    def _miss(self, q: tuple[float, float, float], p: tuple[float, float, float]) -> float:
        h = self.hand_local(*q)
        return math.sqrt((h[0] - p[0]) ** 2 + (h[1] - p[1]) ** 2 + (h[2] - p[2]) ** 2)

    def planar_solutions(self, p: tuple[float, float, float]) -> list[tuple[float, float, float]]:
        """All analytic (pitch, roll, elbow) in radians putting the hand at local point p (p assumed reachable)."""
        px, py, pz = p
        l1, l2 = self.l1, self.l2
        r = math.hypot(px, pz)
        u = py - self.offset
        d2 = u * u + r * r
        c3 = min(max((d2 - l1 * l1 - l2 * l2) / (2 * l1 * l2), -1.0), 1.0)
        base = math.atan2(-pz, px) if r > 1e-12 else 0.0
        a3 = math.acos(c3)
        sols = []
        # Pitch `base` puts the target at in-plane coordinate v = -r; base +- pi at v = +r.
        for q1, v in ((base, -r), (base + math.pi, r), (base - math.pi, r)):
            for q3 in (-a3, a3):
                q2 = math.atan2(v, u) - math.atan2(l2 * math.sin(q3), l1 + l2 * math.cos(q3))
                sols.append((q1, math.atan2(math.sin(q2), math.cos(q2)), q3))
        return sols

    def clamp_to_reach(self, p: tuple[float, float, float]) -> tuple[float, float, float]:
        """Move p, along its direction from the roll joint, into the shell the elbow's range can reach."""
        wx, wy, wz = p[0], p[1] - self.offset, p[2]
        d = math.sqrt(wx * wx + wy * wy + wz * wz)
        if d < 1e-12:
            return (0.0, self.offset + self._d_min, 0.0)
        if d > self._d_max:
            k = self._d_max / d
        elif d < self._d_min:
            k = self._d_min / d
        else:
            return p
        return (wx * k, self.offset + wy * k, wz * k)

    def candidates(self, goal: tuple[float, float, float]) -> list[tuple[float, float, float]]:
        """The analytic solutions for `goal`, each angle as its representative (+-2pi) within the limits if any."""
        lo, hi = self.lower, self.upper
        out = []
        for q in self.planar_solutions(goal):
            w = []
            for a, low, high in zip(q, lo, hi):
                if not low - 1e-9 <= a <= high + 1e-9:
                    if low - 1e-9 <= a + _TWO_PI <= high + 1e-9:
                        a += _TWO_PI
                    elif low - 1e-9 <= a - _TWO_PI <= high + 1e-9:
                        a -= _TWO_PI
                w.append(a)
            out.append((w[0], w[1], w[2]))
        return out

    def clip(self, q: Sequence[float]) -> tuple[float, float, float]:
        """q (radians) moved into the joint limits."""
        lo, hi = self.lower, self.upper
        return (min(max(q[0], lo[0]), hi[0]), min(max(q[1], lo[1]), hi[1]), min(max(q[2], lo[2]), hi[2]))

    def nearest_within_limits(self, p: tuple[float, float, float], q0: Sequence[float],
                              iterations: int = 40) -> tuple[float, float, float]:
        """The angles within the limits whose hand comes nearest p: Levenberg-Marquardt projected onto the bounds.

        Three joints and an analytic Jacobian make this a few 3x3 solves (Cramer's rule); scipy's bounded
        least_squares gives the same answers but costs milliseconds per call in overhead.
        """
        lo0, lo1, lo2 = self.lower
        hi0, hi1, hi2 = self.upper
        l1, l2, offset = self.l1, self.l2, self.offset
        px, py, pz = p
        cos, sin = math.cos, math.sin
        # Scalars throughout (3x3 sums written out, the solve by Cramer's rule, hand_local and clip inlined): in
        # lists and comprehensions each iteration cost several times its arithmetic, and the replay at --speed max
        # runs this a few thousand times a minute of session.
        q1, q2, q3 = self.clip(q0)
        u = offset + l1 * cos(q2) + l2 * cos(q2 + q3)
        v = l1 * sin(q2) + l2 * sin(q2 + q3)
        r0, r1, r2 = -v * cos(q1) - px, u - py, v * sin(q1) - pz
        cost = r0 * r0 + r1 * r1 + r2 * r2
        damping = 1e-3
        for _ in range(iterations):
            c1, s1 = cos(q1), sin(q1)
            s2, c2, s23, c23 = sin(q2), cos(q2), sin(q2 + q3), cos(q2 + q3)
            v = l1 * s2 + l2 * s23
            a, b = l1 * c2 + l2 * c23, l2 * c23
            # Jacobian columns j0, j1, j2
            j00, j01, j02 = v * s1, 0.0, v * c1
            j10, j11, j12 = -a * c1, -v, a * s1
            j20, j21, j22 = -b * c1, -l2 * s23, b * s1
            g0 = j00 * r0 + j01 * r1 + j02 * r2
            g1 = j10 * r0 + j11 * r1 + j12 * r2
            g2 = j20 * r0 + j21 * r1 + j22 * r2
            # Joints at a bound that the gradient pushes further out cannot move: drop them from this step.
            f0 = not ((q1 <= lo0 + 1e-12 and g0 > 0) or (q1 >= hi0 - 1e-12 and g0 < 0))
            f1 = not ((q2 <= lo1 + 1e-12 and g1 > 0) or (q2 >= hi1 - 1e-12 and g1 < 0))
            f2 = not ((q3 <= lo2 + 1e-12 and g2 > 0) or (q3 >= hi2 - 1e-12 and g2 < 0))
            if not (f0 or f1 or f2):
                break
            # The damped normal equations, rows and columns of fixed joints replaced by the identity's.
            m00 = (j00 * j00 + j01 * j01 + j02 * j02) + damping if f0 else 1.0
            m11 = (j10 * j10 + j11 * j11 + j12 * j12) + damping if f1 else 1.0
            m22 = (j20 * j20 + j21 * j21 + j22 * j22) + damping if f2 else 1.0
            m01 = (j00 * j10 + j01 * j11 + j02 * j12) if f0 and f1 else 0.0
            m10 = (j10 * j00 + j11 * j01 + j12 * j02) if f0 and f1 else 0.0
            m02 = (j00 * j20 + j01 * j21 + j02 * j22) if f0 and f2 else 0.0
            m20 = (j20 * j00 + j21 * j01 + j22 * j02) if f0 and f2 else 0.0
            m12 = (j10 * j20 + j11 * j21 + j12 * j22) if f1 and f2 else 0.0
            m21 = (j20 * j10 + j21 * j11 + j22 * j12) if f1 and f2 else 0.0
            b0, b1, b2 = -g0 if f0 else 0.0, -g1 if f1 else 0.0, -g2 if f2 else 0.0
            e_i = m11 * m22 - m12 * m21
            d_i = m10 * m22 - m12 * m20
            d_h = m10 * m21 - m11 * m20
            det = m00 * e_i - m01 * d_i + m02 * d_h
            t1 = q1 + (b0 * e_i - m01 * (b1 * m22 - m12 * b2) + m02 * (b1 * m21 - m11 * b2)) / det
            t2 = q2 + (m00 * (b1 * m22 - m12 * b2) - b0 * d_i + m02 * (m10 * b2 - b1 * m20)) / det
            t3 = q3 + (m00 * (m11 * b2 - b1 * m21) - m01 * (m10 * b2 - b1 * m20) + b0 * d_h) / det
            t1 = min(max(t1, lo0), hi0)
            t2 = min(max(t2, lo1), hi1)
            t3 = min(max(t3, lo2), hi2)
            u = offset + l1 * cos(t2) + l2 * cos(t2 + t3)
            v = l1 * sin(t2) + l2 * sin(t2 + t3)
            rt0, rt1, rt2 = -v * cos(t1) - px, u - py, v * sin(t1) - pz
            cost_trial = rt0 * rt0 + rt1 * rt1 + rt2 * rt2
            if cost_trial < cost:
                converged = cost - cost_trial < 1e-14
                q1, q2, q3, r0, r1, r2, cost = t1, t2, t3, rt0, rt1, rt2, cost_trial
                damping = max(damping / 3, 1e-9)
                if converged:
                    break
            else:
                damping *= 4
                if damping > 1e6:
                    break
        return (q1, q2, q3)

    # ----- the solve ----------------------------------------------------------------------------------------------
    def closed_form(self, candidates: list[tuple[float, float, float]], goal: tuple[float, float, float],
                    prefer_deg: Sequence[float]) -> tuple[float, float, float] | None:
        """The candidate within limits nearest `prefer_deg` that lands on `goal` (the target moved into reach), or
        None."""
        lo, hi = self.lower, self.upper
        best, best_d = None, math.inf
        for q in candidates:
            if all(lo[i] - 1e-9 <= q[i] <= hi[i] + 1e-9 for i in range(3)):
                d = sum((math.degrees(q[i]) - prefer_deg[i]) ** 2 for i in range(3))
                if d < best_d:
                    best, best_d = q, d
        if best is None:
            return None
        best = self.clip(best)
        # A branch within limits that reaches `goal` beats a search; check it really lands there.
        return best if self._miss(best, goal) <= 1e-6 else None

    def fallback(self, candidates: list[tuple[float, float, float]], p: tuple[float, float, float],
                 prefer_deg: Sequence[float]) -> tuple[float, float, float]:
        """The bounded search: from the clipped candidate landing nearest p, and from the preferred pose when that
        is no worse; enough to find the nearest reachable point in practice, at a bounded cost for 90 Hz control."""
        clipped = min((self.clip(q) for q in candidates), key=lambda q: self._miss(q, p))
        preferred = self.clip([math.radians(a) for a in prefer_deg])
        starts = [clipped] + ([preferred] if self._miss(preferred, p) < self._miss(clipped, p) + 0.02 else [])
        return min((self.nearest_within_limits(p, x0) for x0 in starts), key=lambda q: self._miss(q, p))

    def solve(self, x: float, y: float, z: float, prefer_deg: Sequence[float] | None = None
              ) -> tuple[tuple[float, float, float], float]:
        """(pitch, roll, elbow) in degrees within the limits putting the hand at base-frame (x, y, z) metres, or
        as near as the arm gets; and the hand's distance from the target (m)."""
        if not (math.isfinite(x) and math.isfinite(y) and math.isfinite(z)):
            raise ValueError(f"IK target must be 3 finite numbers, got {[x, y, z]}")
        prefer = self._home if prefer_deg is None else prefer_deg
        p = self.to_local(x, y, z)
        goal = self.clamp_to_reach(p)
        candidates = self.candidates(goal)
        best = self.closed_form(candidates, goal, prefer)
        if best is None:
            best = self.fallback(candidates, p, prefer)
        lo, hi = self._lo_deg, self._hi_deg
        angles = tuple(min(max(math.degrees(best[i]), lo[i]), hi[i]) for i in range(3))
        return (angles[0], angles[1], angles[2]), self._miss(best, p)


def arm_ik(
    side: str,
    target_xyz: Sequence[float] | np.ndarray,
    model: RobotModel | None = None,
    *,
    prefer: Mapping[str, float] | None = None,
    tolerance_m: float = 1e-4,
) -> IKResult:
    """Arm angles putting the hand at `target_xyz` (base frame, metres); see ArmSolver for the method.

    Builds the arm's solver on each call: a control loop should keep an ArmSolver per arm instead.
    """
    model = model or load_qtrobot()
    solver = ArmSolver(model, side)
    target = np.asarray(target_xyz, dtype=float).reshape(3)
    if not np.all(np.isfinite(target)):
        raise ValueError(f"IK target must be 3 finite numbers, got {target.tolist()}")
    pref = None if prefer is None else [prefer.get(n, model.joint(n).home) for n in solver.names]
    angles, error = solver.solve(float(target[0]), float(target[1]), float(target[2]), pref)
    return IKResult(angles_deg=dict(zip(solver.names, angles)), reached=error <= tolerance_m, error_m=error)
