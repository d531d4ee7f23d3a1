"""Test helpers: servers from one factory (the server in its own thread is testbed/server.py's, shared with the
benches), a raw WebSocket client, and a fake headset and topic watchers over roslibpy."""

from __future__ import annotations

import json
import threading
import re
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import roslibpy
from websockets.exceptions import ConnectionClosed
from websockets.sync.client import ClientConnection, connect

from testbed.server import Pace, RunningServer, ServerFactory, wait_for  # noqa: F401 (the tests' names for them)
from vr_teleop_server.settings import ServerSettings
from vr_teleop_server.teleop import TeleopSettings


def patient_teleop() -> TeleopSettings:
    """Explicit control whose stream timeouts are seconds instead of 0.2 s, for tests of replay and of the mapping:
    on a loaded machine a client starved for a few hundred milliseconds must not look like a headset that
    stopped (then the server rightly holds the robot, which an offline mapping of the session cannot know). The
    timeouts themselves are tested with their defaults (test_faults.py, test_explicit_control.py)."""
    return TeleopSettings(watchdog_timeout_s=2.0, controller_timeout_s=2.0)


class RawClient:
    """A plain WebSocket client speaking rosbridge JSON by hand, to assert exact replies."""

    def __init__(self, url: str) -> None:
        self.ws: ClientConnection = connect(url, compression=None, max_size=None, open_timeout=30).__enter__()

    def send(self, message: dict[str, Any]) -> None:
        self.ws.send(json.dumps(message))

    def send_raw(self, frame: str | bytes) -> None:
        self.ws.send(frame)

    def recv_frame(self, timeout: float = 3.0) -> str | bytes:
        return self.ws.recv(timeout=timeout)

    def recv(self, timeout: float = 3.0) -> dict[str, Any]:
        frame = self.recv_frame(timeout)
        assert isinstance(frame, str), f"expected a TEXT frame, got {len(frame)} binary bytes"
        return json.loads(frame)

    def expect(self, op: str, timeout: float = 3.0, **fields: Any) -> dict[str, Any]:
        """The next message with this op (and these field values); fails on anything else in between."""
        message = self.recv(timeout)
        assert message.get("op") == op, f"expected op {op!r}, got {message}"
        for key, value in fields.items():
            assert message.get(key) == value, f"expected {key}={value!r} in {message}"
        return message

    def silent(self, duration: float = 0.3) -> bool:
        """True when nothing arrives for `duration` seconds."""
        try:
            frame = self.ws.recv(timeout=duration)
        except TimeoutError:
            return True
        raise AssertionError(f"expected silence, got {frame!r}")

    def alive(self, topic: str = "/alive_check") -> None:
        """Proves the connection still works: a publish this client makes comes back to it."""
        self.send({"op": "subscribe", "id": "alive", "topic": topic, "type": "std_msgs/String"})
        self.send({"op": "publish", "topic": topic, "msg": {"data": "still here"}})
        deadline = time.monotonic() + 3
        while time.monotonic() < deadline:
            message = self.recv()
            if message.get("op") == "publish" and message.get("topic") == topic:
                assert message["msg"] == {"data": "still here"}
                self.send({"op": "unsubscribe", "id": "alive", "topic": topic})
                return
        raise AssertionError("the connection no longer delivers messages")

    def close(self) -> None:
        try:
            self.ws.close()
        except ConnectionClosed:
            pass


# ---- a fake headset and topic watchers over roslibpy (explicit control, menus) --------------------------------------
EYE_HEIGHT = 1.6


def unity_yaw_pitch(yaw_left_deg: float, pitch_up_deg: float = 0.0) -> dict[str, float]:
    """Unity quaternion for a head turned left and tilted up (Unity: y up, left-handed, so left is -y)."""
    from scipy.spatial.transform import Rotation

    # Unity applies yaw about y, then pitch about x; looking up is a negative rotation about Unity's x.
    q = Rotation.from_euler("YX", [-yaw_left_deg, -pitch_up_deg], degrees=True).as_quat()
    return {"x": q[0], "y": q[1], "z": q[2], "w": q[3]}


