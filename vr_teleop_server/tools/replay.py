"""`vr-teleop replay`: a headless rosbridge client that plays a recorded or synthesised headset session against a
server, S times faster if asked, and reports what came back.

What is replayed: the operator's messages (the client that published /vr/head/pose the most, or --client):
its /vr/* poses and Joy, its operator audio and menu selections, and the service calls it made (engage, menu
select, calibrate...). Everything else in the recording is context and is not sent.

What is measured, all from what the server sends back:
- pose-to-command latency: from sending a head pose to receiving the head command it caused;
- joint tracking error: the commands received against what TeleopMapper computes offline from the same poses at
  the same send times (the server runs the same mapping; differences are timing, or a bug);
- camera frames received, their rate and their age (receive time minus the frame's stamp);
- menu selections acknowledged (successful service responses) and errors (status errors, failed calls).
The report also carries the recorded session's own supervision and attention measures (`autonomy`, as `vr-teleop
metrics autonomy` gives them), read from the file: they are not replayed.
With a `road` (tests and benches: the poses data channel), the operator's /vr/* streams take it while the replayed
operator holds control (as the issue-21 channel requires) and the WebSocket otherwise.
The plot shows, per joint, the commanded angles against the measured ones (/qt_robot/joints/state).

At `--speed max` without a server (`run_simulated`), the replay runs against a server of its own on the stand-in,
on a simulated clock (simclock), through an in-process connection to its transport: the same session, bus and
teleop code a WebSocket client reaches. Poses and Joy go as binary pose frames (client_protocol/pose_frame.py:
float32, one XR frame's in one, as a headset's), which the session takes as it takes their JSON publish frames. The messages go at their
recorded times in simulated time, which runs as fast as the work allows; every time in the report is simulated,
except `replay_s`, `served_s` and the speeds, which say how long it took on the wall clock. At `--speed max`
against a server (`--server`), each message goes as soon as the connection takes it.
"""

from __future__ import annotations

import asyncio
import json
import math
import struct
import sys
import time
from collections import defaultdict
from collections.abc import Awaitable, Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from tqdm import tqdm

from client_protocol import names, pose_frame
from client_protocol.vocabulary import ARMS, AutonomyLevel, Part
from robot_models import load_qtrobot
from simclock import WALL, Clock, SimulatedClock, loop_clock
from simclock import run as run_on_clock

from ..app import TeleopServer
from ..client import Client, RosbridgeError, connect, outcome
from ..recording.format import read_recording
from ..settings import ServerSettings
from ..study.metrics.autonomy import autonomy_metrics

from ..teleop import TeleopError, TeleopMapper, TeleopSettings

REPLAYED_TOPIC_PREFIXES = ("/vr/", names.MENU_SELECTION_TOPIC, names.OPERATOR_AUDIO_TOPIC)
ENGAGE_LAGS = 10  # head poses an engage may be overtaken by, at most
DRAIN_S = 30.0  # at most this long after the last message sent, for answers and late commands
QUIET_S = 2.0  # commands have stopped once none came for this long (a loaded server pauses)
ROAD_CALL_TIMEOUT_S = 30.0  # the road's calls (ICE servers, the media offer) on a loaded machine
TOPIC_TYPES = {names.HEAD_POSE_TOPIC: "geometry_msgs/PoseStamped",
               **{topic: "geometry_msgs/PoseStamped" for topic in names.CONTROLLER_POSE_TOPICS.values()},
               **{topic: "sensor_msgs/Joy" for topic in names.JOY_TOPICS.values()},
               names.MENU_SELECTION_TOPIC: "std_msgs/String",
               names.OPERATOR_AUDIO_TOPIC: "audio_common_msgs/AudioData",
               names.OPERATOR_AUDIO_INFO_TOPIC: "audio_common_msgs/AudioInfo"}


@dataclass(frozen=True)
class Step:
    t: float  # seconds from the session's start, at speed 1
    kind: str  # "publish" or "call"
    topic: str  # the topic, or the service
    payload: dict[str, Any]  # the message, or the call_service frame


