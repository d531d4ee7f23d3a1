"""Modelled perception (features/modelled_faces.py): the pupils' face boxes computed from the stand-in's scene agree
with the real detector on frames the stand-in's render process draws of the same scene, within what the
calibration (features/data/face_recall.json, bench/faces.py --calibrate) says the detector does."""

from __future__ import annotations

import math
from pathlib import Path

import mujoco
import numpy as np
import pytest

from client_protocol import names
from robot_models import load_qtrobot
from sim.pupils import AWAY_DEG, neck_joint
from sim.render_process import RenderProcess
from sim.scene import build_classroom
from simclock import SimulatedClock
from simclock import run as run_on_clock
from testbed.faces import Head, matches
from vr_teleop_server.features.faces import FaceDetector
from vr_teleop_server.features.modelled_faces import ModelledDetector, RecallTable, SceneFaces
from vr_teleop_server.study.kinds import load_study
from vr_teleop_server.tools.study_runner import run_trial

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "classroom.yaml"

WIDTH, HEIGHT = 640, 480
# (HeadYaw, HeadPitch) in degrees and the pupils looking away: the head turned to each side and to the middle,
# level and a little down, every pupil facing the robot, then two of them turned away (the back of their heads).
POSES = [(yaw, pitch, ()) for yaw in (-22.0, 0.0, 22.0) for pitch in (0.0, 6.0)] + [
    (0.0, 0.0, ("child_left", "adult_centre")), (-15.0, 0.0, ("child_right",)), (15.0, 3.0, ("adult_centre",))]


@pytest.fixture(scope="module")
def scene():
    model = build_classroom(load_qtrobot(), antialias=0, offscreen_size=(1280, 720)).model
    renderer = RenderProcess(model, WIDTH, HEIGHT, nice=0)
    yield model, renderer
    renderer.close(RenderProcess.REPLY_TIMEOUT_S)


def pose(model: mujoco.MjModel, yaw: float, pitch: float, away: tuple[str, ...]) -> np.ndarray:
    qpos = mujoco.MjData(model).qpos.copy()
    for joint, deg in [("HeadYaw", yaw), ("HeadPitch", pitch), *((neck_joint(p), AWAY_DEG) for p in away)]:
        qpos[model.jnt_qposadr[mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, joint)]] = math.radians(deg)
    return qpos


def at_least(probabilities: list[float], k: int) -> float:
    """P(at least k of independent events with these probabilities happen): a Poisson binomial's tail."""
    dist = np.zeros(len(probabilities) + 1)
    dist[0] = 1.0
    for p in probabilities:
        dist[1:] = dist[1:] * (1 - p) + dist[:-1] * p
        dist[0] *= 1 - p
    return float(dist[k:].sum())


def box_iou(a: tuple[int, int, int, int], b) -> float:
    x0, y0 = max(a[0], b.x), max(a[1], b.y)
    x1, y1 = min(a[0] + a[2], b.x + b.width), min(a[1] + a[3], b.y + b.height)
    inter = max(0, x1 - x0) * max(0, y1 - y0)
    return inter / (a[2] * a[3] + b.width * b.height - inter)