def pose_msg(position: tuple[float, float, float], orientation: dict[str, float]) -> dict[str, Any]:
    x, y, z = position
    return {"header": {"frame_id": "unity_left_handed"},
            "pose": {"position": {"x": x, "y": y, "z": z}, "orientation": orientation}}


IDENTITY = {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0}


class Headset:
    """Streams head and controller poses at 90 Hz (and Joy at 30 Hz) from a thread, like a Quest would."""

    def __init__(self, ros: roslibpy.Ros) -> None:
        self.ros = ros
        self.head = roslibpy.Topic(ros, "/vr/head/pose", "geometry_msgs/PoseStamped")
        self.hands = {s: roslibpy.Topic(ros, f"/vr/{s}_controller/pose", "geometry_msgs/PoseStamped")
                      for s in ("left", "right")}
        self.joys = {s: roslibpy.Topic(ros, f"/vr/{s}_controller/joy", "sensor_msgs/Joy") for s in ("left", "right")}
        self.head_orientation = IDENTITY
        self.hand_positions = {"left": (-0.19, 1.0, 0.1), "right": (0.19, 1.0, 0.1)}  # hanging down
        self.grips = {"left": 0.0, "right": 0.0}
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._sent = threading.Condition()
        self.head_poses_sent = 0

    def start(self) -> Headset:
        """Starts streaming, and returns once the first head pose is handed to the connection: roslibpy sends in
        the order handed, so a call made next (an engage) reaches the server after a head pose, as a headset's
        does. (Engaging ahead of the first pose is refused; a server may still take it if the pose overtakes the
        call's task, and a recording of that replays as a refusal.)"""
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()
        self.send_head_poses(1)
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2)

    def send_head_poses(self, count: int, timeout: float = 60.0) -> None:
        """Wait until `count` more head poses went out (at 90 Hz, count / 90 s on an idle machine): a motion held
        for a number of poses is the same session on a loaded machine, where the sleeps between poses run long."""
        with self._sent:
            target = self.head_poses_sent + count
            if not self._sent.wait_for(lambda: self.head_poses_sent >= target, timeout):
                raise TimeoutError(f"the headset sent {self.head_poses_sent} head poses, not {target}, in {timeout} s")

    def _run(self) -> None:
        n = 0
        pace = Pace(90, catch_up=False)
        while not self._stop.is_set():
            self.head.publish(roslibpy.Message(pose_msg((0.0, EYE_HEIGHT, 0.0), self.head_orientation)))
            with self._sent:
                self.head_poses_sent += 1
                self._sent.notify_all()
            for side, topic in self.hands.items():
                topic.publish(roslibpy.Message(pose_msg(self.hand_positions[side], IDENTITY)))
            if n % 3 == 0:
                for side, topic in self.joys.items():
                    topic.publish(roslibpy.Message({"axes": [0.0, 0.0, 0.0, self.grips[side]],
                                                    "buttons": [0, 0, 0, 0]}))
            n += 1
            if pace.wait(self._stop):
                break


class Watch:
    """The latest message of a topic, and every message, as a client receives them."""

    def __init__(self, ros: roslibpy.Ros, topic: str, type_name: str) -> None:
        self.messages: list[dict[str, Any]] = []
        self.lock = threading.Lock()
        self.topic = roslibpy.Topic(ros, topic, type_name)
        self.topic.subscribe(self._on)

    def _on(self, msg: dict[str, Any]) -> None:
        with self.lock:
            self.messages.append(msg)

    @property
    def latest(self) -> dict[str, Any]:
        with self.lock:
            return self.messages[-1] if self.messages else {}

    def any(self, predicate) -> bool:
        with self.lock:
            return any(predicate(m) for m in self.messages)

    def close(self) -> None:
        self.topic.unsubscribe()