def load_steps(path: Path, client: str | None = None) -> tuple[list[Step], str]:
    """The operator's messages and calls, in time order, and which client they came from."""
    messages = list(read_recording(path))
    if not messages:
        raise ValueError(f"{path}: an MCAP file without messages: nothing to replay")
    if client is None:
        counts: dict[str, int] = defaultdict(int)
        for m in messages:
            if m.topic == names.HEAD_POSE_TOPIC:
                counts[m.sender] += 1
        if not counts:
            raise ValueError(f"{path}: no client published /vr/head/pose; nothing to replay")
        client = max(counts, key=counts.__getitem__)
    start = min(m.time_ns for m in messages)
    steps = []
    for m in messages:
        if m.sender != client:
            continue
        t = (m.time_ns - start) / 1e9
        if m.topic.startswith(REPLAYED_TOPIC_PREFIXES) and m.metadata.get("direction") is None:
            steps.append(Step(t, "publish", m.topic, _current_frame_id(m.data)))
        elif m.topic == names.RECORDING_IN_CHANNEL and m.data.get("op") == "call_service":
            steps.append(Step(t, "call", m.data.get("service", ""), m.data))
    steps.sort(key=lambda s: s.t)
    return steps, client


def _current_frame_id(msg: Any) -> Any:
    """Recordings made before issue 18 (`vr-teleop synth`, clients following the old README) labelled raw Unity
    axes "unity"; the server now reads every frame id but "unity_left_handed" as ROS axes, so such poses are
    replayed under the new name and keep their meaning. Exactly "unity": ROS#'s "Unity" is ROS axes already."""
    header = msg.get("header") if isinstance(msg, dict) else None
    if isinstance(header, dict) and isinstance(header.get("frame_id"), str) \
            and header["frame_id"] == "unity" and "pose" in msg:
        return {**msg, "header": {**header, "frame_id": "unity_left_handed"}}
    return msg


def _frame_part(topic: str, msg: dict[str, Any]) -> tuple[float, bool | None, tuple[Any, ...]] | None:
    """A pose or Joy message as a pose frame's part: (stamp, Unity axes or None for a Joy, values), or None when
    the layout cannot say what the message says (another frame id, more axes or buttons, another topic)."""
    try:
        header = msg["header"]
        stamp = header["stamp"]
        t = stamp.get("secs", stamp.get("sec", 0)) + stamp.get("nsecs", stamp.get("nanosec", 0)) / 1e9
        frame_id = header.get("frame_id", "")
        if topic in pose_frame.POSE_TOPICS and frame_id in ("", pose_frame.UNITY_FRAME):
            p, o = msg["pose"]["position"], msg["pose"]["orientation"]
            return t, frame_id == pose_frame.UNITY_FRAME, (p["x"], p["y"], p["z"], o["x"], o["y"], o["z"], o["w"])
        axes, buttons = msg["axes"], msg["buttons"]
        if topic in pose_frame.JOY_TOPICS and frame_id == "" and len(axes) == 4 and len(buttons) == 4 \
                and all(b in (0, 1) for b in buttons):
            return t, None, (axes, buttons)
    except (KeyError, TypeError, AttributeError):
        pass
    return None


def _pose_frames(steps: list[Step]) -> list[tuple[bytes, int] | None]:
    """For each step, the binary pose frame (client_protocol/pose_frame.py) to send at it and how many steps it
    carries (this one and those after it); None for a step sent as JSON, or one that went in a frame before it. One XR frame's poses and Joy (consecutive steps with
    one time and one stamp) go as one frame, as a headset's data channel sends them, when the head pose, if any,
    comes first: the server steps on the head pose, and the controllers' poses and Joy are read at the next step,
    so their order among themselves (the frame's: poses, then Joy) changes nothing."""
    out: list[tuple[bytes, int] | None] = [None] * len(steps)
    i = 0
    while i < len(steps):
        step = steps[i]
        part = _frame_part(step.topic, step.payload) if step.kind == "publish" else None
        if part is None:
            i += 1
            continue
        stamp, unity = part[0], part[1]
        poses: dict[str, tuple[float, ...]] = {}
        joys: dict[str, tuple[Any, Any]] = {}
        j = i
        while j < len(steps):
            other = steps[j]
            part = _frame_part(other.topic, other.payload) \
                if other.kind == "publish" and other.t == step.t and other.topic not in poses \
                and other.topic not in joys and (j == i or other.topic != names.HEAD_POSE_TOPIC) else None
            if part is None or part[0] != stamp or (part[1] is not None and unity is not None and part[1] != unity):
                break
            if part[1] is None:
                joys[other.topic] = part[2]
            else:
                poses[other.topic], unity = part[2], part[1]
            j += 1
        try:
            out[i] = (pose_frame.encode(stamp, poses=poses, joys=joys, unity=bool(unity)), j - i)
        except struct.error:  # a value the layout cannot hold: this step as JSON
            j = i + 1
        i = j
    return out


