"""The arm IK's two halves checked against each other over the workspace: the closed form (law of cosines on the
two parallel roll joints) and the bounded Levenberg-Marquardt fallback, both as the control loop runs them
(robot_models.ArmSolver, plain floats), and both against forward kinematics."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from robot_models import ArmSolver, forward_kinematics, load_qtrobot

MODEL = load_qtrobot()
SOLVERS = {side: ArmSolver(MODEL, side) for side in ("left", "right")}
ZERO = forward_kinematics(MODEL, {})


def hand_of(side, angles_deg):
    """The hand in the base frame by the URDF chain (not by the solver's own formula)."""
    return forward_kinematics(MODEL, dict(zip(SOLVERS[side].names, angles_deg)))[f"{side}_hand"][:3, 3]


def shell_distance(solver, p):
    """How far local point p lies outside the shell of distances from the roll joint the elbow's range allows:
    no angles within the limits bring the hand nearer than this."""
    d = math.dist(p, (0.0, solver.offset, 0.0))
    lo3, hi3 = solver.lower[2], solver.upper[2]
    reach = [math.sqrt(solver.l1 ** 2 + solver.l2 ** 2 + 2 * solver.l1 * solver.l2 * math.cos(a))
             for a in np.linspace(lo3, hi3, 2001)]
    return max(0.0, d - max(reach), min(reach) - d)


def within_limits(solver, q):
    return all(lo - 1e-12 <= a <= hi + 1e-12 for a, lo, hi in zip(q, solver.lower, solver.upper))


@st.composite
def reachable(draw):
    side = draw(st.sampled_from(["left", "right"]))
    s = SOLVERS[side]
    q = [draw(st.floats(math.degrees(lo), math.degrees(hi))) for lo, hi in zip(s.lower, s.upper)]
    return side, q


@settings(max_examples=300, deadline=None)
@given(reachable(), st.tuples(*[st.floats(-10.0, 10.0)] * 3))
def test_reachable_targets_closed_form_lands_and_the_search_agrees(pose, nudge_deg):
    """Within the workspace the closed form lands on the target (checked by the URDF's FK), and the fallback search
    started a few degrees away from it comes back to the target: the two agree where both apply."""
    side, q = pose
    s = SOLVERS[side]
    target = hand_of(side, q)
    p = s.to_local(*map(float, target))
    candidates = s.candidates(s.clamp_to_reach(p))
    q_cf = s.closed_form(candidates, s.clamp_to_reach(p), q)
    assert q_cf is not None and within_limits(s, q_cf)
    assert np.linalg.norm(hand_of(side, [math.degrees(a) for a in q_cf]) - target) < 1e-6
    start = s.clip([a + math.radians(n) for a, n in zip(q_cf, nudge_deg)])
    q_lm = s.nearest_within_limits(p, start)
    assert within_limits(s, q_lm)
    assert np.linalg.norm(hand_of(side, [math.degrees(a) for a in q_lm]) - target) < 1e-4


@settings(max_examples=300, deadline=None)
@given(st.sampled_from(["left", "right"]), st.tuples(*[st.floats(-0.45, 0.45)] * 3))
def test_any_target_closed_form_is_never_beaten_by_the_search(side, offset):
    """Any target around the shoulder, reachable or not: when the closed form answers, its hand is the nearest any
    angles within the limits can get (the reach shell bounds every answer from below) and no search start does
    better; when it does not, the fallback stays within the limits and its reported error is FK's."""
    s = SOLVERS[side]
    target = ZERO[f"{side.capitalize()}ShoulderRoll"][:3, 3] + np.array(offset)
    p = s.to_local(*map(float, target))
    goal = s.clamp_to_reach(p)
    candidates = s.candidates(goal)
    q_cf = s.closed_form(candidates, goal, [MODEL.joint(n).home for n in s.names])
    floor = shell_distance(s, p)
    angles, error = s.solve(*map(float, target))
    assert within_limits(s, [math.radians(a) for a in angles])
    assert error == pytest.approx(float(np.linalg.norm(hand_of(side, angles) - target)), abs=1e-9)
    assert error >= floor - 1e-6
    if q_cf is not None:
        assert error == pytest.approx(floor, abs=1e-6)  # on the shell, radially: nothing can be nearer
        for start in [*candidates, [math.radians(MODEL.joint(n).home) for n in s.names]]:
            q_lm = s.nearest_within_limits(p, start)
            assert math.dist(s.hand_local(*q_lm), p) >= error - 1e-9


def test_solver_matches_arm_ik_and_refuses_bad_targets():
    from robot_models import arm_ik

    s = SOLVERS["left"]
    target = (0.1, 0.25, 0.3)
    angles, error = s.solve(*target)
    r = arm_ik("left", target, MODEL)
    assert tuple(r.angles_deg[n] for n in s.names) == angles and r.error_m == error
    with pytest.raises(ValueError, match="finite"):
        s.solve(0.0, math.inf, 0.0)
    with pytest.raises(ValueError, match="left"):
        ArmSolver(MODEL, "middle")
