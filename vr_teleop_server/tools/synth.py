"""Fake headsets: operator sessions synthesised at 90 Hz, written as recordings that `vr-teleop replay` plays.

Motion is a chain of minimum-jerk moves (the smooth bell-shaped velocity of human reaching), with tracking noise
(about 1 mm of position and 0.2 degrees of orientation) and a slight sway at rest. Poses are in Unity's frame
(frame_id "unity_left_handed": left-handed, y up, z forward, metres), as a Quest reports them; the operator stands at the
origin facing +z with the eyes at 1.62 m. Every session starts by streaming, then engaging control through
/vr_teleop/control/engage; arms move only while their grip is held.

Scenarios: look-around (head sweeps to and past the robot's limits), nod, wave (right arm), both-arms,
menu-tour (every menu item selected once, through /vr_teleop/menu/select), classroom (a 5-minute mix).
"""

from __future__ import annotations

import bisect
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from client_protocol import names
from client_protocol.registry import TypeRegistry
from menus import load_menus
from robot_models import load_qtrobot

from ..core.bus import SERVER_NODE, Bus
from ..robot.gestures import GestureLibrary, packaged_gesture_dir
from ..features.menu_service import MenuService
from ..recording.format import SESSION_METADATA
from ..recording.recorder import Recorder

RATE = 90.0
JOY_EVERY = 3  # Joy at 30 Hz
EYE = np.array([0.0, 1.62, 0.0])
SHOULDER_DROP = 0.22
SHOULDER_HALF = 0.19
CLIENT = "synth"
TOGGLES = ("motion.record", "motion.arms", "motion.head")  # selected twice, to leave things as found
SCENARIOS = ("look-around", "nod", "wave", "both-arms", "menu-tour", "classroom")


def min_jerk(s: np.ndarray) -> np.ndarray:
    s = np.clip(s, 0.0, 1.0)
    return s ** 3 * (10 - 15 * s + 6 * s * s)


@dataclass
class Track:
    """A piecewise minimum-jerk trajectory of a vector, built move by move."""

    start: np.ndarray
    moves: list[tuple[float, float, np.ndarray, np.ndarray]] = field(default_factory=list)  # t0, t1, from, to
    _cache: list[float] = field(default_factory=list, repr=False)

    def __post_init__(self) -> None:
        self.start = np.asarray(self.start, dtype=float)

    @property
    def end(self) -> np.ndarray:
        return self.moves[-1][3] if self.moves else self.start

    @property
    def end_time(self) -> float:
        return self.moves[-1][1] if self.moves else 0.0

    def move(self, to, duration: float, at: float | None = None) -> float:
        t0 = self.end_time if at is None else max(at, self.end_time)
        self.moves.append((t0, t0 + duration, self.end, np.asarray(to, dtype=float)))
        return t0 + duration

    def hold(self, duration: float) -> float:
        return self.move(self.end, duration)

    def __call__(self, t: float) -> np.ndarray:
        i = bisect.bisect_right(self._starts(), t) - 1
        if i < 0:
            return self.start
        t0, t1, a, b = self.moves[i]
        return a + (b - a) * float(min_jerk(np.array((t - t0) / (t1 - t0))))

    def _starts(self) -> list[float]:
        """Move start times, for bisecting (moves are only ever appended)."""
        if len(self._cache) != len(self.moves):
            self._cache = [m[0] for m in self.moves]
        return self._cache