class PoseRoad(Protocol):
    """Another way for the operator's streams than the WebSocket, opened on the replay's connection (`call` makes
    a service call over it and returns the response's values)."""

    async def open(self, call: Callable[[str, dict[str, Any]], Awaitable[Any]]) -> None: ...

    def send(self, topic: str, msg: dict[str, Any]) -> bool:
        """Takes the message (True), or leaves it to the WebSocket (False: this road is not up)."""

    async def close(self) -> None: ...


@dataclass
class Collected:
    sent_head: list[tuple[float, int]] = field(default_factory=list)  # send time, index into steps
    commands: dict[str, list[tuple[float, list[float]]]] = field(default_factory=lambda: defaultdict(list))
    joint_states: list[tuple[float, dict[str, float]]] = field(default_factory=list)
    camera: list[tuple[float, float]] = field(default_factory=list)  # receive wall time, stamp
    calls: dict[str, tuple[str, float, dict[str, Any]]] = field(default_factory=dict)  # id -> service, sent, args
    responses: dict[str, tuple[bool, Any, float]] = field(default_factory=dict)
    errors: list[str] = field(default_factory=list)
    last_command: float = 0.0  # when the newest joint command arrived
    started: float = 0.0  # when the first message was sent
    by_road: int = 0  # operator stream messages handed to the road instead of the WebSocket
    # the server's latched /vr_teleop/menus: selectable id -> (command, args)
    menu_items: dict[str, tuple[str, dict[str, Any]]] = field(default_factory=dict)
    clock: Clock = WALL  # whose times the ones above are
    wall_started: float = 0.0  # time.perf_counter() when the first message was sent
    wall_last_command: float = 0.0  # time.perf_counter() when the newest joint command arrived

    def __repr__(self) -> str:
        # short: asyncio writes the repr of a finished task's result when the run ends, and the full one of a
        # 300 s session (its lists) took 0.2 s of CPU
        return (f"Collected(sent_head={len(self.sent_head)}, commands={ {k: len(v) for k, v in self.commands.items()} }, "
                f"joint_states={len(self.joint_states)}, camera={len(self.camera)}, calls={len(self.calls)}, "
                f"errors={len(self.errors)})")


def _listen(client: Client, got: Collected) -> list[tuple[str, Callable[[dict[str, Any]], None]]]:
    """What the replay subscribes to, and how each message is recorded as it arrives."""
    clock = got.clock

    def command(part: str) -> Callable[[dict[str, Any]], None]:
        def on(msg: dict[str, Any]) -> None:
            got.last_command = now = clock.monotonic()
            got.commands[part].append((now, msg["data"]))  # a part never commanded has no entry
            got.wall_last_command = time.perf_counter()
        return on

    def joint_state(msg: dict[str, Any]) -> None:
        got.joint_states.append((clock.monotonic(), dict(zip(msg["name"], msg["position"]))))

    def menus(msg: dict[str, Any]) -> None:
        got.menu_items = {item["id"]: (item["command"], json.loads(item.get("args") or "{}"))
                          for item in msg["items"] if item.get("command")}

    def camera(msg: dict[str, Any]) -> None:
        stamp = msg["header"]["stamp"]
        secs = stamp.get("secs", stamp.get("sec", 0)) + stamp.get("nsecs", stamp.get("nanosec", 0)) / 1e9
        got.camera.append((clock.time(), secs))

    client.on_status = lambda msg: got.errors.append(msg.get("msg", "")) if msg.get("level") == "error" else None
    return [*((topic, command(part)) for topic, part in names.COMMAND_TOPIC_PARTS.items()),
            (names.JOINT_STATE_TOPIC, joint_state), (names.MENUS_TOPIC, menus), (names.CAMERA_TOPIC, camera)]


