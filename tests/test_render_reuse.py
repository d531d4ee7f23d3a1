"""The render process's reuse of an unchanged view (simulated clock): a reused frame is the picture a fresh
render of the same state gives, pixel for pixel, and a change in view is drawn anew."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from robot_models import load_qtrobot
from sim.render_process import VisibleScene, _Worker
from sim.scene import build_classroom
from worker_process.frame_ring import FrameRing

ROBOT = load_qtrobot()
W, H = 320, 240


@pytest.fixture(scope="module")
def workers():
    model = build_classroom(ROBOT, antialias=0).model
    rings = [FrameRing.create(W, H), FrameRing.create(W, H)]
    reusing, fresh = (_Worker(model, W, H, (r.dup(), *r.spec()[1:]), reuse=reuse) for r, reuse in zip(rings, (True, False)))
    yield model, reusing, fresh, rings
    for w in (reusing, fresh):
        w.close()
    for r in rings:
        r.close()


def state(model, **degrees: float) -> tuple:
    qpos = np.zeros(model.nq)
    for name, value in {"HeadPitch": 18.0, **degrees}.items():  # looking down at the table, as the study does
        qpos[model.jnt_qposadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)]] = np.radians(value)
    return qpos, np.zeros(model.nv), 0.0


def test_a_reused_frame_is_the_fresh_render_of_its_state_and_a_new_view_is_drawn(workers):
    model, reusing, fresh, rings = workers
    assert reusing.visible is not None  # the classroom has no shadows or reflections: reuse applies
    poses = [{}, {}]  # the same state twice: the second is reused
    poses += [{"RightShoulderPitch": a} for a in (-60.0, -100.0, -140.0)]  # an arm moving out of view
    poses += [{"RightShoulderRoll": -75.0, "RightElbowRoll": -7.0}, {}]  # the right hand comes into view, leaves
    poses += [{"RightShoulderRoll": -75.0, "RightElbowRoll": -7.0}, {"RightShoulderRoll": -72.0, "RightElbowRoll": -7.0}]
    poses += [{"HeadYaw": 25.0}, {"HeadYaw": 25.0}, {}]  # a head turn changes the view; back again
    shown, reused = [], []
    for seq, pose in enumerate(poses, start=1):
        s = state(model, **pose)
        _, _, _, render_ms, _ = reusing.do_frame(s, None, seq)
        fresh.do_frame(s, None, seq)
        a, b = (ring.read(seq, np.copy) for ring in rings)
        assert np.array_equal(a, b), f"frame {seq} ({pose}) differs from a fresh render of its state"
        shown.append(a)
        reused.append(render_ms == 0.0)
    assert not reused[8] and not np.array_equal(shown[8], shown[7]), "a hand moving in view was not drawn"
    assert reused[1] and reused[10], "the same state again was drawn anew"
    assert not reused[9] and not np.array_equal(shown[9], shown[8]), "a head turn was not drawn"
    assert not reused[11]  # back from the turn: a view unlike the last one
    assert any(reused[3:5]), "an arm moving out of view was drawn anew each time"
    assert not reused[5] and not reused[6] and not np.array_equal(shown[5], shown[4]), "a hand in view was not drawn"


def test_a_new_face_is_drawn_on_the_next_frame(workers):
    model, reusing, _fresh, _rings = workers
    s = state(model)
    reusing.do_frame(s, None, 100)
    assert reusing.do_frame(s, None, 101)[3] == 0.0
    reusing.do_face("happy", None, None)
    assert reusing.do_frame(s, None, 102)[3] > 0.0


def test_no_reuse_where_an_unseen_geom_could_change_a_pixel():
    assert VisibleScene.of(build_classroom(ROBOT, antialias=0, shadows=True).model, W, H) is None