@dataclass
class Session:
    """What the operator does: head yaw/pitch (degrees, + = left/up), hand positions relative to the shoulder
    (metres, Unity axes), grips (0..1), and timed service calls."""

    head: Track = field(default_factory=lambda: Track(np.zeros(2)))
    hands: dict[str, Track] = field(default_factory=lambda: {
        "left": Track(np.array([0.0, -0.55, 0.1])), "right": Track(np.array([0.0, -0.55, 0.1]))})
    grips: dict[str, list[tuple[float, float]]] = field(default_factory=lambda: {"left": [], "right": []})
    calls: list[tuple[float, str, str, dict]] = field(default_factory=list)  # time, service, type, args

    def grip(self, side: str, t0: float, t1: float) -> None:
        self.grips[side].append((t0, t1))

    def call(self, t: float, service: str, type_name: str, args: dict) -> None:
        self.calls.append((t, service, type_name, args))

    @property
    def duration(self) -> float:
        ends = [self.head.end_time, *(h.end_time for h in self.hands.values()),
                *(c[0] + 1.0 for c in self.calls)]
        return max(ends) + 0.5


# ---- scenarios ----------------------------------------------------------------------------------------------------
def _engaged() -> Session:
    s = Session()
    s.head.hold(1.0)  # grips are pressed only after engaging: a grip held while engaging must be pressed anew
    s.call(0.5, names.ENGAGE_SERVICE, "std_srvs/SetBool", {"data": True})
    return s


def look_around(s: Session, rng: np.random.Generator) -> None:
    for yaw, pitch in ((40, 0), (75, 10), (0, 0), (-40, -5), (-75, -20), (0, 30), (0, -30), (0, 0)):
        s.head.move((yaw + rng.normal(0, 2), pitch + rng.normal(0, 1)), 1.2 + abs(yaw) / 100)
        s.head.hold(0.3)


def nod(s: Session, rng: np.random.Generator) -> None:
    yaw = float(s.head.end[0])
    for _ in range(3):
        s.head.move((yaw, -18 + rng.normal(0, 1)), 0.35)
        s.head.move((yaw, 6 + rng.normal(0, 1)), 0.35)
    s.head.move((yaw, 0), 0.4)


def wave(s: Session, rng: np.random.Generator, side: str = "right") -> None:
    hand = s.hands[side]
    sign = 1 if side == "right" else -1
    t0 = max(hand.end_time, s.head.end_time)
    hand.move((sign * 0.25, 0.25, 0.25), 1.0, at=t0)  # raise beside the head
    s.grip(side, t0 + 0.2, t0 + 1.2 + 6 * 0.45 + 1.2)
    for i in range(6):
        hand.move((sign * (0.25 + (0.12 if i % 2 == 0 else -0.08)) + rng.normal(0, 0.01), 0.25, 0.25), 0.45)
    hand.move((0.0, -0.55, 0.1), 1.2)


def both_arms(s: Session, rng: np.random.Generator) -> None:
    t0 = max(s.head.end_time, *(h.end_time for h in s.hands.values()))
    poses = [(0.0, 0.0, 0.55), (0.0, 0.35, 0.35), (0.55, 0.0, 0.0), (0.0, -0.3, 0.45), (0.0, -0.55, 0.1)]
    for side, sign in (("left", -1), ("right", 1)):
        hand = s.hands[side]
        if t0 > hand.end_time:
            hand.hold(t0 - hand.end_time)
        for x, y, z in poses:
            hand.move((sign * x + rng.normal(0, 0.01), y + rng.normal(0, 0.01), z), 1.1 + rng.uniform(0, 0.2))
            hand.hold(0.2)
        s.grip(side, t0 + 0.3, hand.end_time - 0.3)