def _answered(got: Collected, call_id: str, future: asyncio.Future[dict[str, Any]]) -> None:
    """Records a replayed call's answer: acknowledged, or refused or failed (with the reason's values)."""
    if future.cancelled() or isinstance(future.exception(), ConnectionError):
        return  # never answered
    try:
        answer: tuple[bool, Any] = (True, outcome(future.result()))
    except RosbridgeError as exc:
        answer = (False, exc.values)
    got.responses[call_id] = (*answer, got.clock.monotonic())


async def run_replay(steps: list[Step], url: str, speed: float, camera: bool = True,
                     progress: bool = True, road: PoseRoad | None = None,
                     connection: Callable[[], Any] | None = None,
                     pose_frames: bool = False) -> tuple[Collected, float]:
    """Plays the steps at `speed` (math.inf: each as soon as the connection takes it) over a WebSocket to `url`,
    or over `connection()` (a connection shaped like a websockets one, as the server's in-process one) when given.
    `pose_frames`: poses and Joy go as binary pose frames where the layout carries them (a server of ours only:
    float32 values, as a headset's pose frames have), the rest as JSON."""
    clock = loop_clock()
    got = Collected(clock=clock)
    control: list[tuple[Step, str]] = []  # control calls whose answers are not applied yet, in order sent
    answers: list[asyncio.Future[dict[str, Any]]] = []
    holding = False
    client = Client(connection(), id_prefix="replay") if connection is not None \
        else await connect(url, id_prefix="replay")
    async with client:
        for topic, on in _listen(client, got):
            if topic == names.CAMERA_TOPIC and not camera:
                continue
            # every command and joint state: a backlog, not the newest only; the camera's newest frame only
            options = {"queue_length": 0 if topic == names.CAMERA_TOPIC else 100_000} \
                if topic != names.MENUS_TOPIC else {"type": "vr_teleop_msgs/Menus"}
            await client.subscribe(topic, callback=on, **options)
        for topic in sorted({s.topic for s in steps if s.kind == "publish"} & set(TOPIC_TYPES)):
            await client.advertise(topic, TOPIC_TYPES[topic])
        if road is not None:
            await road.open(lambda service, args: client.call(service, args, timeout=ROAD_CALL_TIMEOUT_S))
        await client.sync()  # the subscriptions and advertisements are the server's before the first step
        # made before the clock starts, as the steps were read from the file before it
        binary = _pose_frames(steps) if pose_frames else [None] * len(steps)
        in_frame = -1  # the last step sent in a pose frame already
        loop = asyncio.get_running_loop()
        t0 = loop.time()
        got.started = clock.monotonic()
        got.wall_started = time.perf_counter()
        bar = tqdm(total=len(steps), unit="msg", disable=not progress, file=sys.stderr, desc="replay")
        for i, step in enumerate(steps):
            if i <= in_frame:  # sent in the pose frame of a step before it
                bar.update(1)
                continue
            delay = t0 + step.t / speed - loop.time()
            if delay > 0:
                await asyncio.sleep(delay)
            elif math.isinf(speed):
                await asyncio.sleep(0)  # as fast as the server takes them, the answers read as they come
            if step.kind == "publish":
                sent = clock.monotonic()
                if road is not None and step.topic.startswith("/vr/"):
                    holding = _holding(control, got, holding)
                if holding and road is not None and step.topic.startswith("/vr/") \
                        and road.send(step.topic, step.payload):
                    got.by_road += 1
                elif (frame := binary[i]) is not None:
                    await client.send(frame[0])
                    in_frame = i + frame[1] - 1
                else:
                    await client.publish(step.topic, step.payload)
                if step.topic == names.HEAD_POSE_TOPIC:
                    got.sent_head.append((sent, i))
            else:
                call_id = f"replay:{i}"
                args = step.payload.get("args") or {}
                got.calls[call_id] = (step.topic, clock.monotonic(), args)
                control.append((step, call_id))
                answer = await client.request(step.topic, args, call_id=call_id)
                answer.add_done_callback(lambda future, cid=call_id: _answered(got, cid, future))
                answers.append(answer)
            bar.update(1)
        bar.close()
        elapsed = time.perf_counter() - got.wall_started
        await _drain(got, answers, loop.time() + DRAIN_S)
        if road is not None:
            await road.close()
    return got, elapsed