def test_modelled_boxes_agree_with_the_detector_on_rendered_frames_of_the_stand_in(scene):
    model, renderer = scene
    table = RecallTable.load()
    modelled = SceneFaces(model, WIDTH, HEIGHT, table)
    detector = FaceDetector()
    misses: list[float] = []  # the calibrated probability of a miss, for every face the model sees
    missed = 0
    ious: list[float] = []
    outcomes: dict[str, int] = {}
    unexplained = []
    for yaw, pitch, away in POSES:
        qpos = pose(model, yaw, pitch, away)
        jpeg, *_ = renderer.frame((qpos, np.zeros(model.nv), 0.0), 80)
        faces, size = detector.detect_jpeg(jpeg)
        assert size == (WIDTH, HEIGHT)
        views = modelled.look(qpos)
        seen = []
        for v in views:
            outcomes[v.seen.split(" by ")[0]] = outcomes.get(v.seen.split(" by ")[0], 0) + 1
            if v.seen != "visible":
                continue
            head = Head(v.name, v.u, v.v, v.diameter_px, v.turned_deg, whole=True)
            real = [f for f in faces if matches(head, f)]
            misses.append(1.0 - v.recall)
            missed += not real
            if real:
                seen.extend(real)
                ious.append(max(box_iou(modelled.box(v), f) for f in real))
        # a box on no face the model sees: on a face it calls hidden, or a false positive
        unexplained += [(yaw, pitch, away, f) for f in faces if f not in seen]
    # every kind of face the poses were chosen to show: in view, out of the frame, turned away (recall near 0)
    assert outcomes.get("visible", 0) >= 15 and outcomes.get("out of the frame", 0) >= 2, outcomes
    assert len(misses) == outcomes["visible"]
    # The detector missed no more of the faces the model sees than the calibrated recall makes plausible
    # (the chance of at least this many misses is over 1 in 1000).
    assert at_least(misses, missed) > 1e-3, (missed, [round(m, 3) for m in misses])
    # Where both found a face, the modelled box overlaps the detector's at least as well as the worst of the
    # calibration's (its boxes, placed by the medians, against the detector's on the calibration's pictures).
    assert ious and min(ious) >= table.box_iou["min"], (min(ious), table.box_iou)
    # The detector finds no face the model hides (out of the frame, turned away, occluded) beyond its calibrated
    # false positives: at most as many as a Poisson count of that rate over these frames reaches 999 times in 1000.
    rate = table.measured["false_positives_per_frame"] * len(POSES)
    assert len(unexplained) <= poisson_999(rate), unexplained


def poisson_999(rate: float) -> int:
    k, term, total = 0, math.exp(-rate), math.exp(-rate)
    while total < 0.999:
        k += 1
        term *= rate / k
        total += term
    return k


def test_the_modelled_detector_is_seeded(scene):
    """The same seed gives the same boxes over the same scenes (a lesson's seed makes its perception too)."""
    model, _ = scene
    scenes = [pose(model, yaw, 0.0, ()) for yaw in np.linspace(-25, 25, 40)]

    def run(seed: int) -> list:
        d = ModelledDetector(model, WIDTH, HEIGHT, seed=seed)
        return [d.detect(q) for q in scenes]

    first = run(7)
    assert first == run(7)
    assert all(f.width > 0 and 0 < f.confidence <= 1 for frame in first for f in frame)
    assert sum(map(len, first)) >= 2 * len(scenes)  # at least two of the three pupils in view, mostly found


def test_a_modelled_lesson_publishes_the_detector_s_messages_and_draws_no_frame(tmp_path):
    """A study file's `perception: modelled` reaches the lesson's server: /perception/faces carries the modelled
    detector's boxes at the camera's rate while autonomy watches, and the head camera draws nothing."""
    study = load_study(EXAMPLE).model_copy(update={"perception": "modelled", "lesson_s": 6.0})
    heard: list[dict] = []
    servers = []

    def on_server(server) -> None:
        servers.append(server)
        server.bus.subscribe("test", names.FACES_TOPIC, "vr_teleop_msgs/Faces", lambda p: heard.append(p.data))

    clock = SimulatedClock()
    report = run_on_clock(run_trial(study, "supervised", clock=clock, seed=3, on_server=on_server), clock)
    assert report.outcome == "completed"
    (server,) = servers
    assert server.faces.perception.name == "modelled:centerface"
    assert server.robot.standin.latest_frame() is None  # no frame drawn: nobody watched the camera
    assert len(heard) >= study.lesson_s * study.camera_fps - 1, len(heard)
    assert all(m["detector"] == "modelled:centerface" and (m["image_width"], m["image_height"]) == (640, 480)
               for m in heard)
    assert any(m["faces"] for m in heard)  # the robot faces the class: pupils in view, found


@pytest.mark.parametrize("settings, named", [
    ({"backend": "ros", "perception": "modelled"}, "it needs --backend sim"),
    ({"perception": "modelled", "blur_faces": True}, "it needs --perception rendered"),
])
def test_modelled_perception_is_refused_where_there_is_no_scene_or_frames_are_needed(settings, named):
    from pydantic import ValidationError

    from vr_teleop_server.settings import ServerSettings

    with pytest.raises(ValidationError, match=named):
        ServerSettings(**settings)
