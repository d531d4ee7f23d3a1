"""A fake QTrobot v3 for tests: a service hub (and its MQTT gateway, and a realsense-driver plugin) made of
luxai-magpie's own server-side classes (ZMQRpcResponder and MqttRpcResponder served by a ServerNode, ZeroMQ and MQTT
stream writers and readers), answering LuxAI's SDK from the SDK's own interface definition (its IDL names every RPC
and stream, their directions and frame types). Only the robot's body is simulated: joints that move toward their
commands at the commanded speed within the hub's own (narrower) limits, a talking face, a speaker, a microphone
that hears a tone, a camera that sees a moving gradient.

Over MQTT the stream frames the SDK writes (joint commands, audio) arrive on the bare stream topic, not under the
robot id (SDK 0.6.9), so that is where the gateway here reads them, as a real one has to.
"""

from __future__ import annotations

import math
import threading
import time
from typing import Any

import numpy as np

from luxai.magpie.frames import AudioFrameRaw, DictFrame, ImageFrameRaw
from luxai.magpie.nodes import ServerNode
from luxai.magpie.transport import MqttConnection, MqttOptions, MqttRpcResponder, MqttStreamReader, \
    MqttStreamWriter, ZMQRpcResponder, ZmqStreamReader, ZmqStreamWriter
from luxai.magpie.transport.mqtt import MqttReconnectOptions
from luxai.robot.core.config import SYSTEM_DESCRIBE_SERVICE
from luxai.robot.core.frames import JointStateFrame
from luxai.robot.core.idl.api_core import QTROBOT_CORE_APIS
from luxai.robot.core.idl.api_plugins import QTROBOT_PLUGINS_APIS

from robot_models import load_qtrobot

from .processes import free_port

CAMERA_NODE_ID = "qtrobot-realsense-driver"
# The hub's limits: narrower than the URDF's on HeadYaw (-60..60) and RightElbowRoll's velocity, as LuxAI's own
# motor.list example differs from its URDF.
NARROW = {"HeadYaw": {"position_min": -40.0, "position_max": 45.0},
          "RightElbowRoll": {"velocity_max": 50.0}}
STATE_HZ = 30.0
MIC_CHUNK_S = 0.02
CAMERA_SIZE = (160, 120)
CAMERA_HZ = 10.0


def _served_streams() -> dict[str, dict[str, Any]]:
    """The hub's streams this fake serves, as the SDK's IDL declares them (topic -> spec)."""
    keys = ("motor.joints_state", "motor.joints_error", "motor.joints_command", "media.fg_audio_stream",
            "microphone.int_audio_ch0", "microphone.int_event")
    return {QTROBOT_CORE_APIS["stream"][k]["topic"]: QTROBOT_CORE_APIS["stream"][k] for k in keys}