async def _drain(got: Collected, answers: list[asyncio.Future[dict[str, Any]]], deadline: float) -> None:
    """Waits for the last answers (a sentence, a gesture) and for the commands a lagging server still owes: until
    no command has come for QUIET_S, or the deadline."""
    try:
        async with asyncio.timeout_at(deadline):
            if answers:
                await asyncio.wait(answers)
            while (quiet_in := QUIET_S - (got.clock.monotonic() - got.last_command)) > 0:
                await asyncio.sleep(quiet_in)  # to when the quiet would be complete, unless a command came since
    except TimeoutError:
        pass


def _holding(control: list[tuple[Step, str]], got: Collected, holding: bool) -> bool:
    """Whether the replayed operator holds control, from the answers to its control calls so far (in order)."""
    while control and control[0][1] in got.responses:
        step, cid = control.pop(0)
        action = _control_action(step, got, cid)
        if action is not None and action[0] in ("engage", "estop"):
            holding = action == ("engage", True)
    return holding


def run_simulated(steps: list[Step], camera: bool = True, progress: bool = True,
                  settings: ServerSettings | None = None) -> tuple[Collected, float]:
    """The replay at `--speed max` without a server: a server of its own on the stand-in and a simulated clock,
    reached through an in-process connection to its transport. Returns what run_replay returns.

    Without `camera` nobody watches the head camera, so no frame is drawn for the faces either: the pupils' faces
    are modelled (`perception: modelled`). Searching drawn frames for them was 43% of a menu tour's replay CPU."""
    base = settings or ServerSettings(port=0, backend="sim")
    perception = "modelled" if not camera and not base.blur_faces else base.perception
    clock = SimulatedClock()

    async def main() -> tuple[Collected, float]:
        server = TeleopServer(base.model_copy(update={"port": 0, "backend": "sim", "host": "127.0.0.1",
                                                   # the session as it was: no autonomous moves of the robot's own,
                                                   # no simulated pupils' lines (the recording has its own; each
                                                   # line is an espeak-ng render the simulated clock waits for:
                                                   # x7.3 against x10.3 without them)
                                                   "autonomy": AutonomyLevel.TELEOPERATED,
                                                   "bystander_interval": 0, "perception": perception}), clock)
        async with server:
            return await run_replay(steps, "", 1.0, camera=camera, progress=progress,
                                    connection=server.transport.connect_local, pose_frames=True)

    return run_on_clock(main(), clock)


def _responses(got: Collected, expected: dict[int, dict[str, list[float]]]) -> tuple[
        dict[int, dict[str, tuple[float, list[float]]]], str]:
    """For each head pose sent (by step index), the commands it caused, per part, and how they were paired.

    The server steps on each head pose in the order sent and publishes the moving parts' targets. When a part's
    command count matches the offline mapping's, the n-th command from the end answers the n-th pose from the end
    that moves that part ("in_order", exact even when the server lags). Otherwise a pose is paired with the first
    command received after it and before the next pose ("window", right only while the server keeps up)."""
    out: dict[int, dict[str, tuple[float, list[float]]]] = defaultdict(dict)
    # The server may send a few more: an engage taking hold a pose early, a last step of its watchdog tick when
    # the stream stops. Those come first or last: skip the offset at the start that fits best.
    extra = {part: len(got.commands.get(part, [])) - sum(1 for e in expected.values() if part in e)
             for part in names.COMMAND_TOPIC_PARTS.values()}
    if all(0 <= n < ENGAGE_LAGS for n in extra.values()):
        for part in names.COMMAND_TOPIC_PARTS.values():
            causes = sorted(i for i, e in expected.items() if part in e)
            cmds = got.commands.get(part, [])
            if not causes:
                continue
            want = np.array([expected[i][part] for i in causes])

            def misfit(skip: int, cmds=cmds, want=want) -> float:
                have = np.array([c[1] for c in cmds[skip:skip + len(want)]])
                return float(np.abs(have - want).max(axis=1).mean())

            skip = min(range(extra[part] + 1), key=misfit)
            for index, command in zip(causes, cmds[skip:]):
                out[index][part] = command
        return dict(out), "in_order"
    for part, cmds in got.commands.items():
        times = np.array([c[0] for c in cmds])
        for k, (sent, index) in enumerate(got.sent_head):
            before = got.sent_head[k + 1][0] if k + 1 < len(got.sent_head) else float("inf")
            j = int(np.searchsorted(times, sent))
            if j < len(cmds) and cmds[j][0] < before:
                out[index][part] = cmds[j]
    return dict(out), "window"