def menu_item_ids(menu_dir: Path | None = None) -> list[str]:
    """Every selectable item id as the server would list them on /vr_teleop/menus (generated ones too): the
    server's own MenuService is run on a private bus over the menu files and the packaged gestures."""
    model = load_qtrobot()
    menus = load_menus(menu_dir)
    if not menus:
        raise ValueError("menu-tour: no menu files found; nothing to select")
    bus = Bus(TypeRegistry())
    gestures = GestureLibrary([packaged_gesture_dir()], model).names
    MenuService(bus, menus, gestures=gestures, emotions=model.emotions, status=lambda _which: {},
                luxai=None, unavailable=lambda: {"record_clip"}).start()  # a `serve` without --clips, as replayed
    got: list[Any] = []
    bus.subscribe(SERVER_NODE, names.MENUS_TOPIC, None, lambda published: got.append(published.data))
    ids = [item["id"] for item in got[-1]["items"] if item["command"]]
    # Leave the robot as found: emergency stop, release and motors off come last, then motors on and engage.
    last = ("motion.robot.stop", "motion.robot.release", "motion.robot.motors_off", "motion.robot.motors_on",
            "motion.robot.engage")
    return [i for i in ids if i not in last] + [i for i in last if i in ids]


TOUR_PUPIL = "child_left"  # the stand-in's pupil on the left: a teleoperated server attends to nobody


def menu_tour(s: Session, rng: np.random.Generator, ids: list[str] | None = None, spacing: float = 1.5) -> None:
    t = max(s.head.end_time, 1.0)
    ids = ids if ids is not None else menu_item_ids()
    for item in ids:
        if item == "motion.record":
            args = json.dumps({"name": "synth_menu_tour"})
        elif item.startswith("speech.sentences."):  # the teacher picks whom a sentence's {pupil} names
            args = json.dumps({"pupil": TOUR_PUPIL})
        else:
            args = ""
        s.call(t, names.MENU_SELECT_SERVICE, "vr_teleop_msgs/MenuSelect", {"id": item, "args": args})
        if item in TOGGLES:  # select it again: stop and save, or switch back on
            t += spacing
            again = args if item == "motion.record" else json.dumps({"enable": True})
            s.call(t, names.MENU_SELECT_SERVICE, "vr_teleop_msgs/MenuSelect", {"id": item, "args": again})
        t += spacing
    s.head.move((rng.normal(0, 5), rng.normal(0, 3)), max(0.5, t - s.head.end_time))


def classroom(s: Session, rng: np.random.Generator, minutes: float = 5.0) -> None:
    """A teacher's session: looking at pupils, nodding, waving, pointing, a few words and faces, pauses."""
    end = minutes * 60.0
    selections = ["emotion.happy", "speech.sentences.good_morning_class", "emotion.surprise",
                  "speech.sentences.well_done", "emotion.neutral", "speech.sentences.can_you_tell_me_more"]
    k = 0
    while s.head.end_time < end - 12:
        choice = rng.choice(["look", "look", "nod", "wave", "arms", "talk", "idle"])
        if choice == "look":
            for _ in range(3):
                s.head.move((rng.uniform(-55, 55), rng.uniform(-10, 15)), rng.uniform(0.8, 1.6))
                s.head.hold(rng.uniform(0.5, 2.0))
        elif choice == "nod":
            nod(s, rng)
        elif choice == "wave":
            wave(s, rng, str(rng.choice(["left", "right"])))
            _head_waits_for_hands(s)
        elif choice == "arms":
            both_arms(s, rng)
            _head_waits_for_hands(s)
        elif choice == "talk":
            item = selections[k % len(selections)]
            k += 1
            s.call(s.head.end_time, names.MENU_SELECT_SERVICE, "vr_teleop_msgs/MenuSelect", {"id": item, "args": ""})
            s.head.hold(3.0)
        else:
            s.head.move(s.head.end + rng.normal(0, 2, 2), rng.uniform(2, 5))
    s.head.move((0, 0), max(1.0, end - s.head.end_time))


def _head_waits_for_hands(s: Session) -> None:
    s.head.hold(max(0.0, max(h.end_time for h in s.hands.values()) - s.head.end_time))


