"""SimRobot: the Robot interface over the running MuJoCo stand-in, driven from asyncio."""

from __future__ import annotations

import asyncio
import contextlib
import math
import time

import cv2
import numpy as np
import pytest

from robot_models import load_qtrobot
from robot_models.types import CameraFrame
from testbed.server import Pace, until
from vr_teleop_server.robot.backends.sim import SimRobot
from vr_teleop_server.robot.interface import Gesture, MotorMode, Robot, Waypoint

MODEL = load_qtrobot()


@pytest.fixture(scope="module")
def robot():
    r = SimRobot(MODEL)
    yield r
    r.close()


async def simulated_time_passes(robot: SimRobot, seconds: float) -> None:
    """Until the stand-in's simulation has advanced by `seconds` (what a joint has had to move in)."""
    start = robot.standin.joint_state().sim_time
    assert await until(lambda: robot.standin.joint_state().sim_time >= start + seconds, 30), "the simulation stopped"


async def at_home(robot: SimRobot) -> None:
    robot.set_control_mode(list(MODEL.parts), MotorMode.ON)
    robot.home()
    home = MODEL.home_pose()
    assert await until(lambda: all(abs(v - home[n]) < 0.5 for n, v in robot.joint_state().as_dict().items()), 30)


async def test_is_a_robot_and_builds_off_the_loop():
    r = await SimRobot.create(MODEL)
    try:
        assert isinstance(r, Robot) and r.model is MODEL
    finally:
        await r.aclose()


async def test_part_targets_in_range_are_applied(robot):
    await at_home(robot)
    report = robot.set_part_targets("right_arm", [-60.0, -40.0, -50.0])
    assert report.ok and report.names == MODEL.parts["right_arm"]
    assert report.applied == (-60.0, -40.0, -50.0)
    assert await until(lambda: abs(robot.joint_state().as_dict()["RightShoulderPitch"] + 60.0) < 0.5, 30)


async def test_out_of_range_targets_are_clamped_and_reported(robot):
    await at_home(robot)
    report = robot.set_part_targets("head", [100.0, -40.0])
    assert not report.ok
    assert report.applied == (60.0, -15.0)
    assert {(c.name, c.requested, c.applied) for c in report.clamped} == {("HeadYaw", 100.0, 60.0),
                                                                         ("HeadPitch", -40.0, -15.0)}
    assert "HeadYaw 100.0 -> 60.0" in report.describe()
    assert await until(lambda: abs(robot.joint_state().as_dict()["HeadYaw"] - 60.0) < 0.5, 30)
    with pytest.raises(ValueError, match="HeadYaw, HeadPitch"):
        robot.set_part_targets("head", [1.0])
    with pytest.raises(KeyError, match="right_arm"):
        robot.set_part_targets("tail", [1.0])
    with pytest.raises(ValueError, match="finite"):
        robot.set_part_targets("head", [float("inf"), 0.0])


async def test_calls_from_the_loop_return_fast(robot):
    calls = [
        lambda: robot.set_part_targets("head", [5.0, 5.0]),
        robot.joint_state,
        robot.motor_status,
        lambda: robot.show_emotion("happy"),
        robot.add_camera_subscriber,
        robot.remove_camera_subscriber,
        robot.latest_frame,
    ]
    # Non-blocking means no call waits for a render, a sleep or a physics run: each takes the state lock for
    # at most one batch of steps. A preempted call on a loaded machine is slow once, a blocking call every time,
    # so each call's fastest of 20 tries must be well under a camera frame (bench/standin.py prints the figures).
    for call in calls:
        fastest = math.inf
        for _ in range(20):
            t0 = time.perf_counter()
            call()
            fastest = min(fastest, time.perf_counter() - t0)
        assert fastest < 0.02, (call, fastest)


async def test_joint_state_orders(robot):
    state = robot.joint_state()
    assert state.names == MODEL.names
    alpha = state.reordered(MODEL.alphabetical_names)
    assert alpha.names == MODEL.alphabetical_names
    assert alpha.as_dict() == state.as_dict()
    assert abs(state.stamp_wall - time.time()) < 1.0