def _measured_at(got: Collected, t: float) -> dict[str, float] | None:
    states = [joints for when, joints in got.joint_states if when <= t]
    return states[-1] if states else None


def _control_action(step: Step, got: Collected, cid: str) -> tuple[str, bool] | None:
    """What a successful call did to explicit control: ("engage"|"estop"|"head"|"arms", on), or None.
    Menu items that reach the control services count too."""
    response = got.responses.get(cid)
    if response is None or not response[0]:
        return None
    args = got.calls[cid][2]
    service, data = step.topic, args.get("data")
    if service == names.MENU_SELECT_SERVICE:
        command, item_args = got.menu_items.get(args.get("id", ""), ("", {}))
        extra = json.loads(args.get("args") or "{}")
        item_args = {**item_args, **extra}
        service = {"engage": names.ENGAGE_SERVICE, "estop": names.ESTOP_SERVICE, "set_head_control": names.HEAD_SERVICE,
                   "set_arms_control": names.ARMS_SERVICE}.get(command, "")
        data = item_args.get("enable", True)
        if command in ("set_head_control", "set_arms_control") and "enable" not in item_args:
            on = str(response[1].get("message", "") if isinstance(response[1], dict) else "").endswith(" on")
            data = on  # a toggle: the answer says which way it went
    kind = {names.ENGAGE_SERVICE: "engage", names.ESTOP_SERVICE: "estop", names.HEAD_SERVICE: "head",
            names.ARMS_SERVICE: "arms"}.get(service)
    return (kind, bool(data)) if kind else None


def expected_commands(steps: list[Step], got: Collected, settings: TeleopSettings | None = None,
                      engage_lag: int = 0, head_only: bool = False) -> dict[int, dict[str, list[float]]]:
    """What TeleopMapper gives for each head pose, computed offline from the same messages at the replay's send
    times. Control calls act where they were sent, except that an engage takes hold `engage_lag` head poses later
    (the server runs service calls as tasks, so a pose or two may overtake one), from the joints measured then.
    Where velocity caps bind, the server's own step times (its load) show in the difference. `head_only`: the arms
    held (their IK is most of the mapping's cost, and the head's commands do not depend on them)."""
    mapper = TeleopMapper(load_qtrobot(), settings)
    for part in ARMS if head_only else ():
        mapper.set_part_enabled(part, False)
    send_time = {index: sent for sent, index in got.sent_head}
    expected: dict[int, dict[str, list[float]]] = {}
    last_t = 0.0
    engage_in: int | None = None
    for i, step in enumerate(steps):
        if step.kind == "call":
            action = _control_action(step, got, f"replay:{i}")
            if action == ("engage", True):
                engage_in = engage_lag
            elif action is not None and action[0] in ("engage", "estop"):
                engage_in = None
                if action[0] == "engage":
                    mapper.release()
                else:
                    mapper.estop()
            elif action is not None and not (head_only and action[0] != "head"):
                for part in (Part.HEAD,) if action[0] == "head" else ARMS:
                    mapper.set_part_enabled(part, action[1])
            continue
        t = last_t = send_time.get(i, last_t)
        try:
            if step.topic == names.HEAD_POSE_TOPIC:
                if engage_in == 0:
                    engage_in = None
                    mapper.engage(t, _measured_at(got, t))
                elif engage_in is not None:
                    engage_in -= 1
                mapper.on_head_pose(step.payload, t)
                out = mapper.step(t)
                if out.commands:
                    expected[i] = {part: list(values) for part, values in out.commands.items()}
            elif step.topic.endswith("_controller/pose"):
                mapper.on_controller_pose(step.topic.split("/")[2].split("_")[0], step.payload, t)
            elif step.topic.endswith("/joy"):
                mapper.on_joy(step.topic.split("/")[2].split("_")[0], step.payload["axes"], step.payload["buttons"], t)
        except (ValueError, TeleopError):  # the server refuses these too
            continue
    return expected