def build(name: str, seed: int = 0) -> Session:
    rng = np.random.default_rng(seed)
    s = _engaged()
    if name == "look-around":
        look_around(s, rng)
    elif name == "nod":
        nod(s, rng)
    elif name == "wave":
        wave(s, rng)
        _head_waits_for_hands(s)
    elif name == "both-arms":
        both_arms(s, rng)
        _head_waits_for_hands(s)
    elif name == "menu-tour":
        menu_tour(s, rng)
    elif name == "classroom":
        classroom(s, rng)
    else:
        raise ValueError(f"unknown session {name!r}; choose one of {', '.join(SCENARIOS)}")
    return s


# ---- rendering to messages ----------------------------------------------------------------------------------------
def _quat(yaw_left: float, pitch_up: float, jitter: np.ndarray) -> list[float]:
    # Unity: yaw about y (left is negative), then pitch about x (up is negative).
    r = Rotation.from_euler("YX", [-yaw_left, -pitch_up], degrees=True) * Rotation.from_rotvec(np.radians(jitter))
    return r.as_quat().tolist()


def _pose(stamp_ns: int, position: np.ndarray, quat: list[float]) -> dict:
    return {"header": {"seq": 0, "stamp": {"secs": stamp_ns // 10**9, "nsecs": stamp_ns % 10**9}, "frame_id": "unity_left_handed"},
            "pose": {"position": dict(zip("xyz", map(float, position))),
                     "orientation": dict(zip("xyzw", quat))}}


def write(session: Session, out: Path, seed: int = 0, start_ns: int = 1_700_000_000 * 10**9) -> int:
    """Writes the session as a recording; returns the number of headset frames (90 Hz ticks)."""
    rng = np.random.default_rng(seed + 1)
    recorder = Recorder(out, TypeRegistry(), camera_fps=0)
    n = int(session.duration * RATE)
    recorder.write_metadata(SESSION_METADATA, {"duration_s": f"{(n - 1) / RATE:.3f}"})  # names a cut-off copy
    calls = sorted(session.calls)
    call_index = 0
    for i in range(n):
        t = i / RATE
        stamp = start_ns + int(t * 1e9)
        while call_index < len(calls) and calls[call_index][0] <= t:
            _, service, _type, args = calls[call_index]
            frame = {"op": "call_service", "id": f"synth:{call_index}", "service": service, "args": args}
            recorder.on_frame(CLIENT, "in", json.dumps(frame), time_ns=stamp)
            call_index += 1
        yaw, pitch = session.head(t)
        sway = np.array([0.005 * math.sin(0.7 * t), 0.003 * math.sin(1.1 * t), 0.004 * math.sin(0.5 * t)])
        eye = EYE + sway + rng.normal(0, 0.001, 3)
        head = _pose(stamp, eye, _quat(yaw, pitch, rng.normal(0, 0.2, 3)))
        recorder.write_message(names.HEAD_POSE_TOPIC, "geometry_msgs/PoseStamped", CLIENT, json.dumps(head).encode(),
                               stamp)
        for side, sign in (("left", -1), ("right", 1)):
            shoulder = EYE + np.array([sign * SHOULDER_HALF, -SHOULDER_DROP, -0.05])
            position = shoulder + session.hands[side](t) + rng.normal(0, 0.001, 3)
            msg = _pose(stamp, position, _quat(0, 0, rng.normal(0, 0.3, 3)))
            recorder.write_message(names.CONTROLLER_POSE_TOPICS[side], "geometry_msgs/PoseStamped", CLIENT,
                                   json.dumps(msg).encode(), stamp)
            if i % JOY_EVERY == 0:
                held = any(a <= t <= b for a, b in session.grips[side])
                joy = {"header": {"seq": 0, "stamp": {"secs": stamp // 10**9, "nsecs": stamp % 10**9},
                                  "frame_id": ""},
                       "axes": [0.0, 0.0, 0.0, 0.95 if held else 0.0], "buttons": [0, 0, 0, 0]}
                recorder.write_message(names.JOY_TOPICS[side], "sensor_msgs/Joy", CLIENT,
                                       json.dumps(joy).encode(), stamp)
    recorder.finish()
    return n