async def test_motor_modes_and_status(robot):
    await at_home(robot)
    robot.set_control_mode(["head"], MotorMode.BRAKE)
    report = robot.set_part_targets("head", [30.0, 10.0])
    assert report.ignored == ("HeadYaw", "HeadPitch") and not report.ok
    await simulated_time_passes(robot, 0.3)
    assert abs(robot.joint_state().as_dict()["HeadYaw"]) < 0.5
    status = {m.name: m for m in robot.motor_status()}
    assert set(status) == set(MODEL.names)
    assert status["HeadYaw"].mode is MotorMode.BRAKE and status["LeftElbowRoll"].mode is MotorMode.ON
    assert status["HeadYaw"].source == "modelled" and status["HeadYaw"].voltage_v is None
    assert 20.0 < status["HeadYaw"].temperature_c < 120.0
    robot.set_control_mode(["head"], MotorMode.ON)
    assert robot.set_part_targets("head", [30.0, 10.0]).ok
    assert await until(lambda: abs(robot.joint_state().as_dict()["HeadYaw"] - 30.0) < 0.5, 30)
    with pytest.raises(KeyError):
        robot.set_control_mode(["wheels"], MotorMode.OFF)


async def test_home_brings_every_part_back(robot):
    robot.set_part_targets("left_arm", [0.0, -20.0, -20.0])
    await simulated_time_passes(robot, 0.3)
    reports = robot.home()
    assert set(reports) == set(MODEL.parts) and all(r.ok for r in reports.values())
    assert await until(lambda: abs(robot.joint_state().as_dict()["LeftShoulderPitch"] - 90.0) < 0.5, 30)


async def test_emotions(robot):
    robot.show_emotion("QT/sad")
    assert robot.standin.emotion == "sad"
    assert await asyncio.to_thread(robot.standin.wait_face)
    with pytest.raises(ValueError, match="happy"):
        robot.show_emotion("QT/gleeful")


async def test_say_returns_when_done_and_stop_cuts_it_short(robot):
    text = "hello children how are you today"
    expected = robot.speech_duration(text)
    assert expected == pytest.approx(6 * 60 / 150)
    task = asyncio.create_task(robot.say(text))
    assert await until(robot.standin.is_talking, 30)
    robot.stop_speech()
    result = await asyncio.wait_for(task, 1.0)
    assert not result.completed and result.duration_s < 1.0 and result.audible is False
    assert not robot.standin.is_talking()

    short = await robot.say("hi there")
    assert short.completed and short.duration_s == pytest.approx(robot.speech_duration("hi there"), abs=0.1)
    assert not robot.standin.is_talking()


async def test_gesture_plays_its_waypoints_in_time_without_blocking_the_loop(robot):
    await at_home(robot)
    gesture = Gesture("nod_right", tuple(
        Waypoint(t, {"HeadYaw": 20.0 * np.sin(np.pi * t / 0.8), "HeadPitch": 10.0 * t})
        for t in np.arange(0.0, 0.85, 0.05)))
    events: list[str] = []  # in the order they happened on the loop: "tick" (another task ran), "wp" (a waypoint)
    send = robot.set_joint_targets

    def recorded(targets):
        events.append("wp")
        return send(targets)

    async def ticker():  # another task taking turns on the loop at 100 Hz: what the test looks for
        pace = Pace(100, catch_up=False)
        while True:
            await pace.tick()
            events.append("tick")

    robot.set_joint_targets = recorded
    tick = asyncio.create_task(ticker())
    t0 = time.monotonic()
    try:
        result = await robot.play_gesture(gesture)
    finally:
        elapsed = time.monotonic() - t0
        tick.cancel()
        del robot.set_joint_targets
    assert result.completed and not result.stopped, result
    assert result.waypoints_sent == len(gesture.waypoints) and not result.clamps
    assert result.final_error_deg <= 1.0
    assert elapsed >= gesture.duration_s  # never ahead of its schedule
    # The loop kept running throughout: other tasks ran between the waypoints, not only before or after them.
    wps = [i for i, e in enumerate(events) if e == "wp"]
    assert len(wps) >= len(gesture.waypoints), events
    between = events[wps[0]:wps[len(gesture.waypoints) - 1]]
    assert between.count("tick") >= 2, events
    assert abs(robot.joint_state().as_dict()["HeadPitch"] - 8.0) < 1.0