class FakeQtrobotV3:
    """start() binds (the same ports again after a stop(): the robot process restarting); stop() kills it."""

    def __init__(self, *, robot_id: str = "QTRD000320", broker: str | None = None, broker_options: Any = None,
                 zmq: bool = True,
                 limits: dict[str, dict[str, float]] | None = None, camera: bool = True,
                 speech_s_per_word: float = 0.5) -> None:
        self.robot_id = robot_id
        self.broker = broker
        self.broker_options = broker_options or MqttOptions(
            reconnect=MqttReconnectOptions(min_delay_sec=1, max_delay_sec=1))
        self.zmq = zmq
        self.model = load_qtrobot()
        self.limits = {j.name: {"part": j.part, "position_min": j.lower, "position_max": j.upper,
                                "position_home": j.home, "velocity_max": 100.0} for j in self.model.joints}
        for name, values in (NARROW if limits is None else limits).items():
            self.limits[name].update(values)
        self.camera = camera
        self.speech_s_per_word = speech_s_per_word
        self.hub_port, self.rpc_port, self.camera_port, self.camera_stream_port = (free_port() for _ in range(4))
        self.stream_ports = {topic: free_port() for topic in _served_streams()}
        self.lock = threading.Lock()
        self.positions = {j.name: j.home for j in self.model.joints}
        self.targets = dict(self.positions)
        self.speeds = {j.name: 100.0 for j in self.model.joints}
        self.torque = {j.name: True for j in self.model.joints}
        self.commands: list[dict[str, Any]] = []  # every joint command frame received
        self.command_times: list[float] = []  # time.monotonic() at each one's arrival (bench/qtrobot_v3.py)
        self.emotions: list[str] = []
        self.said: list[dict[str, Any]] = []
        self.spoken: list[str] = []  # sentences said to the end
        self.cancelled: list[str] = []  # sentences cut short
        self.tts_config: dict[str, Any] = {}
        self.gestures: list[tuple[str, float]] = []
        self.homed: list[str] = []
        self.audio = bytearray()  # what the speaker received
        self.audio_frames: list[tuple[int, int, int]] = []  # (channels, sample_rate, bit_depth) of each
        self.rpc_names: list[str] = []
        self.faults: dict[str, dict[str, bool]] = {}
        self.mic_event: dict[str, Any] | None = None
        self._cancel_speech = threading.Event()
        self._cancel_gesture = threading.Event()
        self._parts: list[Any] = []
        self._writers: dict[str, list[tuple[Any, str]]] = {}
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self.running = False

    # ---- the description, from the SDK's IDL ------------------------------------------------------------------
    def describe(self) -> dict[str, Any]:
        services = {spec["service_name"] for spec in QTROBOT_CORE_APIS["rpc"].values()}
        services |= {spec["cancel_service_name"] for spec in QTROBOT_CORE_APIS["rpc"].values()
                     if spec.get("cancel_service_name")}
        rpc = {name: {"transports": {"zmq": {"endpoint": f"tcp://*:{self.rpc_port}"},
                                     "mqtt": {"topic": f"{self.robot_id}/hub"}}} for name in sorted(services)}
        stream = {}
        for topic, spec in _served_streams().items():
            stream[topic] = {"direction": spec["direction"], "frame_type": spec["frame_type"],
                             "transports": {"zmq": {"endpoint": f"tcp://*:{self.stream_ports[topic]}",
                                                    "delivery": spec["delivery"], "queue_size": spec["queue_size"]},
                                            "mqtt": {"topic": f"{self.robot_id}{topic}"}}}
        return {"robot_type": "qtrobot-v3", "robot_id": self.robot_id, "sdk_version": "0.6.9", "min_sdk": "0.6.0",
                "rpc": rpc, "stream": stream}

    def describe_camera(self) -> dict[str, Any]:
        rpc = {spec["service_name"]: {"transports": {"zmq": {"endpoint": f"tcp://*:{self.camera_port}"},
                                                     "mqtt": {"topic": CAMERA_NODE_ID}}}
               for spec in QTROBOT_PLUGINS_APIS["rpc"].values() if spec.get("provider") == "realsense-driver"}
        spec = QTROBOT_PLUGINS_APIS["stream"]["camera.color"]
        stream = {spec["topic"]: {"direction": "out", "frame_type": spec["frame_type"],
                                  "transports": {"zmq": {"endpoint": f"tcp://*:{self.camera_stream_port}",
                                                         "delivery": "latest", "queue_size": 1},
                                                 "mqtt": {"topic": f"{CAMERA_NODE_ID}{spec['topic']}"}}}}
        return {"rpc": rpc, "stream": stream}

    # ---- RPCs -------------------------------------------------------------------------------------------------
    def handle(self, request: dict[str, Any]) -> dict[str, Any]:
        name, args = request.get("name"), request.get("args") or {}
        self.rpc_names.append(name)
        try:
            handler = self._handlers().get(name)
            if handler is None:
                return {"status": False, "response": f"{name} is not simulated by the fake hub"}
            return {"status": True, "response": handler(args)}
        except Exception as exc:  # a bad argument: the robot answers a failure
            return {"status": False, "response": str(exc)}

    def _handlers(self) -> dict[str, Any]:
        return {
            SYSTEM_DESCRIBE_SERVICE: lambda a: self.describe(),
            "/motor/list": lambda a: {n: dict(v) for n, v in self.limits.items()},
            "/face/emotion/list": lambda a: [f"QT/{e}.avi" for e in self.model.emotions],
            "/face/emotion/show": self._show_emotion,
            "/tts/engine/say/text": self._say,
            "/tts/engine/cancel": lambda a: self._cancel_speech.set() or True,
            "/tts/engine/configure/set": lambda a: self.tts_config.update(a["config"]) or True,
            "/gesture/file/list": lambda a: ["QT/bye", "QT/nod"],
            "/gesture/file/play": self._play_gesture,
            "/gesture/cancel": lambda a: self._cancel_gesture.set() or True,
            "/motor/on": lambda a: self._torque(a["motor"], True),
            "/motor/off": lambda a: self._torque(a["motor"], False),
            "/motor/move/home": self._home,
            "/media/audio/fg/stream/cancel": lambda a: True,
        }

    def _show_emotion(self, args: dict[str, Any]) -> bool:
        name = str(args["emotion"]).removesuffix(".avi")
        if name.removeprefix("QT/") not in self.model.emotions:
            raise ValueError(f"no emotion {name}")
        self.emotions.append(name)
        return True

    def _say(self, args: dict[str, Any]) -> bool:
        self.said.append(dict(args))
        self._cancel_speech.clear()
        if self._cancel_speech.wait(self.speech_s_per_word * len(str(args["text"]).split())):
            self.cancelled.append(args["text"])
            return False
        self.spoken.append(args["text"])
        return True

    def _play_gesture(self, args: dict[str, Any]) -> bool:
        self.gestures.append((args["gesture"], float(args.get("speed_factor", 1.0))))
        self._cancel_gesture.clear()
        return not self._cancel_gesture.wait(1.0 / float(args.get("speed_factor", 1.0)))  # a 1 s gesture

    def _torque(self, motor: str, on: bool) -> bool:
        with self.lock:
            self.torque[motor] = on
            self.targets[motor] = self.positions[motor]
        return True

    def _home(self, args: dict[str, Any]) -> bool:
        motor = args["motor"]
        with self.lock:
            self.targets[motor] = self.limits[motor]["position_home"]
        self.homed.append(motor)
        return True

    # ---- streams in -------------------------------------------------------------------------------------------
    def _on_command(self, value: dict[str, Any]) -> None:
        frame = value.get("value", value)
        with self.lock:
            self.commands.append(frame)
            self.command_times.append(time.monotonic())
            for name, command in frame.items():
                if name in self.targets and self.torque[name] and "position" in command:
                    limit = self.limits[name]
                    self.targets[name] = min(max(float(command["position"]), limit["position_min"]),
                                             limit["position_max"])
                    if command.get("velocity"):
                        self.speeds[name] = min(float(command["velocity"]), limit["velocity_max"])

    def _on_audio(self, value: dict[str, Any]) -> None:
        frame = AudioFrameRaw.from_dict(value) if isinstance(value, dict) else value
        self.audio_frames.append((frame.channels, frame.sample_rate, frame.bit_depth))
        self.audio += frame.data

    # ---- lifecycle --------------------------------------------------------------------------------------------
    def start(self) -> FakeQtrobotV3:
        self._stop = threading.Event()
        self._writers = {}
        inbound = {"/motor/joints/command/stream:i": self._on_command, "/media/audio/fg/stream:i": self._on_audio}
        if self.zmq:
            for port in (self.hub_port, self.rpc_port):
                self._parts.append(ServerNode(ZMQRpcResponder(f"tcp://127.0.0.1:{port}"), self.handle,
                                              max_workers=8))
            for topic, spec in _served_streams().items():
                endpoint = f"tcp://127.0.0.1:{self.stream_ports[topic]}"
                if spec["direction"] == "out":
                    writer = ZmqStreamWriter(endpoint, bind=True, delivery=spec["delivery"], queue_size=0)
                    self._writers.setdefault(topic, []).append((writer, topic))
                    self._parts.append(writer)
                else:
                    reader = ZmqStreamReader(endpoint, topic=topic, bind=True, queue_size=0)
                    self._parts.append(reader)
                    self._thread(self._read, reader, inbound[topic])
            if self.camera:
                self._parts.append(ServerNode(ZMQRpcResponder(f"tcp://127.0.0.1:{self.camera_port}"),
                                              self._handle_camera, max_workers=2))
                writer = ZmqStreamWriter(f"tcp://127.0.0.1:{self.camera_stream_port}", bind=True, delivery="latest",
                                         queue_size=0)
                self._writers.setdefault("/camera/color/image", []).append((writer, "/camera/color/image"))
                self._parts.append(writer)
        if self.broker:
            self._start_gateway(inbound)
        self._thread(self._simulate)
        self._thread(self._microphone)
        if self.camera:
            self._thread(self._camera)
        self.running = True
        return self

    def _start_gateway(self, inbound: dict[str, Any]) -> None:
        """The hub's MQTT gateway: the same RPCs and streams through the broker, under the robot id."""
        conn = MqttConnection(self.broker, options=self.broker_options)
        if not conn.connect(timeout=10):
            raise RuntimeError(f"the fake hub's gateway cannot reach the broker {self.broker}")
        self.connection = conn
        for service in (self.robot_id, f"{self.robot_id}/hub"):
            self._parts.append(ServerNode(MqttRpcResponder(conn, service), self.handle, max_workers=8))
        writer = MqttStreamWriter(conn, queue_size=0, qos=0)
        self._parts.append(writer)
        for topic, spec in _served_streams().items():
            if spec["direction"] == "out":
                self._writers.setdefault(topic, []).append((writer, f"{self.robot_id}{topic}"))
            else:
                reader = MqttStreamReader(conn, topic, queue_size=0)  # the bare topic: SDK 0.6.9 writes there
                self._parts.append(reader)
                self._thread(self._read, reader, inbound[topic])
        if self.camera:
            self._parts.append(ServerNode(MqttRpcResponder(conn, CAMERA_NODE_ID), self._handle_camera,
                                          max_workers=2))
            self._writers.setdefault("/camera/color/image", []).append(
                (writer, f"{CAMERA_NODE_ID}/camera/color/image"))

    def _handle_camera(self, request: dict[str, Any]) -> dict[str, Any]:
        name = request.get("name")
        if name == "":
            return {"status": True, "response": self.describe_camera()}
        if name == "/camera/color/intrinsics":
            return {"status": True, "response": {"width": CAMERA_SIZE[0], "height": CAMERA_SIZE[1], "fx": 376.40,
                                                 "fy": 376.08, "cx": 314.64, "cy": 255.58}}
        return {"status": False, "response": f"{name} is not simulated"}

    def _thread(self, target: Any, *args: Any) -> None:
        thread = threading.Thread(target=target, args=args, daemon=True)
        thread.start()
        self._threads.append(thread)

    def _read(self, reader: Any, handle: Any) -> None:
        while not self._stop.is_set():
            try:
                got = reader.read(timeout=0.2)
            except TimeoutError:
                continue
            except Exception:
                if self._stop.is_set():
                    return
                continue
            if got is not None:
                handle(got[0])

    def publish(self, topic: str, frame: Any) -> None:
        data = frame.to_dict()
        for writer, wire_topic in self._writers.get(topic, ()):
            try:
                writer.write(data, wire_topic)
            except Exception:
                pass

    def _simulate(self) -> None:
        period = 1.0 / STATE_HZ
        last = time.monotonic()
        while not self._stop.wait(period):
            now = time.monotonic()
            dt, last = now - last, now
            with self.lock:
                for name, target in self.targets.items():
                    step = self.speeds[name] * dt
                    here = self.positions[name]
                    self.positions[name] = here + max(-step, min(step, target - here))
                value = {n: {"position": p, "velocity": 0.0, "effort": 0.0, "temperature": 35.0 + i,
                             "voltage": 12.0} for i, (n, p) in enumerate(self.positions.items())}
                faults = dict(self.faults)
            self.publish("/motor/joints/state/stream:o", JointStateFrame(value=value))
            self.publish("/motor/joints/error/stream:o", DictFrame(value=faults))
            if self.mic_event is not None:
                self.publish("/mic/int/event/stream:o", DictFrame(value=dict(self.mic_event)))

    def _microphone(self) -> None:
        """A 440 Hz tone at 16 kHz mono, in 20 ms frames."""
        n = int(16000 * MIC_CHUNK_S)
        t0 = 0
        while not self._stop.wait(MIC_CHUNK_S):
            t = (np.arange(n) + t0) / 16000.0
            t0 += n
            pcm = (0.3 * 32767 * np.sin(2 * math.pi * 440.0 * t)).astype("<i2").tobytes()
            self.publish("/mic/int/audio/ch0/stream:o", AudioFrameRaw(channels=1, sample_rate=16000, bit_depth=16,
                                                                      data=pcm))

    def _camera(self) -> None:
        w, h = CAMERA_SIZE
        i = 0
        while not self._stop.wait(1.0 / CAMERA_HZ):
            i += 1
            image = np.zeros((h, w, 3), np.uint8)
            image[:, :, 2] = 200  # red in BGR
            image[:, : (i * 7) % w, 1] = 120
            self.publish("/camera/color/image", ImageFrameRaw(data=image.tobytes(), format="raw", width=w, height=h,
                                                              channels=3, pixel_format="BGR"))

    def stop(self) -> None:
        """The robot's process dies: every socket closes."""
        self.running = False
        self._stop.set()
        self._cancel_speech.set()
        self._cancel_gesture.set()
        for thread in self._threads:
            thread.join(timeout=3)
        self._threads = []
        for part in reversed(self._parts):
            try:
                if isinstance(part, ServerNode):
                    part.terminate(timeout=3)
                else:
                    part.close()
            except Exception:
                pass
        self._parts = []
        if self.broker and getattr(self, "connection", None) is not None:
            self.connection.disconnect()
            self.connection = None