def still(predicate: Callable[[], Any], watch: Watch, messages: int = 15, timeout: float = 5.0) -> bool:
    """True when `predicate` still holds after `messages` more messages of a stream with a steady rate (teleop
    state: 30 Hz): a joint at its target stays there, one passing through on its way elsewhere does not."""
    with watch.lock:
        seen = len(watch.messages)
    return wait_for(lambda: len(watch.messages) >= seen + messages, timeout) and bool(predicate())


def physics_ran(standin, seconds: float, timeout: float = 30.0) -> bool:
    """Waits until the stand-in's physics has stepped `seconds` of its own time from now: what a joint told to move
    has had to move in, however far a loaded machine makes the physics trail the wall clock."""
    start = standin.joint_state().sim_time
    return wait_for(lambda: standin.joint_state().sim_time >= start + seconds, timeout)


def joints(watch: Watch) -> dict[str, float]:
    msg = watch.latest
    return dict(zip(msg.get("name", []), msg.get("position", [])))


def call(ros: roslibpy.Ros, name: str, type_name: str, args: dict[str, Any] | None = None) -> dict[str, Any]:
    return roslibpy.Service(ros, name, type_name).call(roslibpy.ServiceRequest(args or {}), timeout=10)


def refused(reply: dict[str, Any], reason: str = "") -> dict[str, Any]:
    """A refusal as the server answers one: a successful call whose response says so (success or status false,
    the reason in message where the type has one)."""
    assert reply.get("success", reply.get("status")) is False, reply
    if "message" in reply or "success" in reply:
        assert re.search(reason, reply["message"]), (reason, reply)
    return reply


def engage(ros: roslibpy.Ros, timeout: float = 30.0) -> None:
    """Engages, asking again while the server refuses (inside the response, success false) for want of a head pose
    of this operator: one sent from another connection (the operator's headset beside its page) may still be on
    its way. A Headset on `ros` itself has sent one before start() returned."""
    replies: list[Any] = []

    def engaged() -> bool:
        try:
            replies.append(call(ros, "/vr_teleop/control/engage", "std_srvs/SetBool", {"data": True}))
        except roslibpy.core.ServiceException as exc:
            replies.append(exc)
            return False
        return bool(replies[-1]["success"])

    assert wait_for(engaged, timeout), replies[-1]


def wait_subscribed(server: RunningServer, topic: str, clients: int = 1, timeout: float = 5.0) -> bool:
    """Waits until `clients` client connections (not the server's own features, whatever node name they subscribe
    under: autonomy's is its own) subscribe to `topic`: roslibpy's subscribe returns before the server has it, and a
    message published in between would be missed."""

    def count() -> int:
        t = server.server.bus.topics.get(topic)
        sessions = server.server.sessions
        return 0 if t is None else len({owner for owner, _cb in t.subscribers.values() if owner in sessions})
    return wait_for(lambda: server.call(count) >= clients, timeout)


def bystanders_in_view(robot, width: int, height: int) -> dict[str, tuple[float, float]]:
    """Where each bystander's head centre falls in the head camera's image (pixels), from the scene and the
    forward kinematics at the current joint state."""
    import mujoco
    import numpy as np

    from robot_models.kinematics import forward_kinematics
    from vr_teleop_server.study.perception.aruco import camera_matrix

    standin = robot.standin
    scene, model = standin.scene, robot.model
    data = mujoco.MjData(standin.model)
    mujoco.mj_forward(standin.model, data)
    base_from_camera = forward_kinematics(model, {**model.home_pose(), **robot.joint_state().as_dict()})["camera"]
    camera_from_world = np.linalg.inv(scene.robot_base_world @ base_from_camera)
    k = camera_matrix(model, width, height)
    seen = {}
    for name in scene.bystanders:
        head = data.geom_xpos[mujoco.mj_name2id(standin.model, mujoco.mjtObj.mjOBJ_GEOM, f"{name}_head")]
        p = camera_from_world @ np.append(head, 1.0)
        u, v, _ = k @ (p[:3] / p[2])
        if p[2] > 0 and 0 <= u < width and 0 <= v < height:
            seen[name] = (u, v)
    return seen