async def test_gesture_reports_clamps_stop_and_motors_off(robot):
    await at_home(robot)
    clamped = await robot.play_gesture(Gesture("too_far", (Waypoint(0.0, {"HeadYaw": 80.0}),)), speed=2.0)
    assert [(c.name, c.applied) for c in clamped.clamps] == [("HeadYaw", 60.0)]
    assert clamped.completed  # it reached the clamped pose, and says what was clamped

    long = Gesture("slow", (Waypoint(0.0, {"HeadYaw": 0.0}), Waypoint(3.0, {"HeadYaw": -50.0})))
    task = asyncio.create_task(robot.play_gesture(long))
    assert await until(lambda: robot.standin.targets()["HeadYaw"] == 0.0, 30)  # its first waypoint is out (from 60)
    robot.stop_gesture()
    result = await asyncio.wait_for(task, 1.0)
    assert result.stopped and not result.completed and result.waypoints_sent == 1

    robot.set_control_mode(["head"], MotorMode.OFF)
    try:
        off = await robot.play_gesture(Gesture("limp", (Waypoint(0.0, {"HeadYaw": 10.0}),)))
        assert not off.completed and off.ignored == ("HeadYaw",)
    finally:
        robot.set_control_mode(["head"], MotorMode.ON)

    with pytest.raises(ValueError, match="backwards"):
        await robot.play_gesture(Gesture("bad", (Waypoint(1.0, {"HeadYaw": 0}), Waypoint(0.5, {"HeadYaw": 1}))))
    with pytest.raises(KeyError):
        await robot.play_gesture(Gesture("bad", (Waypoint(0.0, {"Tail": 0}),)))


async def camera_stopped(robot: SimRobot) -> None:
    """Until nobody watches and the render thread has acknowledged it: a frame it had in flight is out."""
    assert await asyncio.to_thread(robot.standin.wait_camera_stopped, 30), "the render thread never saw the stop"


async def next_frame_watched(robot: SimRobot, after_seq: int) -> CameraFrame:
    """The next frame after `after_seq`, watching the camera for it only."""
    robot.add_camera_subscriber()
    try:
        frame = await robot.next_frame(after_seq, timeout=30)
    finally:
        robot.remove_camera_subscriber()
    assert frame is not None
    return frame


async def test_camera_frames_only_while_subscribed(robot):
    # The frames are numbered as drawn: the first one drawn after a time nobody watched follows the last one drawn
    # before it, so none was drawn in between (no wall-clock window to wait out).
    await camera_stopped(robot)
    before = robot.latest_frame()
    before_seq = before.seq if before else 0
    robot.add_camera_subscriber()
    try:
        frame = await robot.next_frame(before_seq, timeout=30)
        assert frame is not None and frame.seq == before_seq + 1
        image = cv2.imdecode(np.frombuffer(frame.jpeg, np.uint8), cv2.IMREAD_COLOR)
        assert image.shape == (MODEL.camera.height, MODEL.camera.width, 3)
        newer = await robot.next_frame(frame.seq, timeout=30)
        assert newer is not None and newer.seq > frame.seq and newer.stamp_monotonic > frame.stamp_monotonic
    finally:
        robot.remove_camera_subscriber()
    await camera_stopped(robot)
    last = robot.latest_frame()
    assert (await next_frame_watched(robot, last.seq)).seq == last.seq + 1


async def test_live_frames_start_after_the_kept_frame_and_give_the_camera_back(robot):
    assert await next_frame_watched(robot, 0) is not None  # leave a kept frame from an earlier run of the camera
    await camera_stopped(robot)
    kept = robot.latest_frame()
    watchers = robot.standin.camera_subscribers
    async with contextlib.aclosing(robot.live_frames()) as frames:
        first = await anext(frames)
        assert robot.standin.camera_subscribers == watchers + 1
    assert first.seq > kept.seq and first.stamp_monotonic > kept.stamp_monotonic
    assert robot.standin.camera_subscribers == watchers


async def test_a_dead_render_process_ends_live_frames_and_the_robot_still_moves():
    """The stand-in's render process crashes while a consumer iterates live_frames(): the iteration ends (the
    camera is closed, not silently stalled) and joint commands still move the robot."""
    import psutil

    robot = await SimRobot.create(MODEL)
    try:
        frames = []

        async def consume() -> None:
            async with contextlib.aclosing(robot.live_frames()) as live:
                async for frame in live:
                    frames.append(frame)

        consumer = asyncio.ensure_future(consume())
        assert await until(lambda: len(frames) >= 2, 30)
        psutil.Process(robot.standin.render_pid).kill()
        await asyncio.wait_for(consumer, 30)  # ends by itself
        assert robot.camera_closed()
        yaw = robot.joint_state().as_dict()["HeadYaw"]
        robot.set_joint_targets({"HeadYaw": yaw + 15.0})
        assert await until(lambda: abs(robot.joint_state().as_dict()["HeadYaw"] - (yaw + 15.0)) < 1.0, 30)
    finally:
        robot.close()