def _tracking(got: Collected, expected: dict[int, dict[str, list[float]]]) -> tuple[
        dict[str, np.ndarray], dict[int, dict[str, tuple[float, list[float]]]], str]:
    caused, pairing = _responses(got, expected)
    errors = {part: np.array([np.abs(np.array(parts[part][1]) - np.array(expected[i][part])).max()
                              for i, parts in caused.items() if part in parts and part in expected.get(i, {})])
              for part in names.COMMAND_TOPIC_PARTS.values()}
    return errors, caused, pairing


def _engage_lag(steps: list[Step], got: Collected, poses: int = 180, settings: TeleopSettings | None = None) -> int:
    """How many head poses after the engage call the server engaged (not on the wire: the server runs calls as
    tasks). The lag whose first offline head commands match the first ones received, in order, wins; as in
    _responses, the server may have sent a few commands first that no pose of the offline mapping causes."""
    received = [c[1] for c in got.commands.get("head", [])]
    engage = next((i for i, step in enumerate(steps) if step.kind == "call" and step.topic == names.ENGAGE_SERVICE),
                  None)
    if engage is None or not received:
        return 0
    after = [i for i, step in enumerate(steps) if i > engage and step.topic == names.HEAD_POSE_TOPIC]
    head = steps[:after[min(poses, len(after)) - 1] + 1] if after else steps

    def miss(lag: int) -> float:
        expected = expected_commands(head, got, settings, engage_lag=lag, head_only=True)
        firsts = [e["head"] for _i, e in sorted(expected.items()) if "head" in e][: len(received)]
        if not firsts:
            return np.inf
        return min(float(np.mean([np.abs(np.array(e) - np.array(r)).max() for e, r in zip(firsts, received[skip:])]))
                   for skip in range(min(ENGAGE_LAGS, len(received))))

    return min(range(ENGAGE_LAGS), key=miss)


def _reason(values: Any) -> Any:
    """A failed call's reason: the refusal's message inside the response, or the values of a call that failed."""
    return values.get("message", values) if isinstance(values, dict) else values


def report(steps: list[Step], got: Collected, elapsed: float, speed: float,
           settings: TeleopSettings | None = None, recording: Path | None = None) -> dict[str, Any]:
    """`settings`: the server's teleop settings, for the offline mapping (default: the defaults). `recording`: the
    session's MCAP file, whose supervision and attention measures (study/metrics/autonomy.py, as `vr-teleop metrics
    autonomy` gives them) the report carries as `autonomy`: what the replay sends back cannot show them, since the
    pupils and the teacher's decisions are not replayed."""
    duration = steps[-1].t if steps else 0.0
    lag = _engage_lag(steps, got, settings=settings)
    expected = expected_commands(steps, got, settings, engage_lag=lag)
    errors, caused, pairing = _tracking(got, expected)
    sent_at = {index: sent for sent, index in got.sent_head}
    last = [c[-1][0] for c in got.commands.values() if c]
    served = max(last) - got.started if last else None
    if got.clock.simulated:  # simulated times in the report; how fast it went is the wall clock's
        served = got.wall_last_command - got.wall_started if last else None
    lat_ms = np.array([(min(t for t, _v in parts.values()) - sent_at[i]) * 1e3 for i, parts in caused.items()])
    cam_rx = np.array([c[0] for c in got.camera])
    cam_age = np.array([(rx - stamp) * 1e3 for rx, stamp in got.camera])
    menu_ids = [cid for cid, (service, _t, _a) in got.calls.items()
                if service == names.MENU_SELECT_SERVICE]
    failed_calls = {cid: _reason(got.responses[cid][1]) for cid in got.calls
                    if cid in got.responses and not got.responses[cid][0]}

    def pct(a: np.ndarray, q: float) -> float | None:
        return round(float(np.percentile(a, q)), 3) if a.size else None

    def stats(e: np.ndarray) -> dict[str, Any]:
        """Per command: the largest joint difference, in degrees."""
        return {"n": int(e.size), "mean": round(float(e.mean()), 3) if e.size else None, "p99": pct(e, 99),
                "max": round(float(e.max()), 3) if e.size else None}

    return {
        "session_s": round(duration, 2), "replay_s": round(elapsed, 2),
        "speed_requested": "max" if math.isinf(speed) else speed,
        "clock": "simulated" if got.clock.simulated else "wall",
        "speed_achieved": round(duration / elapsed, 2) if elapsed > 0 else None,
        # until the last joint command arrived: how fast the server really went through the session
        "served_s": round(served, 2) if served else None,
        "speed_served": round(duration / served, 2) if served else None,
        "messages_sent": sum(1 for s in steps if s.kind == "publish"),
        "calls_sent": len(got.calls), "calls_answered": len(got.responses),
        "latency_ms": {"n": int(lat_ms.size), "pairing": pairing, "p50": pct(lat_ms, 50), "p99": pct(lat_ms, 99),
                       "max": round(float(lat_ms.max()), 3) if lat_ms.size else None},
        "tracking_error_deg": {**stats(np.concatenate(list(errors.values()))),
                               "by_part": {part: stats(e) for part, e in errors.items()}},
        "commands_received": {part: len(v) for part, v in got.commands.items()},
        "commands_expected": {part: n for part in names.COMMAND_TOPIC_PARTS.values()
                              if (n := sum(1 for e in expected.values() if part in e))},
        "camera": {"frames": int(cam_rx.size),
                   "fps": round(float((cam_rx.size - 1) / (cam_rx[-1] - cam_rx[0])), 2) if cam_rx.size > 1 else 0.0,
                   "age_ms_p50": pct(cam_age, 50), "age_ms_p99": pct(cam_age, 99)},
        "menu": {"selected": len(menu_ids), "acknowledged": sum(1 for c in menu_ids if got.responses.get(c, (0,))[0]),
                 "failed": {got.calls[c][2].get("id", c): failed_calls[c] for c in menu_ids if c in failed_calls},
                 "items_on_server": len(got.menu_items),
                 # a session that used the menus: which of the server's items it never tried
                 "not_selected": sorted(set(got.menu_items) - {got.calls[c][2].get("id") for c in menu_ids})
                 if menu_ids else []},
        "errors": {"count": len(got.errors) + len(failed_calls), "status": got.errors[:20],
                   "failed_calls": {c: v for c, v in list(failed_calls.items())[:20]}},
        **({"autonomy": _session_autonomy(recording)} if recording is not None else {}),
    }


def _session_autonomy(recording: Path) -> dict[str, Any]:
    return {k: v for k, v in autonomy_metrics(recording).items() if k != "file"}


def plot(got: Collected, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    model = load_qtrobot()
    t0 = min([t for t, _ in got.joint_states] + [c[0] for v in got.commands.values() for c in v] or [0.0])
    fig, axes = plt.subplots(4, 2, figsize=(12, 10), sharex=True)
    for ax, name in zip(axes.flat, model.names):
        part = next(p for p, names in model.parts.items() if name in names)
        k = model.parts[part].index(name)
        cmds = got.commands.get(part, [])
        if cmds:
            ax.plot([c[0] - t0 for c in cmds], [c[1][k] for c in cmds], label="commanded", lw=1, color="C0")
        if got.joint_states:
            ax.plot([t - t0 for t, _ in got.joint_states], [j.get(name, np.nan) for _, j in got.joint_states],
                    label="measured", lw=1, color="C1")
        joint = model.joint(name)
        ax.axhline(joint.lower, color="grey", ls=":", lw=0.8)
        ax.axhline(joint.upper, color="grey", ls=":", lw=0.8)
        ax.set_title(name, fontsize=9)
        ax.set_ylabel("deg")
    axes.flat[0].legend(fontsize=8)
    for ax in axes[-1]:
        ax.set_xlabel("replay time (s)")
    fig.tight_layout()
    fig.savefig(out, dpi=100)
    plt.close(fig)
